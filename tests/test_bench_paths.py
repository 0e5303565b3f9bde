"""Benchmark scripts that start other processes point them at this checkout: their repository root and
``src`` paths are the real ones (``bench_train_speed`` and ``bench_executors`` once named ``benchmarks/src``,
which worked only through the editable install); ``bench_train_speed`` prints its mean ratio with an
interval."""

from __future__ import annotations

from pathlib import Path

import pytest

from helpers import load_benchmark

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    ("script", "name", "want"),
    [
        ("suites/bench_train_speed", "ROOT", REPO),
        ("tools/ab_train_step", "ROOT", REPO),
        ("suites/bench_executors", "SRC", REPO / "src"),
    ],
)
def test_the_paths_a_benchmark_hands_its_subprocesses_are_this_checkouts(
    script: str, name: str, want: Path
) -> None:
    got = getattr(load_benchmark(script), name)
    assert got == want
    assert (REPO / "src" / "spikenerf" / "__init__.py").is_file()


def test_the_speed_benchmark_prints_the_mean_ratio_with_its_interval() -> None:
    """``bench_train_speed`` (and ``ab_train_step``) print the rounds' mean ratio and 95 % t interval (none
    for a single round)."""
    tool = load_benchmark("suites/bench_train_speed")
    rounds = [2.63, 2.61, 2.53, 2.08, 2.72, 2.53, 2.29, 2.19, 3.25, 2.73]
    assert tool.mean_and_interval(rounds) == ", mean 2.56× [2.32×, 2.79×] (95 % t)"
    assert tool.mean_and_interval([3.1]) == ""

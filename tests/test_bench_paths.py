"""Benchmark scripts that start other processes point them at this checkout: their repository root and
``src`` paths are the real ones (``bench_train_speed`` and ``bench_executors`` once named ``benchmarks/src``,
which worked only through the editable install)."""

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

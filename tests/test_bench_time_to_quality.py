"""``benchmarks/experiments/bench_time_to_quality.py``: the summary of any methods against the oracle, on
either clock, and one worker's curve with ``train``'s device, compile and field options (a CPU smoke run;
the curves it measures are in docs/performance.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from helpers import load_benchmark, run_cli

TTQ = load_benchmark("experiments/bench_time_to_quality")


def _points(method: str, times: list[float], psnrs: list[float]) -> list:
    # the wall clock (train_s) runs twice as fast as the CPU clock here, so the two can be told apart
    return [
        TTQ.Point(method, 100, 10 * (i + 1), t, 2 * t, q, 0.0)
        for i, (t, q) in enumerate(zip(times, psnrs, strict=True))
    ]


def test_each_method_is_compared_with_the_oracle_on_the_chosen_clock() -> None:
    points = _points("nerf-gt", [10, 20, 30], [27.0, 30.5, 31.0])
    points += _points("spike-integral", [10, 20, 30, 40], [25.0, 28.2, 29.0, 30.1])
    text = TTQ.summarize(points, (28.0, 30.0), "wall")
    assert "to 30 dB (train s / CPU s)" in text
    assert "| nerf-gt | 100 | 30 | 30 | 60 | 20 / 40 | 20 / 40 | 31.00 (30 / 60) |" in text
    assert "| spike-integral | 100 | 40 | 40 | 80 | 20 / 40 | 40 / 80 | 30.10 (40 / 80) |" in text
    assert "spike-integral: speed to 30 dB, 100 iters | 0.025 | 0.05 (nerf-gt) | 1/train s | 0.50×" in text
    assert "spike-integral: PSNR at 30 train s" in text  # the latest time both reached
    on_cpu = TTQ.summarize(points, (30.0,), "cpu")
    assert "0.0125 | 0.025 (nerf-gt) | 1/CPU s | 0.50×" in on_cpu
    assert "speed to" not in TTQ.summarize(points[:3], (30.0,), "wall")  # the oracle alone: no ratio


def test_a_worker_trains_with_the_given_field_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ds = tmp_path / "ds"
    code, _, err = run_cli(capsys, "simulate", "--scene", "analytic-orbs", "--width", 16, "--height", 16,
                           "--frames", 40, "--test-views", 1, "--out", ds)  # fmt: skip
    assert code == 0, err
    opts = TTQ.Options(str(ds), 1e9, 1e9, "wall", 1, 64, 0, float("inf"), "cpu", False,
                       ("static_samples=24", "weight_threshold=0.00001"))  # fmt: skip
    points = TTQ.train_curve("nerf-gt", 3, opts, tmp_path / "run", tmp_path / "t.csv")
    assert [p.iteration for p in points] == [3] and TTQ.read_points(tmp_path / "t.csv") == points
    config = (tmp_path / "run" / "config.yaml").read_text()
    assert "static_samples: 24" in config and "weight_threshold: 1.0e-05" in config
    args = TTQ.worker_options(opts, 2)  # a worker gets the texts as given (1e-05 would read as a string)
    assert args[args.index("--field-option") + 3] == "weight_threshold=0.00001" and "--compile" not in args

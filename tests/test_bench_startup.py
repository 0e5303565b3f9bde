"""``benchmarks/tools/bench_startup.py``: a smoke run, this checkout against itself, on a tiny run (the
timings it prints are measurements, docs/performance.md)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from helpers import load_benchmark
from spikenerf.cli import main

TOOL = load_benchmark("tools/bench_startup")


def test_info_and_eval_are_timed_for_both_builds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ds, run = tmp_path / "ds", tmp_path / "run"
    main(["simulate", "--scene", "analytic-orbs", "--width", "16", "--height", "16", "--frames", "60",
          "--test-views", "1", "--blur-fps", "0", "--out", str(ds)])  # fmt: skip
    main(["train", str(ds), "--method", "nerf-gt", "--iters", "3", "--batch", "64", "--eval-every", "0",
          "--device", "cpu", "--quiet", "--out", str(run)])  # fmt: skip
    capsys.readouterr()
    ratios = TOOL.main([str(run), "--ref-src", str(TOOL.ROOT / "src"), "--rounds", "1"])
    out = capsys.readouterr().out
    assert set(ratios) == {"info", "eval"} and all(r > 0 for r in ratios.values())
    assert len(re.findall(r"^\| 0 \| (info|eval) \| (reference|ours) \| [\d.]+ \|$", out, re.M)) == 4, out
    assert re.search(r"^eval: reference [\d.]+ s, ours [\d.]+ s \(medians of 1\), ratio [\d.]+×$", out, re.M)
    assert not (run / "metrics.json").exists()  # the copies were evaluated, not the run

"""``benchmarks/tools/bench_static_budgets.py``: a CPU smoke run on a tiny finished run (the timings it prints
are measurements, docs/performance.md)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from helpers import load_benchmark, run_cli

TOOL = load_benchmark("tools/bench_static_budgets")


def test_both_settings_train_from_one_resumed_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    ds, run = tmp_path / "ds", tmp_path / "run"
    code, _, err = run_cli(capsys, "simulate", "--scene", "analytic-orbs", "--width", 16, "--height", 16,
                           "--frames", 60, "--test-views", 1, "--out", ds)  # fmt: skip
    assert code == 0, err
    code, _, err = run_cli(capsys, "train", ds, "--method", "nerf-gt", "--iters", 3, "--batch", 64,
                           "--eval-every", 0, "--quiet", "--out", run)  # fmt: skip
    assert code == 0, err
    capsys.readouterr()
    argv = ["bench_static_budgets", str(run), "--samples", "24", "--colors", "2", "--visible", "6"]
    monkeypatch.setattr(sys, "argv", [*argv, "--steps", "1", "--rounds", "2"])
    TOOL.main()
    out = capsys.readouterr().out
    assert out.count("every slot:") == 2 and out.count("static_colors=2:") == 2
    assert out.count("static_colors=2 static_visible=6:") == 2
    assert "coloured slots left out and" in out and "samples cut a step" in out
    assert out.count("median: ") == 3 and "median: every slot" in out
    assert (run / "checkpoint.pt").is_file() and "static_samples" not in (run / "config.yaml").read_text()

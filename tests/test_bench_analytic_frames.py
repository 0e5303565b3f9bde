"""``benchmarks/tools/bench_analytic_frames.py``: a smoke run at a tiny size (its timings are measurements,
docs/scenes.md)."""

from __future__ import annotations

import pytest

from helpers import load_benchmark

TOOL = load_benchmark("tools/bench_analytic_frames")


def test_each_scene_and_spp_is_timed(capsys: pytest.CaptureFixture[str]) -> None:
    result = TOOL.main(["--size", "8", "--poses", "2"])
    assert set(result) == {(s, spp) for s in ("analytic-orbs", "analytic-blocks") for spp in (1, 4)}
    assert all(t >= 0 for t in result.values())
    assert capsys.readouterr().out.count("ms CPU a frame (8²)") == 4

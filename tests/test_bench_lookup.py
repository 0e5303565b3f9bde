"""``benchmarks/tools/bench_lookup.py``: a CPU smoke run at a tiny size; every lookup that runs on the CPU
agrees with ``grid_sample`` (the timings it prints are measurements, docs/performance.md)."""

from __future__ import annotations

import re
import sys

import pytest

from helpers import load_benchmark
from spikenerf.fields import vm_kernel

TOOL = load_benchmark("tools/bench_lookup")


def test_each_lookup_is_timed_against_grid_sample_and_agrees_with_it(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    argv = ["bench_lookup", "--device", "cpu", "--points", "5000", "--resolution", "12", "--repeats", "1"]
    monkeypatch.setattr(sys, "argv", [*argv, "--rounds", "1"])
    TOOL.main()
    out = capsys.readouterr().out
    assert "C = 16 (summed" in out and "C = 24 ((M, 3, C)" in out
    names = ["grid_sample", "gather"] + (["cpu kernel"] if vm_kernel.available() else [])
    assert "triton" not in out.split("\n", 1)[1]  # not timed in Triton's interpreter
    for name in names:
        rows = re.findall(rf"^\| {name} \| [\d.]+ \| [\d.]+× \| (.+) \|$", out, flags=re.M)
        assert len(rows) == 2, out
        assert all(float(d) < 1e-3 for row in rows for d in row.split(", ")), rows
    assert out.count("| grid_sample |") == 2 and "| 1.00× |" in out


def test_points_follow_rays_inside_the_box() -> None:
    xyz = TOOL.ray_points(1000, 20, TOOL.torch.device("cpu"))
    assert xyz.shape == (1000, 3) and xyz.abs().max() <= 1
    steps = (xyz[1:64] - xyz[:63]).norm(dim=1)
    assert steps.max() <= 2 / 19 + 1e-6  # a cell apart (or less where clamped at the box)

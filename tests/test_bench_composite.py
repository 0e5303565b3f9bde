"""``benchmarks/tools/bench_composite.py``: a CPU smoke run at a tiny size; the renderer's compositing agrees
with the scatter reference it is timed against (the timings it prints are measurements,
docs/performance.md), and the Triton kernels are not timed in the CPU interpreter."""

from __future__ import annotations

import re
import sys

import pytest

from helpers import load_benchmark

TOOL = load_benchmark("tools/bench_composite")


def test_the_compositing_is_timed_against_the_scatter_reference_and_agrees_with_it(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    argv = ["bench_composite", "--device", "cpu", "--rays", "300", "--samples", "8", "--repeats", "1"]
    monkeypatch.setattr(sys, "argv", [*argv, "--rounds", "1"])
    TOOL.main()
    out = capsys.readouterr().out
    rows = dict(re.findall(r"^\| (\w+) \| [\d.]+ \| [\d.]+× \| ([\d.e+-]+) \|$", out, flags=re.M))
    assert set(rows) == {"scatter", "torch"}, out  # (triton: compiled kernels only)
    assert float(rows["scatter"]) == 0 and float(rows["torch"]) < 1e-5
    assert "triton: not timed here" in out


def test_the_scatter_reference_is_the_renderers_result() -> None:
    """The reference kept in the tool computes what the renderer computes (so the ratio compares like with
    like), empty rays included."""
    inputs = TOOL.packed_inputs(50, 6, TOOL.torch.device("cpu"), seed=3)
    assert (TOOL.torch.bincount(inputs[4], minlength=50) == 0).any()  # some rays have no samples
    for a, b in zip(TOOL.scatter(inputs), TOOL.renderer(False)(inputs), strict=True):
        TOOL.torch.testing.assert_close(a, b, atol=1e-6, rtol=1e-6)

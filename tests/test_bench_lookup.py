"""``benchmarks/tools/bench_lookup.py``: a CPU smoke run at a tiny size; every lookup that runs on the CPU
agrees with ``grid_sample`` (the timings it prints are measurements, docs/performance.md)."""

from __future__ import annotations

import re
import sys

import pytest

from helpers import load_benchmark
from spikenerf.fields import vm_kernel, vm_triton

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
        rows = re.findall(rf"^\| {name} \| [\d.]+ \| [\d.]+ \| [\d.]+× \| (.+) \|$", out, flags=re.M)
        assert len(rows) == 2, out
        assert all(float(d) < 1e-3 for row in rows for d in row.split(", ")), rows
    assert out.count("| grid_sample |") == 2 and "| 1.00× |" in out


def test_points_follow_rays_inside_the_box() -> None:
    xyz = TOOL.ray_points(1000, 20, TOOL.torch.device("cpu"))
    assert xyz.shape == (1000, 3) and xyz.abs().max() <= 1
    steps = (xyz[1:64] - xyz[:63]).norm(dim=1)
    assert steps.max() <= 2 / 19 + 1e-6  # a cell apart (or less where clamped at the box)


def test_launch_shapes_parse_and_bad_ones_name_the_item() -> None:
    assert TOOL.launch_shapes("64x4, 32x8") == [(64, 4), (32, 8)]
    for bad, why in (("64", "not POINTSxWARPS"), ("48x4", "a power of 2"), ("64x3", "warps one of")):
        with pytest.raises(TOOL.argparse.ArgumentTypeError, match=why):
            TOOL.launch_shapes(bad)


def test_each_launch_shape_holds_for_its_whole_steps_backward_included(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The Triton lookups in the table (here in the interpreter, which the tool itself leaves out)."""
    pytest.importorskip("triton", reason="the triton package runs the kernels")
    if not (vm_triton.interpreted() or TOOL.torch.cuda.is_available()):
        pytest.skip("needs TRITON_INTERPRET=1 (tests/conftest.py) or CUDA")
    before = dict(vm_triton.LAUNCH)
    seen: set[tuple[str, tuple[int, int]]] = set()
    launch = vm_triton._launch

    def spy(kernel_name: str, *args, **kwargs):  # type: ignore[no-untyped-def]
        seen.add((kernel_name, vm_triton.LAUNCH[kernel_name]))
        return launch(kernel_name, *args, **kwargs)

    monkeypatch.setattr(vm_triton, "_launch", spy)
    applies = vm_triton.applies(TOOL.torch.zeros(1), TOOL.torch.zeros(1))
    monkeypatch.setattr(vm_triton, "interpreted", lambda: False)  # the tool leaves out the interpreter:
    monkeypatch.setattr(vm_triton, "applies", lambda *_: applies)  # time them there all the same
    argv = ["bench_lookup", "--points", "64", "--resolution", "6", "--repeats", "1", "--rounds", "1"]
    monkeypatch.setattr(sys, "argv", [*argv, "--channels", "5", "--triton-launch", "32x2,64x1"])
    TOOL.main()
    assert seen == {(k, s) for k in ("forward", "backward") for s in ((32, 2), (64, 1))}
    assert before == vm_triton.LAUNCH
    rows = re.findall(
        r"^\| triton (32x2|64x1) \| [\d.]+ \| [\d.]+ \| [\d.]+× \| (.+) \|$", capsys.readouterr().out, re.M
    )
    assert len(rows) == 2 and all(float(d) < 1e-3 for _, row in rows for d in row.split(", ")), rows

"""``benchmarks/tools/ab_vm_kernel.py``: it reads a checkout's kernel source without importing it, alternates
which build goes first and prints before / after (its timings are measurements, docs/performance.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from helpers import load_benchmark
from spikenerf.fields import vm_build

TOOL = load_benchmark("tools/ab_vm_kernel")


def test_the_kernel_source_is_read_from_the_file(tmp_path: Path) -> None:
    cpp = Path(vm_build.__file__).with_name(vm_build.SOURCE_FILE)
    assert TOOL.kernel_source(cpp) == vm_build.kernel_source() == cpp.read_text(encoding="utf-8")
    module = tmp_path / "vm_cpu_source.py"  # a checkout from before the source was a .cpp file
    module.write_text('"""The C++ source."""\n\nSOURCE = r"""\nint y;\n"""\n')
    assert TOOL.kernel_source(module) == "\nint y;\n"
    older = tmp_path / "vm_kernel.py"  # a checkout from before the source had a module of its own
    older.write_text("_SOURCE = 'int x;'\n")
    assert TOOL.kernel_source(older) == "int x;"
    other = tmp_path / "other.py"
    other.write_text("KERNEL = 'not the name'\n")
    with pytest.raises(SystemExit, match="no SOURCE"):
        TOOL.kernel_source(other)


def test_the_builds_take_turns_going_first_and_the_ratio_is_before_over_after(
    capsys: pytest.CaptureFixture[str],
) -> None:
    order: list[str] = []
    times = TOOL.timed({"before": lambda: order.append("b"), "after": lambda: order.append("a")}, 4)
    assert order == ["b"] * 3 + ["a"] * 3 + ["b", "a", "a", "b", "b", "a", "a", "b"]
    assert [len(v) for v in times.values()] == [4, 4]
    TOOL.report("backward", {"before": [0.002] * 4, "after": [0.001] * 4})
    assert "| backward | 2.00 | 1.00 | 2.000× (2.000–2.000) |" in capsys.readouterr().out


def test_before_cflags_replace_the_checkouts_flags_of_the_before_build(monkeypatch) -> None:
    seen: list[tuple[str, list[str]]] = []
    monkeypatch.setattr(
        TOOL, "load_inline", lambda name, extra_cflags, **kw: seen.append((name, extra_cflags))
    )
    TOOL.build("int x;", "before", ["-O2"])
    TOOL.build("int x;", "after")
    (before_name, before), (after_name, after) = seen
    assert before == ["-O2", *vm_build._OPENMP_CFLAGS] and after == vm_build._CFLAGS + vm_build._OPENMP_CFLAGS
    assert before_name != after_name  # cached apart: the name hashes the flags


class _Kernel:
    """A stand-in for a built kernel module (no compiler needed): zero outputs of the kernel's shapes."""

    def forward(self, planes, lines, xyz, summed):  # type: ignore[no-untyped-def]
        return xyz.new_zeros((len(xyz),) if summed else (len(xyz), 3, planes.shape[-1]))

    def backward(self, planes, lines, xyz, grad):  # type: ignore[no-untyped-def]
        return planes.new_zeros(planes.shape), lines.new_zeros(lines.shape)


class _PointKernel(_Kernel):
    def point_backward(self, planes, lines, xyz, grad):  # type: ignore[no-untyped-def]
        return xyz.new_zeros(xyz.shape)


@pytest.mark.parametrize("before_has_points", [False, True])
def test_the_points_gradient_is_timed_only_where_both_builds_have_it(
    before_has_points: bool, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    kernels = {"before": _PointKernel() if before_has_points else _Kernel(), "after": _PointKernel()}
    monkeypatch.setattr(TOOL, "kernel_source", lambda path: str(path))
    monkeypatch.setattr(TOOL, "build", lambda source, tag, cflags=None: kernels[tag])
    argv = ["ab_vm_kernel", "a.cpp", "b.cpp", "--points", "256", "--resolution", "8", "--repeats", "2"]
    monkeypatch.setattr("sys.argv", [*argv, "--threads", "1"])
    TOOL.main()
    out = capsys.readouterr().out
    assert out.count("| backward, 1 thread(s)") == 2 and out.count("| forward, 1 thread(s)") == 2
    assert out.count("| points' gradient, 1 thread(s)") == (2 if before_has_points else 0)
    assert out.count("largest difference (output, gradients) | 0.0e+00") == 2

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

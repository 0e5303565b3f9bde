"""The fused CPU kernel's C++ source is a file of the package (``fields/vm_cpu.cpp``, package data read with
``importlib.resources``): the build compiles that text, its cache folder's name hashes it, and an
installation without it falls back to ``grid_sample`` with one warning, as one without a compiler does."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import pytest

from spikenerf.fields import vm_build


def test_the_source_is_the_package_file_and_the_build_compiles_it(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import torch.utils.cpp_extension as ext

    text = resources.files("spikenerf.fields").joinpath("vm_cpu.cpp").read_text(encoding="utf-8")
    assert vm_build.kernel_source() == text
    assert "PYBIND11_MODULE(TORCH_EXTENSION_NAME" in text and "#include <torch/extension.h>" in text
    seen: list[tuple[str, list[str]]] = []
    monkeypatch.setattr(ext, "_get_build_directory", lambda name, verbose: str(tmp_path / name))
    monkeypatch.setattr(ext, "load_inline", lambda name, cpp_sources, **kw: seen.append((name, cpp_sources)))
    monkeypatch.setattr(vm_build, "_find_ninja", lambda: None)
    vm_build._build([], [])
    ((name, sources),) = seen
    assert sources == [text] and name == vm_build._name(vm_build._CFLAGS, [], text)


def test_the_cache_folder_changes_with_the_source_text() -> None:
    flags, text = vm_build._CFLAGS, vm_build.kernel_source()
    assert vm_build._name(flags, []) == vm_build._name(flags, [], text)  # (default: the package's file)
    assert vm_build._name(flags, [], text + "// a comment\n") != vm_build._name(flags, [], text)
    assert vm_build._name(flags, [], text, prefix="ab_") != vm_build._name(flags, [], text)


def test_without_its_source_the_kernel_falls_back_to_grid_sample_once(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setattr(vm_build, "_build", lambda *a: pytest.fail("a build was attempted"))
    monkeypatch.setattr(vm_build, "SOURCE_FILE", "absent.cpp")
    monkeypatch.delenv("SPIKENERF_VM_KERNEL", raising=False)
    monkeypatch.setattr(vm_build, "_MODULE", None)
    monkeypatch.setattr(vm_build, "_FAILED", False)
    vm_build.kernel_source.cache_clear()
    try:
        with pytest.warns(UserWarning, match=r"source absent\.cpp is missing .*using grid_sample") as got:
            assert vm_build.load() is None
            assert vm_build.load() is None  # remembered: no second warning
        assert len(got) == 1
    finally:
        monkeypatch.undo()
        vm_build.kernel_source.cache_clear()  # (the package's file again for the tests after this one)
    assert vm_build.kernel_source().startswith("// The fused CPU kernel")

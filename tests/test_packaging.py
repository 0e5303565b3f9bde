"""The wheel a user installs (``pip install .`` without ``-e``) holds every file of the package: the
modules, the fused CPU kernel's C++ source, the shipped reconstructor weights and their card, ``py.typed``;
and the ``spikenerf`` command.
The editable install of ``make`` and CI reads ``src/`` directly and would not notice a file left out."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
import zipfile
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "spikenerf"


def _package_files() -> set[str]:
    """Every file below ``src/spikenerf`` a wheel must carry, as wheel names (``spikenerf/...``)."""
    names = set()
    for path in PACKAGE.rglob("*"):
        if path.is_file() and "__pycache__" not in path.parts and path.suffix not in {".pyc", ".pyo"}:
            names.add(path.relative_to(PACKAGE.parent).as_posix())
    return names


def _setuptools_new_enough() -> bool:
    if importlib.util.find_spec("pip") is None:
        return False
    try:  # (not imported here: setuptools replaces distutils, which the test process may have loaded)
        major = version("setuptools").split(".")[0]
    except PackageNotFoundError:
        return False
    return major.isdigit() and int(major) >= 77  # the build-system requirement


@pytest.mark.skipif(not _setuptools_new_enough(), reason="needs pip and setuptools>=77 in this environment")
def test_the_wheel_carries_every_package_file_and_the_command(tmp_path: Path) -> None:
    tree = tmp_path / "tree"  # a copy, so that the build's own folders stay out of the checkout
    tree.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE", "MANIFEST.in"):
        shutil.copy2(ROOT / name, tree / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    shutil.copytree(ROOT / "src", tree / "src", ignore=ignore)
    cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "--no-index",
           "-w", str(tmp_path / "dist"), str(tree)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    (wheel,) = (tmp_path / "dist").glob("spikenerf-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        entry_points = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
        scripts = archive.read(entry_points).decode()
    missing = sorted(_package_files() - names)
    assert not missing, f"the wheel leaves out {missing} (pyproject.toml [tool.setuptools.package-data])"
    assert "spikenerf/recon/weights/recon-v1.pt" in names
    assert "spikenerf/fields/vm_cpu.cpp" in names  # the fused CPU kernel's C++ source (vm_build.py)
    assert "spikenerf = spikenerf.cli:main" in scripts

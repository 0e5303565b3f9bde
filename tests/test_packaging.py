"""The wheel a user installs (``pip install .`` without ``-e``) holds every file of the package: the
modules, the fused CPU kernel's C++ source, the shipped reconstructor weights and their card, ``py.typed``;
and the ``spikenerf`` command. So does the source distribution, and the wheel built from it (what
``pip install spikenerf-X.tar.gz`` installs).
The editable install of ``make`` and CI reads ``src/`` directly and would not notice a file left out."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tarfile
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
    # installed versions only, nothing imported or looked up on the import path: setuptools replaces
    # distutils, which the test process may have loaded, and ``find_spec("pip")`` made setuptools' distutils
    # shim stand down for the whole process (a later ``import torch.utils.cpp_extension`` then failed)
    try:
        version("pip")
        major = version("setuptools").split(".")[0]
    except PackageNotFoundError:
        return False
    return major.isdigit() and int(major) >= 77  # the build-system requirement


def _tree(tmp_path: Path) -> Path:
    """A copy of what a build reads, so that the build's own folders stay out of the checkout."""
    tree = tmp_path / "tree"
    tree.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE", "MANIFEST.in"):
        shutil.copy2(ROOT / name, tree / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    shutil.copytree(ROOT / "src", tree / "src", ignore=ignore)
    return tree


def _wheel(source: Path, dist: Path) -> Path:
    """``pip wheel`` of a source tree (offline, in this environment): the wheel's path."""
    cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "--no-index",
           "-w", str(dist), str(source)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    (wheel,) = dist.glob("spikenerf-*.whl")
    return wheel


@pytest.mark.skipif(not _setuptools_new_enough(), reason="needs pip and setuptools>=77 in this environment")
def test_the_sdist_and_its_wheel_carry_every_package_file(tmp_path: Path) -> None:
    tree, dist = _tree(tmp_path), tmp_path / "sdist"
    build = f"from setuptools import build_meta; print(build_meta.build_sdist({str(dist)!r}))"
    cmd = [sys.executable, "-c", build]
    done = subprocess.run(cmd, cwd=tree, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    (sdist,) = dist.glob("spikenerf-*.tar.gz")
    with tarfile.open(sdist) as archive:
        top = archive.getnames()[0].split("/")[0]
        names = {n.split("/", 2)[2] for n in archive.getnames() if n.startswith(f"{top}/src/")}
        safe = {"filter": "data"} if hasattr(tarfile, "data_filter") else {}  # (3.10.12+, 3.11.4+)
        archive.extractall(tmp_path / "unpacked", **safe)  # type: ignore[arg-type]
    missing = sorted(_package_files() - names)
    assert not missing, f"the sdist leaves out {missing} (MANIFEST.in, pyproject.toml package-data)"
    wheel = _wheel(tmp_path / "unpacked" / top, tmp_path / "dist")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
    assert not sorted(_package_files() - names), "the wheel built from the sdist leaves out package files"
    assert "spikenerf/fields/vm_cpu.cpp" in names
    # installed (not editable), the build reads the kernel's source from the installation
    target = tmp_path / "site"
    cmd = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index", "--target", str(target),
           str(wheel)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    probe = "from spikenerf.fields import vm_build as b; print(b.__file__); print(b.kernel_source()[:40])"
    env = {**os.environ, "PYTHONPATH": str(target)}
    cmd = [sys.executable, "-c", probe]
    done = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    where, head = done.stdout.splitlines()
    assert Path(where).is_relative_to(target) and head == (PACKAGE / "fields" / "vm_cpu.cpp").read_text()[:40]


@pytest.mark.skipif(not _setuptools_new_enough(), reason="needs pip and setuptools>=77 in this environment")
def test_the_wheel_carries_every_package_file_and_the_command(tmp_path: Path) -> None:
    wheel = _wheel(_tree(tmp_path), tmp_path / "dist")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        entry_points = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
        scripts = archive.read(entry_points).decode()
    missing = sorted(_package_files() - names)
    assert not missing, f"the wheel leaves out {missing} (pyproject.toml [tool.setuptools.package-data])"
    assert "spikenerf/recon/weights/recon-v1.pt" in names
    assert "spikenerf/fields/vm_cpu.cpp" in names  # the fused CPU kernel's C++ source (vm_build.py)
    assert "spikenerf = spikenerf.cli:main" in scripts

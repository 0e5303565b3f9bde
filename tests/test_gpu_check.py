"""``benchmarks/suites/gpu_check.sh`` (issue 27's GPU checks in parts): its parts run end to end on the CPU at
a tiny size and write the summary; an unknown part stops it with exit 2. The figures it prints on a GPU are
measurements (docs/performance.md)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "suites" / "gpu_check.sh"


def _run(out: Path, work: Path, *parts: str, **extra: str) -> subprocess.CompletedProcess:
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT / "src"),
        "PYTHON": sys.executable,
        "DEVICE": "cpu",
        "SIZE": "16",
        "JOBS": "1",
        "BATCH": "128",
        "SMALL": "64",
        "ITERS": "10",
        "COMPILE": "",
        "WARMUP": "1",
        "STEPS": "1",
        "PSTEPS": "1",
        "VARIANTS": "base static_visible=8+compile-optimizer",
        "GRID": "10",
        "WORK": str(work),
        "OMP_NUM_THREADS": "1",
        **extra,
    }
    cmd = ["bash", str(SCRIPT), str(out), *parts]
    return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)


def test_the_parts_run_on_a_cpu_and_write_their_summary(tmp_path: Path) -> None:
    out, work = tmp_path / "out", tmp_path / "work"
    done = _run(out, work, "data", "train", "profile")
    assert done.returncode == 0, done.stdout + done.stderr
    summary = (out / "summary.txt").read_text()
    for line in ("== data: rc 0", "wrote", "== train: rc 0", "trained 10 iterations", "== profile-base: rc 0",
                 "== profile-static_visible-8+compile-optimizer: rc 0",
                 "static_visible=8 --compile-optimizer:"):  # fmt: skip
        assert line in summary, summary
    assert summary.count("ms/step") >= 4  # two batches × two variants
    assert (work / "orbs16" / "transforms.json").is_file() and (work / "nerf-gt16" / "curves.csv").is_file()
    again = _run(out, work, "data", "composite", "march")  # the dataset is kept between calls
    summary = (out / "summary.txt").read_text()
    assert again.returncode == 0 and "is there" in summary
    assert "== composite: rc 0" in summary and "| torch |" in summary and "| scatter |" in summary, summary
    assert "== march: rc 0" in summary and "| static |" in summary, summary


def test_the_default_spike_method_trains_and_profiles_in_its_own_run(tmp_path: Path) -> None:
    out, work = tmp_path / "out", tmp_path / "work"
    done = _run(out, work, "data", "train", "fast", "profile", METHOD="spike-integral", VARIANTS="base",
                LOOKUP="auto")  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    summary = (out / "summary.txt").read_text()
    assert "method=spike-integral" in summary and "== profile-base: rc 0" in summary, summary
    assert summary.count("spike-integral batch") == 2, summary  # the profile resumed the method's own run
    assert "== fast: rc 0" in summary and summary.count("trained 10 iterations") == 2, summary
    assert (work / "spike-integral16" / "curves.csv").is_file()
    fast = (work / "spike-integral16-fast" / "config.yaml").read_text()
    assert "static_samples: 64" in fast and "lookup: auto" in fast, fast


def test_the_occupancy_and_optimiser_parts_time_both_ways(tmp_path: Path) -> None:
    out = tmp_path / "out"
    done = _run(out, tmp_path / "work", "occupancy", "optim")
    assert done.returncode == 0, done.stdout + done.stderr
    summary = (out / "summary.txt").read_text()
    assert "== occupancy: rc 0" in summary and "points / lattice:" in summary, summary
    assert "== optim: rc 0" in summary and "grid R 10:" in summary and "compiled / eager speed" in summary


def test_an_unknown_part_stops_with_exit_2(tmp_path: Path) -> None:
    done = _run(tmp_path / "out", tmp_path / "work", "everything")
    assert done.returncode == 2 and "unknown part" in done.stdout


def test_every_test_file_the_parts_name_exists() -> None:
    """The `kernels` and `tests` parts run only on a GPU host: a renamed test file must fail here first."""
    import re

    named = set(re.findall(r"tests/[\w/]+\.py", SCRIPT.read_text()))
    assert {"tests/test_vm_triton.py", "tests/test_cuda.py"} <= named
    assert all((ROOT / path).is_file() for path in named), sorted(
        p for p in named if not (ROOT / p).is_file()
    )

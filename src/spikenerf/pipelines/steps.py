"""One benchmark step: a recorded ``spikenerf`` command run as a subprocess, by the local executor
(:mod:`spikenerf.pipelines.benchmark`) and inside Ray tasks (:mod:`spikenerf.pipelines.ray_executor`)."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
import time
from pathlib import Path

from spikenerf.core.errors import InputError

#: a step's child process dies with the process that started it (Linux), so a killed Ray worker or benchmark
#: leaves no orphan writing into a cell that is then retried
_PRCTL = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None


def _die_with_parent() -> None:
    if _PRCTL is not None:
        _PRCTL(1, 9)  # PR_SET_PDEATHSIG, SIGKILL


def run_step(
    command: list[str], log: list[dict], output: Path | None = None, threads: int | None = None
) -> None:
    """Run one ``spikenerf`` step; its output goes to the terminal, or appended to ``output``."""
    env = None if threads is None else {**os.environ, "OMP_NUM_THREADS": str(threads)}
    start = time.perf_counter()
    if output is None:
        rc = subprocess.run(command, check=False, env=env, preexec_fn=_die_with_parent).returncode
    else:
        output.parent.mkdir(parents=True, exist_ok=True)
        with output.open("a") as sink:
            done = subprocess.run(command, check=False, env=env, stdout=sink, stderr=subprocess.STDOUT,
                                  preexec_fn=_die_with_parent)  # fmt: skip
        rc = done.returncode
    log.append({"command": command[2:], "seconds": round(time.perf_counter() - start, 2), "rc": rc})
    if rc != 0:
        where = f" (output in {output})" if output is not None else ""
        raise InputError(f"step failed with exit code {rc}: spikenerf {' '.join(command[3:])}{where}")

"""A benchmark job (:class:`Job`: a dataset or a cell, its commands and its folder) and one step of it: a
recorded ``spikenerf`` command run as a subprocess, by the local executor
(:mod:`~spikenerf.pipelines.benchmark.local_executor`) and inside Ray tasks
(:mod:`~spikenerf.pipelines.benchmark.ray_executor`)."""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spikenerf.core.errors import InputError

#: a step's child process dies with the process that started it (Linux), so a killed Ray worker or benchmark
#: leaves no orphan writing into a cell that is then retried
_PRCTL = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None


@dataclass(frozen=True)
class Job:
    """One unit of work, with paths relative to the benchmark folder.

    ``commands(root)`` gives the ``spikenerf`` argv lists for a benchmark folder at ``root``; they run in
    order (into ``root/logs/<name>.log`` unless the local executor runs one job at a time). The job is
    finished when ``root/done`` exists; ``folder`` is what it writes; ``needs`` names the job that must finish
    first (a cell's dataset; None for a dataset).
    """

    name: str
    commands: Callable[[Path], list[list[str]]]
    folder: str
    done: str
    needs: str | None = None


def _die_with_parent() -> None:
    if _PRCTL is not None:
        _PRCTL(1, 9)  # PR_SET_PDEATHSIG, SIGKILL


#: "1" in every step's environment: the step's own "aborted"/"terminated" line then gives no hint of how to
#: continue it alone (``train --resume``): the benchmark's line says how to continue the whole (run it again)
STEP_ENV = "SPIKENERF_BENCHMARK_STEP"

#: the steps running now (a benchmark interrupted by SIGTERM or Ctrl-C stops them: :func:`stop_running`)
_RUNNING: set[subprocess.Popen] = set()
_RUNNING_LOCK = threading.Lock()


def _run(command: list[str], env: dict | None, sink: Any = None) -> int:
    """Run ``command`` to its end (output to ``sink``, else the terminal), registered in :data:`_RUNNING`."""
    out = {} if sink is None else {"stdout": sink, "stderr": subprocess.STDOUT}
    with _RUNNING_LOCK:
        process = subprocess.Popen(command, env=env, preexec_fn=_die_with_parent, **out)
        _RUNNING.add(process)
    try:
        return process.wait()
    finally:
        with _RUNNING_LOCK:
            _RUNNING.discard(process)


def stop_running() -> None:
    """Send SIGTERM to every step running now (each unwinds and exits 143; its job then fails)."""
    with _RUNNING_LOCK:
        for process in _RUNNING:
            with contextlib.suppress(OSError):
                process.send_signal(signal.SIGTERM)


def run_step(
    command: list[str], log: list[dict], output: Path | None = None, threads: int | None = None
) -> None:
    """Run one ``spikenerf`` step; its output goes to the terminal, or appended to ``output``."""
    env = {**os.environ, STEP_ENV: "1", **({} if threads is None else {"OMP_NUM_THREADS": str(threads)})}
    start = time.perf_counter()
    if output is None:
        rc = _run(command, env)
    else:
        output.parent.mkdir(parents=True, exist_ok=True)
        with output.open("a") as sink:
            rc = _run(command, env, sink)
    log.append({"command": command[2:], "seconds": round(time.perf_counter() - start, 2), "rc": rc})
    if rc != 0:
        where = f" (output in {output})" if output is not None else ""
        raise InputError(f"step failed with exit code {rc}: spikenerf {' '.join(command[3:])}{where}")

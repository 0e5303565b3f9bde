"""Fail points for the kill-and-resume tests: ``SPIKENERF_KILL_AT=NAME:N`` SIGKILLs the process at the
N-th time it passes the point ``NAME`` (a real SIGKILL: no cleanup, no ``finally``, like ``kill -9``);
``NAME:N:STOP`` sends SIGSTOP instead (the process freezes, holding its locks, until SIGCONT).

Points: ``simulate.render`` (after each cached frame), ``simulate.spikes`` (after each step fed to the
cameras), ``simulate.publish`` (a finished work folder, before it is renamed), ``import.keyframe`` (after each
keyframe reconstruction), ``import.spikes`` (after each chunk of steps copied into the dataset),
``import.publish`` (like ``simulate.publish``), ``train.iteration`` (after
each optimiser step), ``render.view`` (after each cached view), ``render.spikes`` (after each saved spike
state) and ``write:NAME`` (an atomic write of a file called NAME, after its temporary is
complete and before it replaces the file). Unset, a point costs one dictionary lookup.
"""

from __future__ import annotations

import os
import signal

KILL_ENV = "SPIKENERF_KILL_AT"
_hits: dict[str, int] = {}


def failpoint(name: str) -> None:
    """Count a pass through ``name``; SIGKILL this process on the pass named by ``SPIKENERF_KILL_AT``."""
    spec = os.environ.get(KILL_ENV)
    if not spec:
        return
    point, _, count = spec.removesuffix(":STOP").rpartition(":")
    if point != name:
        return
    _hits[name] = _hits.get(name, 0) + 1
    if str(_hits[name]) == count:
        os.kill(os.getpid(), signal.SIGSTOP if spec.endswith(":STOP") else signal.SIGKILL)

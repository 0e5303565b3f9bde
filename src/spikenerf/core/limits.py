"""Resource limits: refuse a job whose estimated memory or disk exceeds what the machine has, before work.

Each command estimates its peak memory and the disk it will write from its arguments (the estimators live
beside the code they describe, e.g. ``capture/simulate.py``); :func:`check_resources` compares them with the
available memory (``psutil``, else ``/proc/meminfo``) and the free space under the output folder. The global
``spikenerf --no-limits`` (environment ``SPIKENERF_NO_LIMITS=1``, inherited by the runs that benchmark and
demo start) skips the check for users who know better (swap, memory that frees up later).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from spikenerf.core.errors import InputError

NO_LIMITS_ENV = "SPIKENERF_NO_LIMITS"
GIB = 1024**3


def limits_disabled() -> bool:
    """True when ``--no-limits`` was given (``SPIKENERF_NO_LIMITS`` set to a non-empty value other than 0)."""
    return os.environ.get(NO_LIMITS_ENV, "") not in ("", "0")


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (None when unknown)."""
    try:
        import psutil

        return int(psutil.virtual_memory().available)
    except ImportError:
        pass
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def free_disk(path: str | Path) -> int | None:
    """Free bytes on the file system that would hold ``path`` (its nearest existing ancestor)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    folder = p if p.is_dir() else p.parent
    try:
        if hasattr(os, "statvfs") and os.statvfs(folder).f_blocks == 0:
            return None  # a file system that reports no size (ramfs, some FUSE mounts): free space unknown
        return int(shutil.disk_usage(folder).free)
    except OSError:
        return None


def human(n: float) -> str:
    """Bytes as a short human string (``1.5 GiB``, ``300 MiB``, ``12 KiB``)."""
    for unit, size in (("TiB", 1024**4), ("GiB", GIB), ("MiB", 1024**2), ("KiB", 1024)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} B"


def check_resources(memory: float, disk: float, out: str | Path, params: str) -> None:
    """InputError when ``memory`` or ``disk`` (estimated bytes) exceeds what is available.

    Args:
        memory: estimated peak memory. disk: estimated bytes written under ``out``.
        out: the output folder (its file system's free space is checked).
        params: the parameters that set the size, named in the message (e.g. ``width/height/frames``; the
            CLI shows their flags).
    """
    if limits_disabled():
        return
    _check(params, "memory", memory, available_memory())
    _check(params, "disk space", disk, free_disk(out))


def check_memory(memory: float, params: str) -> None:
    """:func:`check_resources` for a step that writes nothing: InputError (naming ``params``) when the
    estimated peak ``memory`` exceeds the memory available."""
    if not limits_disabled():
        _check(params, "memory", memory, available_memory())


def _check(params: str, what: str, need: float, have: int | None) -> None:
    if have is not None and need > have:
        raise InputError(
            f"{params}: this needs about {human(need)} of {what}, but only {human(have)} is available; "
            "lower them, or pass no_limits to try anyway",
            param=(*params.split("/"), "no_limits"),
        )

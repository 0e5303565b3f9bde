"""Lazy ``bpy`` import and silencing of Blender's C-level stdout chatter."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from types import ModuleType

from spikenerf.core.errors import InputError

INSTALL_HINT = "Blender is not installed: pip install 'spikenerf[blender]'"


def import_bpy() -> ModuleType:
    """Return the ``bpy`` module, or raise :class:`InputError` with the install hint when it is missing."""
    try:
        with quiet(stderr=True):
            import bpy
    except ImportError as err:
        raise InputError(f"{INSTALL_HINT} ({err})") from err
    return bpy


@contextlib.contextmanager
def quiet(stderr: bool = False) -> Iterator[None]:
    """Redirect file descriptor 1 (and 2 if ``stderr``) to /dev/null around Blender calls.

    Blender prints render progress from C, bypassing ``sys.stdout``; progress bars (stderr) stay readable.
    """
    fds = (1, 2) if stderr else (1,)
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        saved = [os.dup(fd) for fd in fds]
    except OSError:  # no such descriptor (embedded interpreter): nothing to silence
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in fds:
            os.dup2(devnull, fd)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, old in zip(fds, saved, strict=True):
            os.dup2(old, fd)
            os.close(old)
        os.close(devnull)

"""Atomic writes: write to a temporary sibling, then ``os.replace``, so readers never see half a file."""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
from collections.abc import Iterator
from pathlib import Path

from spikenerf.core.errors import InputError
from spikenerf.core.faults import failpoint


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on error it is removed.

    Works for files and for directories (a finished directory is swapped in whole). Parent folders it had
    to create are removed again on error, where still empty.
    """
    path = Path(path)
    created = missing_folders(path.parent)
    path.parent.mkdir(parents=True, exist_ok=True)
    # named, not created: the caller makes it, so an interrupt at any point finds ``tmp`` set and removes
    # it (mkstemp's file, made before its name is returned, was left by a Ctrl-C that landed in between)
    tmp: Path | None = _fresh(path, ".tmp")
    done = False
    try:
        yield tmp
        failpoint(f"write:{path.name}")
        if tmp.is_dir() and path.is_dir():  # swapped out under a fresh name: never a user's .NAME.old
            old = _fresh(path, ".old.tmp")
            try:
                path.rename(old)
                tmp.rename(path)
            except BaseException:  # (an interrupt between the renames): the previous folder goes back
                if old.is_dir() and not (path.exists() or path.is_symlink()):
                    old.rename(path)
                raise
            shutil.rmtree(old, ignore_errors=True)
        elif path.is_dir() and not path.is_symlink():  # (os.replace would name the temporary)
            raise InputError("is a folder, not a file: not replacing it", path=path)
        else:
            os.replace(tmp, path)
        done = True
    finally:
        if tmp is None:
            pass
        elif tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        elif tmp.exists():
            tmp.unlink()
        if not done:
            remove_empty(created)


def _fresh(path: Path, suffix: str) -> Path:
    """A free name ``.NAME.XXXXXXXX<suffix>`` beside ``path`` (eight random characters, as ``mkstemp``'s:
    :data:`TEMP_NAME` matches it), not created."""
    while True:
        token = "".join(secrets.choice("abcdefghijklmnopqrstuvwxyz0123456789_") for _ in range(8))
        fresh = path.parent / f".{path.name}.{token}{suffix}"
        if not (fresh.exists() or fresh.is_symlink()):
            return fresh


def missing_folders(folder: Path) -> list[Path]:
    """The folders of ``folder``'s path that do not exist yet, deepest first (``folder`` itself included)."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return missing


def remove_empty(folders: list[Path]) -> None:
    """Remove ``folders`` (deepest first) while they are empty; stop at the first that is not."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            return


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    write_bytes_atomic(path, text.encode("utf-8"))


#: a temporary of :func:`atomic_path`: ``.NAME.XXXXXXXX.tmp`` (``mkstemp``'s 8 random characters), or the
#: ``.NAME.XXXXXXXX.old.tmp`` a folder swap moves the old folder to
TEMP_NAME = re.compile(r"\..+\.[a-z0-9_]{8}(\.old)?\.tmp")


def clean_stale_temps(folder: str | Path) -> list[str]:
    """Delete the temporaries (``.NAME….tmp`` files or folders) a killed writer left in ``folder``.

    Call it only while holding the folder's writer lock (``core/lock.py``): a live writer's temporaries
    look the same. Returns the names removed.
    """
    folder = Path(folder)
    removed = []
    for tmp in folder.glob(".*.tmp") if folder.is_dir() else []:
        if not TEMP_NAME.fullmatch(tmp.name):  # only the names atomic_path makes, never a user's .x.tmp
            continue
        shutil.rmtree(tmp, ignore_errors=True) if tmp.is_dir() else tmp.unlink(missing_ok=True)
        removed.append(tmp.name)
    return removed

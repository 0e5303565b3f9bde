"""Replacing an output folder whole, and undoing a failed command's writes into a fresh one.

A finished folder is swapped into its place by :func:`replace_dir`: the previous folder is first renamed to
``.<name>.old`` beside it and marked ``retired`` (:func:`retire`), so that a replacement killed between its
renames is finished by :func:`recover_retired` and a user's own ``.<name>.old`` is never deleted or moved
into place. A command that writes into its output in place records what the folder was before
(:func:`fresh_state`) and, when it fails, removes what it wrote there (:func:`discard_fresh`). Which folders
may be replaced at all is :mod:`spikenerf.core.marker`'s to say (``check_output``).
"""

from __future__ import annotations

import contextlib
import json
import shutil
import sys
from pathlib import Path

from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError
from spikenerf.core.marker import MARKER, is_retired, old_path, read_marker


def retire(out: Path) -> Path:
    """Swap the folder ``out`` out of the way (to :func:`old_path`, marked retired); returns that path.
    A retired leftover there is deleted first; anything else there is an InputError, untouched."""
    old = old_path(out)
    if old.exists() or old.is_symlink():
        if not is_retired(old):
            raise InputError("is in the way of a replacement and spikenerf did not write it; move it", old)
        _delete_retired(old)
    entry = read_marker(out)
    write_text_atomic(out / MARKER, json.dumps({**entry, "retired": True}) + "\n")
    try:
        out.rename(old)
    except BaseException:  # (a folder in use, another file system…): it stays in place, so not retired
        if out.is_dir() and not old.exists():
            write_text_atomic(out / MARKER, json.dumps(entry) + "\n")
        raise
    return old


def recover_retired(out: Path) -> None:
    """Finish a replacement killed between its renames (call it holding the lock): a retired ``.<out>.old``
    is restored when ``out`` is missing, else deleted. A ``.<out>.old`` spikenerf did not retire is left."""
    old = old_path(out)
    if not is_retired(old):
        return
    if out.exists() or out.is_symlink():
        _delete_retired(old)
        return
    entry = {k: v for k, v in read_marker(old).items() if k != "retired"}
    write_text_atomic(old / MARKER, json.dumps(entry) + "\n")
    old.rename(out)


def fresh_state(out: Path) -> str | None:
    """What ``out`` is before a command writes into it in place: ``"absent"``, ``"empty"`` (a folder with
    nothing in it, e.g. the user's own) or None (it holds something: not the command's to remove)."""
    if not (out.exists() or out.is_symlink()):
        return "absent"
    if out.is_dir() and not out.is_symlink() and not any(out.iterdir()):
        return "empty"
    return None


def discard_fresh(out: Path, state: str | None) -> None:
    """Undo a failed command's writes into ``out``, which was ``state`` (:func:`fresh_state`) before it: an
    absent folder is removed, an empty one emptied again (the user's folder stays); else nothing."""
    if state == "absent":
        shutil.rmtree(out, ignore_errors=True)
    elif state == "empty" and out.is_dir():
        for child in out.iterdir():
            shutil.rmtree(child, ignore_errors=True) if child.is_dir() else child.unlink(missing_ok=True)


def _delete_retired(old: Path) -> None:
    """Delete a retired copy left by an earlier replacement; InputError naming it where a file in it cannot be
    deleted (an immutable or read-only file: the user's to remove)."""
    try:
        shutil.rmtree(old)
    except OSError as err:
        raise InputError(
            f"a copy an earlier replacement left cannot be deleted ({err.strerror or err}: "
            f"{getattr(err, 'filename', '') or old}); delete it yourself",
            path=old,
        ) from err


def replace_dir(work: Path, out: Path) -> None:
    """Rename the finished ``work`` folder to ``out`` (an existing ``out`` is retired, then deleted); a
    replacement killed between its renames is finished by :func:`recover_retired`."""
    old = retire(out) if out.exists() or out.is_symlink() else None
    work.rename(out)
    if old is not None:
        _remove_retired(old, out)


def _remove_retired(old: Path, out: Path) -> None:
    """Delete the retired ``old`` copy of ``out``, which is already in place: where a file in it cannot be
    deleted (a read-only or immutable file), one warning line, and ``old`` keeps its retired marker so that
    the next replacement deletes it (it is not the user's)."""
    entry = read_marker(old)
    try:
        shutil.rmtree(old)
    except OSError as err:
        if old.is_dir():
            with contextlib.suppress(OSError):
                write_text_atomic(old / MARKER, json.dumps(entry) + "\n")
        print(
            f"spikenerf: warning: {out} is in place, but the copy it replaced could not be deleted "
            f"({err.strerror or err}: {getattr(err, 'filename', '') or old}); delete {old} yourself",
            file=sys.stderr,
        )

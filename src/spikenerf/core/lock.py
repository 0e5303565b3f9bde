"""One writer per output folder: an advisory ``flock`` on ``.<name>.lock`` beside the folder.

The lock file records the holder's PID, so a second writer is refused in one line that names the folder and
that process. The kernel drops a ``flock`` when its process dies (even by SIGKILL), so the file a killed run
leaves behind is a stale lock that the next writer takes over: nobody holds the ``flock`` any more. After
locking, the holder checks that the path still names the file it locked (a releasing holder unlinks it), so
two writers can never both hold one folder.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
from collections.abc import Iterator
from pathlib import Path

from spikenerf.core.atomic import missing_folders, remove_empty
from spikenerf.core.errors import InputError

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Unix: no locking
    fcntl = None  # type: ignore[assignment]


def lock_path(folder: str | Path) -> Path:
    """The lock file of an output folder: ``.<name>.lock`` beside the folder it resolves to (``d/../out``,
    ``out`` and a symbolic link to ``out`` share one lock)."""
    try:
        folder = Path(folder).resolve()
    except RuntimeError as err:  # a link loop (Python < 3.13; later ones raise OSError)
        raise InputError(f"cannot resolve the path ({err})", path=folder) from err
    return folder.parent / f".{folder.name}.lock"


def holder(folder: str | Path) -> int | None:
    """The PID written in ``folder``'s lock file (None when there is none or it is unreadable)."""
    try:
        return int(lock_path(folder).read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def _check_ours(fd: int, path: Path, folder: Path, param: str) -> None:
    """InputError (closing ``fd``) unless the open lock file is a regular file that is empty or holds one
    PID line, as spikenerf writes it: a user's file of that name is neither truncated nor deleted."""
    info = os.fstat(fd)
    head = os.pread(fd, 64, 0) if stat.S_ISREG(info.st_mode) and info.st_size <= 64 else b"x"
    if not re.fullmatch(rb"(\d+\n)?", head):
        os.close(fd)
        raise InputError(
            f"{param}: {path.name} beside it is not spikenerf's lock file (it holds other data); move it",
            path=folder,
            param=param,
        )


def _acquire(path: Path, folder: Path, param: str) -> int:
    """An open descriptor of ``path`` holding an exclusive ``flock``; InputError while another holds it."""
    while True:
        try:  # never through a symbolic link: its target is not ours to truncate
            fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
        except OSError as err:
            if err.errno != errno.ELOOP:
                raise
            raise InputError(
                f"{param}: {path.name} beside it is a symbolic link, not spikenerf's lock file; move it",
                path=folder,
                param=param,
            ) from None
        try:
            _check_ours(fd, path, folder, param)
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            pid = holder(folder)
            who = f"process {pid}" if pid is not None else "another process"
            raise InputError(
                f"{param}: in use by {who} (another spikenerf writer); wait for it to finish or stop it",
                path=folder,
                param=param,
            ) from None
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # the previous holder unlinked the file between our open and our lock: try again


@contextlib.contextmanager
def output_lock(folder: str | Path, param: str = "out") -> Iterator[Path]:
    """Hold the writer lock of ``folder`` (which need not exist yet) for the ``with`` block.

    Raises InputError (naming ``param``, the folder and the holder's PID) when another live process holds
    it; a lock left by a dead process is taken over. Re-entrant in one process is not supported.
    """
    folder = Path(folder)
    path = lock_path(folder)
    if fcntl is None:
        yield path
        return
    made = missing_folders(path.parent)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(
            f"{param}: a parent of this path is a regular file", path=folder, param=param
        ) from None
    try:
        fd = _acquire(path, folder, param)
    except BaseException:
        remove_empty(made)  # a refusal leaves nothing behind, not even the folders above --out
        raise
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield path
    finally:
        with contextlib.suppress(OSError):
            path.unlink()
        os.close(fd)
        remove_empty(made)

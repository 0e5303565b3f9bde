"""Which folders spikenerf wrote: a ``.spikenerf`` marker file, so that nothing else is ever replaced.

Every output folder (dataset, run, render, benchmark, recon pairs and runs, reconstructed frames, the
scores of ``recon-eval``) gets the marker with its kind; a finished dataset's marker also lists its files.
Outputs are never written into a folder of another kind (e.g. ``render --out`` into a dataset) or into a
non-empty folder without the marker. Folders written before the marker existed are recognised by their
files, but only a marked folder whose files are exactly the ones its marker lists is ever replaced
(``--overwrite``): a look-alike, a link, or a dataset holding the user's notes or a trained run is
refused. The swapped-out ``.<name>.old`` of a replacement carries a ``retired`` marker, so a user's own
``.<name>.old`` is never deleted or moved into place (the replacement: :mod:`spikenerf.core.replacement`).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError

MARKER = ".spikenerf"
KINDS = ("dataset", "run", "render", "benchmark", "pairs", "recon", "frames", "scores")
#: files that identify a folder of each kind written before the marker existed
_LEGACY = {
    "dataset": ("transforms.json", "config.yaml"),
    "run": ("checkpoint.pt", "config.yaml"),
    "render": ("render.json",),
    "benchmark": ("results.json", "benchmark.json"),  # a results.json alone may be another tool's
    "pairs": ("manifest.json",),
    "recon": ("checkpoint.pt", "config.json"),
}


def _inventory(folder: Path) -> list[str]:
    """Every file (and link) under ``folder``, relative, except the marker, and every empty folder, as
    ``name/`` (a user's empty folder is theirs too: ``--overwrite`` must not delete it)."""
    found = []
    for base, dirs, files in os.walk(folder):
        rel = Path(base).relative_to(folder)
        found += [str(rel / n) for n in files + [d for d in dirs if (Path(base) / d).is_symlink()]]
        if not dirs and not files and rel != Path("."):
            found.append(f"{rel}/")
    return sorted(f for f in found if f != MARKER)


def mark(folder: str | Path, kind: str, files: bool | list[str] = False, leaving: str | None = None) -> None:
    """Write the marker of ``kind`` into ``folder`` (created if needed); ``files``: also list every file in
    it (True: a finished folder that may later be replaced whole; ``leaving``: but not those in this
    subfolder, which the command deletes before it publishes the folder) or these (the files a command
    wrote)."""
    if kind not in KINDS:
        raise ValueError(f"unknown folder kind {kind!r}")
    entry: dict = {"kind": kind}
    if files is not False:
        before = read_marker(Path(folder))  # a list extended from an older marker keeps its meaning
        entry["files"] = _inventory(Path(folder)) if files is True else sorted(files)
        if leaving is not None:
            entry["files"] = [f for f in entry["files"] if not f.startswith(f"{leaving}/")]
        # the list names empty folders too (older markers did not)
        entry["empty_dirs"] = files is True or before.get("empty_dirs", "files" not in before) is True
    write_text_atomic(Path(folder) / MARKER, json.dumps(entry) + "\n")


def listed(folder: str | Path) -> list[str]:
    """The files ``folder``'s marker lists as spikenerf's ([] when none)."""
    files = read_marker(Path(folder)).get("files")
    return [f for f in files if isinstance(f, str)] if isinstance(files, list) else []


def read_marker(folder: Path) -> dict:
    """The object in ``folder``'s marker ({} where it has none, or one that does not read back as one)."""
    try:
        data = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError, RecursionError):
        return {}
    return data if isinstance(data, dict) else {}


def marker_problem(folder: str | Path) -> str | None:
    """What is wrong with ``folder``'s marker, in words; None where it has none or one that reads back (an
    object naming one of :data:`KINDS`, its ``files`` names). The guards take a damaged one for none."""
    path = Path(folder) / MARKER
    if not (path.exists() or path.is_symlink()):
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError) as err:
        return f"unreadable ({type(err).__name__}: {err})"
    if not isinstance(data, dict) or data.get("kind") not in KINDS:
        return f"expected an object whose 'kind' is one of {', '.join(KINDS)}, found {data!r:.60}"
    if not isinstance(files := data.get("files", []), list) or not all(isinstance(f, str) for f in files):
        return f"field 'files': expected a list of file names, found {files!r:.40}"
    return None


def folder_kind(folder: str | Path) -> str | None:
    """The kind of a folder spikenerf wrote (from its marker, else its files), or None."""
    folder = Path(folder)
    if not folder.is_dir():
        return None
    kind = read_marker(folder).get("kind")
    if kind in KINDS:
        return kind
    for kind, names in _LEGACY.items():
        if all((folder / name).is_file() for name in names):
            return kind
    return None


def strangers(folder: Path) -> list[str]:
    """What ``folder`` holds beyond the files its marker lists (all of it when the marker lists none)."""
    entry = read_marker(folder)
    listed = entry.get("files")
    have = _inventory(folder)
    if entry.get("empty_dirs") is not True:  # a marker from before empty folders were listed
        have = [f for f in have if not f.endswith("/")]
    if not isinstance(listed, list):
        return have
    return [f for f in have if f not in set(listed)]


def old_path(out: Path) -> Path:
    """Where a replacement swaps out the previous ``out``: ``.<name>.old`` beside it."""
    return out.with_name(f".{out.name}.old")


def is_retired(old: Path) -> bool:
    """Whether ``old`` is a folder that a replacement of spikenerf swapped out (not the user's)."""
    return old.is_dir() and not old.is_symlink() and read_marker(old).get("retired") is True


def check_output(
    path: str | Path, kind: str, param: str = "out", overwrite: bool = False, replace: bool = False
) -> None:
    """InputError unless ``path`` may receive output of ``kind``.

    Accepted: a path that does not exist (its parents must be folders), an empty folder, or a folder that
    spikenerf wrote as ``kind``; with ``overwrite=False`` an existing output of ``kind`` is refused too
    (callers that resume or update in place pass ``overwrite=True``). ``replace``: the caller replaces the
    folder whole, so it must not be a link, must carry our marker and hold only the files it lists, and a
    ``.<name>.old`` beside it must be one spikenerf retired. The folder that will hold it (and the folder
    itself, when it exists) must take new files (:func:`check_writable`).
    """
    path = Path(path)
    for parent in path.absolute().parents:
        _check_parent(parent, path, param)
    _check_container(path, kind, param)
    if replace:
        _check_replace_target(path, param)
    if replace and path.is_symlink():
        raise InputError(
            f"{param}: is a symbolic link; spikenerf replaces an output folder whole and will not replace "
            "a link: give the folder it points to",
            path=path,
            param=param,
        )
    if not (path.exists() or path.is_symlink()):
        check_writable(path, param)
        return
    if not path.is_dir():
        raise InputError(
            f"{param}: a file is in the way (expected a folder); not replacing it", path=path, param=param
        )
    found = folder_kind(path)
    if found is None and any(path.iterdir()):
        raise InputError(
            f"{param}: the folder holds files spikenerf did not write (no {MARKER} marker); "
            "refusing to write into or replace it",
            path=path,
            param=param,
        )
    if found is not None and found != kind:
        raise InputError(
            f"{param}: this is a {found} folder, not a {kind} folder; choose another", path=path, param=param
        )
    if found == kind and not overwrite:
        raise InputError("output already exists; pass overwrite to replace it", path=path, param="overwrite")
    if replace and any(path.iterdir()):
        _check_replaceable(path, kind, param)
    check_writable(path, param)


#: the kinds of output that a marked dataset or run may hold in a subfolder (none in a dataset, whose
#: ``--overwrite`` refuses files it did not list; renders in a run); other kinds may hold any: none of their
#: writers removes what it did not write (a render, a frame folder, a pair or recon-train folder each
#: replace only their own files)
HOLDS = {"dataset": set(), "run": {"render"}}


def owned(folder: str | Path) -> bool:
    """Whether ``folder`` carries spikenerf's marker file (not only looks like an output of an older one)."""
    return (Path(folder) / MARKER).is_file()


def _check_container(path: Path, kind: str, param: str) -> None:
    """InputError when the nearest folder above ``path`` that spikenerf marked may not hold a ``kind``
    output (:data:`HOLDS`: a run inside a dataset would make the dataset hold a stranger). Links and ``..``
    are resolved first: ``DS/../DS`` is DS itself, and a link into a dataset lies inside it."""
    for parent in _resolved(path).parents:
        found = read_marker(parent).get("kind") if owned(parent) else None
        if found is None:
            continue
        if found in HOLDS and kind not in HOLDS[found]:
            raise InputError(
                f"{param}: lies inside the {found} folder {parent}; write the {kind} output elsewhere",
                path=path,
                param=param,
            )
        return


def check_inputs_outside(out: str | Path, inputs: list[str | Path | None], param: str = "out") -> None:
    """InputError (naming ``param``) when an input file or folder of ``inputs`` (None: absent) is the
    output folder ``out`` or lies inside it: the writer replaces ``out`` whole and would delete it."""
    where = _resolved(Path(out))
    for given in inputs:
        if given is None:
            continue
        source = _resolved(Path(given))
        if source == where or where in source.parents:
            raise InputError(
                f"{param}: holds the input {given}, which replacing the folder would delete; write to "
                "another folder",
                path=out,
                param=param,
            )


def _check_replace_target(path: Path, param: str) -> None:
    """InputError when a folder that is replaced whole cannot be: a path without a name of its own (``.``, or
    one ending in ``..``: its work folder and retired copy, named after it, would land inside it; the CLI
    gives the folder's real path instead), or the current folder or one holding it (the replacement would
    swap it out from under the shell, and the retired copy the shell stands in is then deleted)."""
    if path.name in ("", ".."):
        raise InputError(f"{param}: give the folder by its name, not as {path}", path=path, param=param)
    try:
        cwd = Path.cwd()
    except OSError:  # the current folder was deleted: it is not this one
        return
    where = _resolved(path)
    if where.is_dir() and (where == cwd or where in cwd.parents):
        raise InputError(
            f"{param}: is the current folder or holds it; spikenerf replaces an output folder whole (it is "
            "moved away, then deleted): run the command from outside it",
            path=path,
            param=param,
        )


def _check_parent(parent: Path, path: Path, param: str) -> None:
    """InputError when ``parent`` of the output ``path`` exists as something other than a folder."""
    if parent.exists() and not parent.is_dir():
        raise InputError(f"{param}: {parent} is a regular file, not a folder", path=path, param=param)


def check_writable(path: str | Path, param: str = "out", file: bool = False) -> None:
    """InputError (naming ``param`` and ``path``) when the output ``path`` cannot be created: the nearest
    existing folder above it (where its lock, temporaries and parents go), and ``path`` itself when it is an
    existing folder, must be writable by this user on a writable file system that stores files; a virtual
    one such as ``/proc`` or ``/sys`` does not. Checked before any size estimate, so that such a path is
    not blamed on the free disk space (a virtual file system reports none). A folder output that is a link
    is checked at its target (where ``lock_path`` puts the lock); a ``file`` output's link is replaced
    itself, so only its parent folder's links are followed; a folder in its place is refused."""
    path = Path(path)
    path = _resolved(path.parent) / path.name if file else _resolved(path)
    if file and path.is_dir() and not path.is_symlink():
        raise InputError(f"{param}: is a folder, not a file: not replacing it", path=path, param=param)
    base = path.parent
    while not base.exists() and base != base.parent:
        base = base.parent
    for folder in (base, path) if path.is_dir() else (base,):
        problem = _unwritable(folder)
        if problem is not None:
            raise InputError(f"{param}: cannot write there: {folder} {problem}", path=path, param=param)


def _resolved(path: Path) -> Path:
    """``path`` with its links resolved (a link loop: as it is; the write will name the loop)."""
    try:
        return path.resolve()
    except (OSError, RuntimeError):
        return path.absolute()


def _unwritable(folder: Path) -> str | None:
    """Why no file can be created in the existing ``folder`` (None: it can, or it cannot be told)."""
    if not folder.is_dir() or not hasattr(os, "statvfs"):
        return None
    try:
        fs = os.statvfs(folder)
    except OSError:
        return None
    if fs.f_flag & os.ST_RDONLY:
        return "is on a read-only file system"
    if not os.access(folder, os.W_OK | os.X_OK):
        return "is not writable by this user (no permission)"
    if fs.f_blocks == 0:  # reports no size: /proc, /sys, cgroup; but also ramfs and some FUSE mounts
        try:  # so try: a virtual file system refuses the file, ramfs takes it
            fd, probe = tempfile.mkstemp(prefix=".spikenerf-probe-", dir=folder)
        except OSError:
            return "is on a virtual file system that cannot hold files (like /proc or /sys)"
        os.close(fd)
        os.unlink(probe)
    return None


def check_file_output(
    path: str | Path, param: str = "out", overwrite: bool = False, within: tuple[str, ...] = ()
) -> None:
    """InputError unless ``path`` may receive a single output file: its parents must be folders, none of
    them marked as one that spikenerf wrote (a dataset, a run, a frame folder…: a file added there would be
    a stranger in it, or replace one of its own) unless the nearest marked one is of a kind in ``within``
    (``export`` into a run, whose own files are never .ply and which no command replaces or empties), the
    folder must take new files (:func:`check_writable`), and an existing file is replaced only with
    ``overwrite``. (Unmarked look-alikes, :data:`_LEGACY`, are not refused: a user's folder may hold a
    ``manifest.json``.)"""
    path = Path(path)
    for parent in path.absolute().parents:
        _check_parent(parent, path, param)
    for parent in (_resolved(path.parent), *_resolved(path.parent).parents):
        if (kind := read_marker(parent).get("kind")) in within:
            break
        if kind in KINDS:
            raise InputError(
                f"{param}: lies inside a {kind} folder spikenerf wrote ({parent}); write it elsewhere",
                path=path,
                param=param,
            )
    if path.is_dir():
        raise InputError(f"{param}: is a folder, not a file", path=path, param=param)
    if path.exists() and not overwrite:
        raise InputError("exists; pass overwrite to replace it", path=path, param="overwrite")
    check_writable(path, param, file=True)


def _check_replaceable(path: Path, kind: str, param: str) -> None:
    if read_marker(path).get("kind") != kind or not isinstance(read_marker(path).get("files"), list):
        raise InputError(
            f"{param}: looks like a {kind} folder but has no complete {MARKER} marker (not written whole by "
            "this spikenerf); refusing to replace it: delete it yourself or choose another",
            path=path,
            param=param,
        )
    extra = strangers(path)
    if extra:
        shown = ", ".join(extra[:3]) + (f" and {len(extra) - 3} more" if len(extra) > 3 else "")
        raise InputError(
            f"{param}: holds files spikenerf did not write ({shown}); refusing to replace it: move them away",
            path=path,
            param=param,
        )
    old = old_path(path)
    if (old.exists() or old.is_symlink()) and not is_retired(old):
        raise InputError(
            f"{param}: {old.name} beside it was not written by spikenerf and is in the way of the "
            "replacement; move it away",
            path=old,
            param=param,
        )

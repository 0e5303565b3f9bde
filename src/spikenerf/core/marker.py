"""Which folders spikenerf wrote: a ``.spikenerf`` marker file, so that nothing else is ever replaced.

Every output folder (dataset, run, render, benchmark) gets the marker with its kind. ``--overwrite`` replaces
only a marked folder (or an empty one), and outputs are never written into a folder of another kind (e.g.
``render --out`` into a dataset). Folders written before the marker existed are recognised by their files.
"""

from __future__ import annotations

import json
from pathlib import Path

from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError

MARKER = ".spikenerf"
KINDS = ("dataset", "run", "render", "benchmark")
#: files that identify a folder of each kind written before the marker existed
_LEGACY = {
    "dataset": ("transforms.json", "config.yaml"),
    "run": ("checkpoint.pt", "config.yaml"),
    "render": ("render.json",),
    "benchmark": ("results.json",),
}


def mark(folder: str | Path, kind: str) -> None:
    """Write the marker of ``kind`` into ``folder`` (created if needed)."""
    if kind not in KINDS:
        raise ValueError(f"unknown folder kind {kind!r}")
    write_text_atomic(Path(folder) / MARKER, json.dumps({"kind": kind}) + "\n")


def folder_kind(folder: str | Path) -> str | None:
    """The kind of a folder spikenerf wrote (from its marker, else its files), or None."""
    folder = Path(folder)
    if not folder.is_dir():
        return None
    try:
        kind = json.loads((folder / MARKER).read_text()).get("kind")
        if kind in KINDS:
            return kind
    except (OSError, ValueError, AttributeError):
        pass
    for kind, names in _LEGACY.items():
        if all((folder / name).is_file() for name in names):
            return kind
    return None


def check_output(path: str | Path, kind: str, param: str = "out", overwrite: bool = False) -> None:
    """InputError unless ``path`` may receive output of ``kind``.

    Accepted: a path that does not exist (its parents must be folders), an empty folder, or a folder that
    spikenerf wrote as ``kind``; with ``overwrite=False`` an existing output of ``kind`` is refused too
    (callers that resume or update in place pass ``overwrite=True``).
    """
    path = Path(path)
    for parent in path.absolute().parents:
        if parent.exists() and not parent.is_dir():
            raise InputError(f"{param}: {parent} is a regular file, not a folder", path=path, param=param)
    if not (path.exists() or path.is_symlink()):
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

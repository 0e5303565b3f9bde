"""``render.json``, the record ``spikenerf render`` writes beside its output (``eval/video.py``), read back.

Two readers need it whole: ``info`` of a render folder (what was rendered, the spike streams to summarise)
and a new render into the folder (the video and spike files of the earlier render to remove). Either
refuses a malformed record in one line naming it: it is no cache that could be rebuilt (the files it lists
are the render's output), and going on without it would leave files behind that no record lists.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from spikenerf.core.errors import InputError

RECORD = "render.json"
#: the fields read back where present, with their JSON types (None: null)
TYPED = {
    "run": (str,),
    "trajectory": (str,),
    "trajectory_kind": (str,),
    "views": (int,),
    "iteration": (int, type(None)),
    "run_iterations": (int, type(None)),
    "spike_steps": (int, type(None)),
    "threshold": (int, float, type(None)),
    "files": (dict,),
}
WORDS = {str: "a string", int: "an integer ≥ 0", float: "a number ≥ 0", dict: "an object", type(None): "null"}


def read_render_record(folder: Path) -> dict[str, Any] | None:
    """The render record of ``folder`` (None where it has none), checked: a JSON object with ``size`` two
    positive integers, the fields of :data:`TYPED` of their types (numbers ≥ 0), ``files.video`` a file
    name and ``files.spikes`` a list of them (names in the folder, no paths). InputError naming the file
    otherwise."""
    path = folder / RECORD
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:  # (nested beyond the stack)
        raise _malformed(path, f"{type(err).__name__}: {err}") from None
    if not isinstance(record, dict):
        raise _malformed(path, f"expected a JSON object, found {type(record).__name__}")
    size = record.get("size")
    if not (isinstance(size, list) and len(size) == 2 and all(_typed(v, (int,)) and v > 0 for v in size)):
        raise _malformed(path, f"size: expected [width, height], two positive integers, found {size!r:.60}")
    for key, types in TYPED.items():
        value = record.get(key)
        if key in record and not _typed(value, types):
            raise _malformed(path, f"{key}: expected {_kinds(types)}, found {value!r:.60}")
    files = record.get("files") or {}
    spikes = files.get("spikes")
    if spikes is not None and not isinstance(spikes, list):
        raise _malformed(path, f"files.spikes: expected a list of file names, found {spikes!r:.60}")
    names = [("files.video", files.get("video"))]
    names += [(f"files.spikes[{i}]", name) for i, name in enumerate(spikes or [])]
    for where, name in names:
        if name is not None and not (
            isinstance(name, str) and name not in ("", "..") and Path(name).name == name
        ):
            raise _malformed(path, f"{where}: expected a file name in the folder, found {name!r:.60}")
    return record


def _typed(value: object, types: tuple[type, ...]) -> bool:
    """Whether ``value`` is one of ``types`` (a JSON true or false is no number) and, a number, ≥ 0."""
    if isinstance(value, bool) or not isinstance(value, types):
        return False
    return not isinstance(value, int | float) or value >= 0


def _kinds(types: tuple[type, ...]) -> str:
    """``types`` in words: "an integer ≥ 0 or null"."""
    return " or ".join(dict.fromkeys(WORDS[t] for t in types if not (t is int and float in types)))


def _malformed(path: Path, problem: str) -> InputError:
    return InputError(
        f"malformed render record ({problem}); delete it and the files of the render it describes (or the "
        "whole folder), then render again",
        path=path,
    )

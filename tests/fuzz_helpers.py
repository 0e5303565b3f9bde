"""Mutations of valid input files for the property-based reader tests (``test_fuzz_inputs.py``).

Each strategy draws an edit of a valid file: bytes cut, flipped, inserted or deleted; one value of a
JSON/YAML tree replaced by another type (null, a list, a huge or negative number, NaN, an empty string, a
deeply nested structure) or its key deleted. :func:`check_refusal` runs a reader on the result: it may
return, or raise one :class:`InputError` line naming the file; anything else fails the test.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
from hypothesis import strategies as st

from spikenerf.core.errors import InputError

#: stands for a structure nested deeper than the parsers' stacks (written into the text, not built)
DEEP = "DEEP_NESTING_MARKER"
#: values that replace one node of a JSON/YAML tree
ODD_VALUES: list[Any] = [None, [], [1, 2], {}, {"a": 1}, 10**30, 10**400, -1, 0, 1.5, -1e308, math.nan,
                         math.inf, "", "x", "../../../etc/passwd", "/etc/passwd", True, DEEP]  # fmt: skip


def paths_of(tree: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path (a tuple of keys and indices) to a node of ``tree``, the root's ``()`` included."""
    found = [prefix]
    if isinstance(tree, dict):
        for key, value in tree.items():
            found += paths_of(value, (*prefix, key))
    elif isinstance(tree, list):
        for i, value in enumerate(tree[:6]):  # a long list: its first items stand for the rest
            found += paths_of(value, (*prefix, i))
    return found


def _edited(tree: Any, path: tuple, value: Any, delete: bool) -> Any:
    if not path:
        return value
    copy = dict(tree) if isinstance(tree, dict) else list(tree)
    key = path[0]
    if len(path) == 1 and delete:
        del copy[key]
    else:
        copy[key] = _edited(copy[key], path[1:], value, delete)
    return copy


@st.composite
def tree_edit(draw: st.DrawFn, tree: Any) -> Any:
    """``tree`` with one node replaced by an odd value, or (a key or item) deleted."""
    path = draw(st.sampled_from(paths_of(tree)))
    delete = bool(path) and draw(st.booleans())
    value = None if delete else draw(st.sampled_from(ODD_VALUES))
    return _edited(tree, path, value, delete)


def dump_json(tree: Any) -> bytes:
    deep = "[" * 100_000 + "]" * 100_000
    text = json.dumps(tree, allow_nan=True).replace(json.dumps(DEEP), deep)
    return text.encode()


def dump_yaml(tree: Any) -> bytes:
    deep = "[" * 5_000 + "]" * 5_000
    text = yaml.safe_dump(tree, sort_keys=False, allow_unicode=False)
    return text.replace(DEEP, deep).encode()


@st.composite
def byte_edit(draw: st.DrawFn, data: bytes) -> bytes:
    """``data`` truncated, or with a byte flipped, bytes inserted or a range deleted."""
    n = len(data)
    kind = draw(st.sampled_from(["truncate", "flip", "insert", "delete", "garbage"]))
    at = draw(st.integers(0, max(n - 1, 0)))
    if kind == "truncate":
        return data[:at]
    if kind == "flip":
        return data[:at] + bytes([data[at] ^ draw(st.integers(1, 255))]) + data[at + 1 :] if n else data
    if kind == "insert":
        return data[:at] + draw(st.binary(min_size=1, max_size=8)) + data[at:]
    if kind == "garbage":
        return draw(st.sampled_from([b"", b"\xff\xfe\x00", b"\x80abc", b"null", b"[]", b"---\n- 1\n"]))
    return data[:at] + data[at + draw(st.integers(1, 16)) :]


@st.composite
def json_edit(draw: st.DrawFn, data: bytes) -> bytes:
    """A byte edit of the JSON text (one time in four) or an edit of its tree."""
    if draw(st.integers(0, 3)) == 0:
        return draw(byte_edit(data))
    return dump_json(draw(tree_edit(json.loads(data))))


@st.composite
def yaml_edit(draw: st.DrawFn, data: bytes) -> bytes:
    """A byte edit of the YAML text (one time in four) or an edit of its tree."""
    if draw(st.integers(0, 3)) == 0:
        return draw(byte_edit(data))
    return dump_yaml(draw(tree_edit(yaml.safe_load(data))))


def check_refusal(read: Callable[[], object], *names: str | Path) -> None:
    """``read()`` returns, or raises one InputError line naming one of ``names`` (a file or folder)."""
    try:
        read()
    except InputError as err:
        message = str(err)
        assert "\n" not in message, f"multi-line message: {message!r}"
        assert any(str(name) in message for name in names), f"message names none of {names}: {message!r}"

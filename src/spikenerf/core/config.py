"""Typed config dataclasses: the one validation mechanism of every config (``TrainConfig`` and its sections,
the field configs).

A config is a dataclass whose annotations are the types it accepts (``Literal`` choices, int, float, bool,
str, ``X | None``, ``tuple[int, ...]``, dict) and whose ``BOUNDS`` class attribute gives the range of its
numbers, by key (:class:`Bound`). :func:`from_mapping` builds one from a mapping (a YAML file, ``--set``
overrides; unknown keys refused, numbers read from YAML 1.1 strings, lists for tuples), :func:`check_config`
checks every value: its type against the annotation (or, for a key with ``choices`` metadata, against the
names that callable returns: a registry), every float finite, every number within its bound. Each error is
an :class:`InputError` naming the key (``spike.kind``); a bound error lists the key in ``param=`` so that the
CLI shows its flag (a type error comes from a file or ``--set``, where the user wrote the key itself).
Rules that join several keys stay in the config's own ``validate``/``check``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import math
import os
import types
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

from spikenerf.core.errors import InputError

__all__ = ["Bound", "check_config", "choices", "coerce", "describe", "from_mapping", "matches"]


@dataclass(frozen=True)
class Bound:
    """The range of a number (of each element, for a tuple): ``≥ least``, ``> above``, ``≤ most``."""

    least: float | None = None
    above: float | None = None
    most: float | None = None

    def holds(self, value: float) -> bool:
        return (
            (self.least is None or value >= self.least)
            and (self.above is None or value > self.above)
            and (self.most is None or value <= self.most)
        )

    def describe(self) -> str:
        """``≥ 1``, ``> 0``, ``in (0, 1]``."""
        if self.most is not None:
            lo = f"({self.above:g}" if self.above is not None else f"[{self.least:g}"
            return f"in {lo}, {self.most:g}]"
        return f"≥ {self.least:g}" if self.least is not None else f"> {self.above:g}"


def choices(names: Callable[[], Any]) -> dict[str, Any]:
    """Field metadata: the key takes one of ``names()`` (e.g. a registry's keys), read when checked."""
    return {"choices": names}


def matches(value: Any, hint: Any) -> bool:
    """``value`` has the annotated type ``hint``."""
    origin = get_origin(hint)
    if origin is Literal:
        return value in get_args(hint)
    if origin in (Union, types.UnionType):
        return any(matches(value, h) for h in get_args(hint))
    if hint is type(None):
        return value is None
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is int:  # 64 bits: torch and numpy overflow beyond
        return isinstance(value, int) and not isinstance(value, bool) and abs(value) < 2**63
    if origin is tuple:
        item = get_args(hint)[0] if get_args(hint) else Any
        return isinstance(value, tuple) and (item is Any or all(matches(v, item) for v in value))
    return isinstance(value, origin or hint)


def coerce(value: Any, hint: Any) -> Any:
    """A value read from a mapping as the annotated type: a string for a number-typed key read as a float
    (YAML 1.1 reads ``1e-3``, no dot, as a string), an int for a float key as a float, a list for a tuple
    key as a tuple; anything else unchanged (``--set dataset=1e3`` stays the string it is)."""
    if isinstance(value, str) and matches(1.0, hint) and not matches(value, hint):
        with contextlib.suppress(ValueError):
            return float(value)
    if hint is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if get_origin(hint) is tuple and isinstance(value, list):
        return tuple(value)
    return value


def shown(value: Any, limit: int = 60) -> str:
    """``value`` as a config file or ``--set`` writes it (YAML's ``null``, ``true``), cut at ``limit``."""
    if value is None or isinstance(value, bool):
        return "null" if value is None else str(value).lower()
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def describe(hint: Any) -> str:
    """``one of gray, rgb``, ``an integer or null``."""
    origin = get_origin(hint)
    if origin is Literal:
        return "one of " + ", ".join(map(str, get_args(hint)))
    if origin in (Union, types.UnionType):
        return " or ".join(describe(h) for h in get_args(hint))
    if origin is tuple:
        return "a list of integers" if get_args(hint)[:1] == (int,) else "a list"
    if origin is dict:
        return "a mapping (KEY: VALUE)"
    names = {
        type(None): "null",
        float: "a number",
        int: "an integer",
        bool: "true or false",
        str: "a string",
        dict: "a mapping (KEY: VALUE)",
    }
    return names.get(hint, f"a {getattr(origin or hint, '__name__', hint)}")


def plain_scalars(config: Any) -> None:
    """Replace the numpy scalars among ``config``'s fields (and its sections', its lists', tuples' and
    dicts' items) by the Python numbers they hold: a sweep's ``np.linspace`` value is a number to
    :func:`check_config` and to the YAML a run records; a ``pathlib.Path`` (what ``simulate_dataset``
    returns) is its string. Duck-typed: this module imports no numpy."""
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            plain_scalars(value)
        elif (plain := _plain(value)) is not value:
            setattr(config, f.name, plain)


def _plain(value: Any) -> Any:
    if type(value).__module__ == "numpy" and getattr(value, "ndim", None) == 0:
        return value.item()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, (list, tuple)):
        items = [_plain(v) for v in value]
        return type(value)(items) if any(a is not b for a, b in zip(items, value, strict=True)) else value
    if isinstance(value, dict):
        plain = {k: _plain(v) for k, v in value.items()}
        return plain if any(plain[k] is not v for k, v in value.items()) else value
    return value


def check_config(config: Any, prefix: str = "", path: str | Path | None = None, bounds: bool = True) -> None:
    """Check every field of a config dataclass (and of its sections, ``prefix.KEY``): its type, and with
    ``bounds`` a float's finiteness and a number's ``BOUNDS``; InputError naming the first key that fails."""
    hints = get_type_hints(type(config))
    ranges: Mapping[str, Bound] = getattr(type(config), "BOUNDS", {}) if bounds else {}
    for f in dataclasses.fields(config):
        value, name = getattr(config, f.name), f"{prefix}{f.name}"
        param = name if path is None else None  # a file's value is named as its key, not as a flag
        if dataclasses.is_dataclass(value):
            check_config(value, f"{name}.", path, bounds)
            continue
        if "choices" in f.metadata:
            names = tuple(f.metadata["choices"]())
            if value not in names:
                listed = ", ".join(map(str, names))
                raise InputError(f"{name} must be one of {listed}, found {value!r}", path=path, param=param)
        elif not matches(value, hints[f.name]):
            kind = type(value)  # a numpy integer prints as one: say what it is
            plain = kind in (int, float, str, bool, type(None), list, tuple)
            found = shown(value) if plain else f"{value} ({kind.__name__})"
            wanted = describe(hints[f.name])
            if isinstance(value, int) and not isinstance(value, bool) and matches(0, hints[f.name]):
                found += " (too large: 64-bit integers stop below 2**63)"  # one torch and numpy cannot hold
            raise InputError(f"{name} must be {wanted}, found {found}", path=path, param=param)
        numbers = value if isinstance(value, tuple) else (value,)
        if bounds and any(isinstance(v, float) and not math.isfinite(v) for v in numbers):
            raise InputError(f"{name} must be a finite number, found {value!r}", param=name)
        bound = ranges.get(f.name)
        if bound is not None and value is not None and not all(bound.holds(v) for v in numbers):
            kind = "a list of integers " if isinstance(value, tuple) else ""
            kind = "a finite number " if matches(0.5, hints[f.name]) else kind
            raise InputError(f"{name} must be {kind}{bound.describe()}, found {value!r}", param=name)


def close_keys(word: str, known: set[str], given: set[str], n: int = 2) -> list[str]:
    """Up to ``n`` of the ``known`` keys close to ``word`` (difflib's 0.6), the closest first; of two as
    close, the one not ``given`` yet first (``seeds`` beside a given ``seed`` still suggests ``seed``)."""
    scored = [(difflib.SequenceMatcher(None, word, key).ratio(), key) for key in known]
    ranked = sorted((t for t in scored if t[0] >= 0.6), key=lambda t: (-t[0], t[1] in given, t[1]))
    return [key for _, key in ranked[:n]]


def from_mapping(
    cls: type, data: Any, label: str | None = None, path: str | Path | None = None,
    sections: Mapping[str, type] | None = None,
) -> Any:  # fmt: skip
    """A ``cls`` config from a mapping (InputError for another value or an unknown key, named as
    ``label``: the class name by default); ``sections``: keys whose values are built as those config
    classes in turn. The values are :func:`coerce`-d, not checked: call :func:`check_config`."""
    label = label or cls.__name__
    if not isinstance(data, dict):
        raise InputError(f"{label} must be a mapping (KEY: VALUE), found {shown(data)}", path=path)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:  # the closest known keys first: the whole list may be cut at the one line's end
        close = [m for k in unknown for m in close_keys(str(k), known, set(data))]
        hint = f"did you mean {', '.join(dict.fromkeys(close))}? " if close else ""
        raise InputError(f"unknown {label} keys {unknown}; {hint}expected some of {sorted(known)}", path=path)
    sections = sections or {}
    hints = get_type_hints(cls)
    values = {
        k: from_mapping(sections[k], v, k, path) if k in sections else coerce(v, hints[k])
        for k, v in data.items()
    }
    return cls(**values)

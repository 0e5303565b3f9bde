"""The one exception type for bad user input; the CLI prints it as one line and exits with code 2."""

from __future__ import annotations

import math
import numbers
import os
import re
from collections.abc import Callable, Collection, Iterable, Sequence
from pathlib import Path
from typing import Any

#: longest message an InputError keeps (foreign library errors can run to pages)
MAX_MESSAGE = 400


def one_line(text: str, limit: int = MAX_MESSAGE) -> str:
    """``text`` with every run of whitespace (newlines included) collapsed to one space, cut at ``limit``."""
    flat = " ".join(str(text).split())
    return flat if len(flat) <= limit else flat[: limit - 1] + "…"


class InputError(ValueError):
    """Bad input from the user: a malformed file, wrong sizes, a missing field, a path escaping a root.

    The message must name the file or field and say what was expected and what was found. It is kept to
    one line (see :func:`one_line`), whatever a wrapped library error said.

    Below the CLI a message names the *parameter* (``window``, ``blur_views``, ``spike.lam``), never a
    command-line flag, and lists it in ``param`` (a name or several); the CLI shows the message with each
    parameter replaced by its flag (:meth:`shown`).
    """

    def __init__(
        self, message: str, path: str | Path | None = None, param: str | Sequence[str] | None = None
    ) -> None:
        self.path = None if path is None else str(path)
        self.params: tuple[str, ...] = (param,) if isinstance(param, str) else tuple(param or ())
        self.message = one_line(message)
        super().__init__(self.shown(lambda name: None))

    def shown(self, flag: Callable[[str], str | None]) -> str:
        """The one line, with the first whole-word mention of each parameter replaced by ``flag(name)``
        (unchanged where that is None): how the CLI prints the error, naming its flags."""
        message = self.message
        for name in self.params:
            shown = flag(name)
            if shown is not None:
                word = rf"(?<![\w.'-]){re.escape(name)}(?![\w'-])"  # not inside a quoted value
                message = re.sub(word, lambda _, s=shown: s, message, count=1)
        return f"{self.path}: {message}" if self.path else message

    def __reduce__(self) -> tuple:  # keep path and params across pickling (worker processes)
        return (type(self), (self.message, self.path, self.params))


def check_choice(value: object, choices: Iterable[object], param: str, what: str | None = None) -> None:
    """InputError naming ``param`` unless ``value`` is one of ``choices``: "WHAT must be one of A, B, found
    'v'" (``what`` defaults to ``param``): the one wording of a refused choice below the CLI."""
    names = tuple(choices)
    if value not in names:
        listed = ", ".join(map(str, names))
        raise InputError(f"{what or param} must be one of {listed}, found {value!r}", param=param)


def comma_list(
    spec: str, known: Collection[str], complaint: Callable[[list[str]], str], param: str | None = None
) -> list[str]:
    """``"a, b"`` → ``["a", "b"]``: the non-empty comma-separated names of ``spec``, each one of ``known``.

    Raises InputError(``complaint(unknown)``, ``param=param``) when a name is not known or there is none
    (the caller words the message: it names the parameter, or the flag in cli/, and what was expected), and
    InputError naming ``param`` when a name is given twice (it would repeat the work and the results).
    """
    names = [n.strip() for n in spec.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise InputError(complaint(unknown), param=param)
    if twice := next((n for i, n in enumerate(names) if n in names[:i]), None):
        raise InputError(f"{param or 'list'}: {twice} is given twice", param=param)
    return names


def is_integer(value: object) -> bool:
    """``value`` is an integer, Python's or numpy's (a bool is not, though Python counts it as one)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def is_number(value: object) -> bool:
    """``value`` is a real number, Python's or numpy's, not a bool (NaN and inf are numbers: check them)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_finite(value: object) -> bool:
    """``value`` is a finite real number (:func:`is_number`); an int too large for a float (``10**400`` in a
    JSON file) is not one (``math.isfinite`` raises OverflowError on it)."""
    try:
        return is_number(value) and math.isfinite(value)  # type: ignore[arg-type]
    except OverflowError:
        return False


def same_shape(reference: Any, other: Any, name: str, reference_name: str) -> None:
    """InputError naming ``name`` unless array or tensor ``other`` has ``reference``'s shape (a check of sizes
    only: no sync, and a guard under ``torch.compile``)."""
    if tuple(other.shape) != tuple(reference.shape):
        raise InputError(
            f"{name} must have the shape of {reference_name}, {tuple(reference.shape)}, found "
            f"{tuple(other.shape)}",
            param=name,
        )


def nonempty(x: Any, name: str, what: str = "value") -> None:
    """InputError naming ``name`` where array or tensor ``x`` holds no element (a mean over it would be NaN);
    ``what`` names one element in the message. Reads the shape only: no sync, and a compiled step traces."""
    if math.prod(x.shape) == 0:
        raise InputError(
            f"{name} must hold at least one {what}, found the empty shape {tuple(x.shape)}", param=name
        )


def as_path(value: object, param: str) -> Path:
    """``value`` (a str or path-like, not empty) as a ``Path``; else InputError naming ``param``
    (``Path(None)`` is a TypeError deep in pathlib, and ``Path("")`` the current folder)."""
    if not isinstance(value, (str, os.PathLike)) or not str(value).strip():
        raise InputError(f"{param} must be a folder or file path, found {value!r:.60}", param=param)
    return Path(value)


def parse_int(text: str, param: str, expected: str) -> int:
    """``int(text)``; else InputError(``"{param}: expected {expected}, found {text!r}"``, ``param=param``)."""
    try:
        return int(text)
    except ValueError:
        raise InputError(f"{param}: expected {expected}, found {text!r}", param=param) from None


def parse_range(text: str, param: str) -> slice:
    """``"A:B"`` → ``slice(A, B)``: a Python slice, either side may be empty (``None``), negatives count from
    the end. InputError naming ``param`` when the text is not ``A:B`` or, A and B of one sign, ``A >= B``
    (it selects nothing whatever the length)."""
    parts = str(text).strip().split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        start, stop = (int(p) if p.strip() else None for p in parts)
    except ValueError:
        raise InputError(
            f"{param}: expected A:B (a Python slice, e.g. 0:100; either side may be empty), found {text!r}",
            param=param,
        ) from None
    if start is not None and stop is not None and (start >= 0) == (stop >= 0) and start >= stop:
        raise InputError(f"{param}: {text!r} selects no frames (need A < B)", param=param)
    return slice(start, stop)

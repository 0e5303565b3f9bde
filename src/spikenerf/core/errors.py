"""The one exception type for bad user input; the CLI prints it as one line and exits with code 2."""

from __future__ import annotations

from collections.abc import Callable, Collection
from pathlib import Path

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
    """

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = None if path is None else str(path)
        message = one_line(message)
        super().__init__(f"{self.path}: {message}" if self.path else message)


def comma_list(spec: str, known: Collection[str], complaint: Callable[[list[str]], str]) -> list[str]:
    """``"a, b"`` → ``["a", "b"]``: the non-empty comma-separated names of ``spec``, each one of ``known``.

    Raises InputError(``complaint(unknown)``) when a name is not known or there is none (the caller words
    the message: it names the flag and what was expected).
    """
    names = [n.strip() for n in spec.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise InputError(complaint(unknown))
    return names

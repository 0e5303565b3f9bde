"""The one exception type for bad user input; the CLI prints it as one line and exits with code 2."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input from the user: a malformed file, wrong sizes, a missing field, a path escaping a root.

    The message must name the file or field and say what was expected and what was found.
    """

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = None if path is None else str(path)
        super().__init__(f"{self.path}: {message}" if self.path else message)

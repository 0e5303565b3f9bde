"""Reading a CSV table that spikenerf wrote (``curves.csv`` of ``train`` and of ``recon-train``): one reader,
whose refusals are one InputError naming the file, the line and what to do."""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from spikenerf.core.errors import InputError

Row = TypeVar("Row")


def read_table(
    path: Path,
    what: str,
    header_problem: Callable[[list[str]], str | None],
    parse: Callable[[list[str], list[str]], Row],
    aside: str,
) -> list[Row]:
    """The rows of the CSV file ``path`` as ``parse(header, row)`` gives them (blank lines skipped).

    InputError naming ``path`` ("not a ``what``", then ``aside``: what the user may do) where
    ``header_problem(header)`` names a problem, where ``parse`` raises ValueError or TypeError (a value that
    is no number, a row cut short; with its line number), or where the bytes are not text or not CSV.
    """
    rows, line = [], 1
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = next(reader, [])
            if problem := header_problem(header):
                raise InputError(f"not a {what}: {problem} ({aside})", path=path)
            for row in reader:
                line = reader.line_num
                if row:
                    rows.append(parse(header, row))
    except InputError:  # (a ValueError too: raised as it is)
        raise
    except (UnicodeDecodeError, csv.Error) as err:  # (UnicodeDecodeError is a ValueError: before it)
        raise InputError(f"not a {what} ({type(err).__name__}: {err}; {aside})", path=path) from err
    except (ValueError, TypeError, KeyError) as err:
        raise InputError(
            f"not a {what}: line {line} is not a row of numbers ({err}; {aside})", path=path
        ) from err
    return rows

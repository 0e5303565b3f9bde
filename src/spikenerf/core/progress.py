"""Progress bars: ``tqdm``, hidden where the caller asks or where ``spikenerf --quiet`` runs.

``spikenerf --quiet COMMAND`` sets :data:`QUIET_ENV`, which the runs that ``benchmark`` and ``demo`` start
on this machine inherit (a Ray worker's runs do not: they have the worker's environment), so every bar of
the command and of its child processes stays hidden; each command's own ``--quiet`` (``--no-progress``)
hides its bars alone.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable
from typing import Any

#: set to "1" by ``spikenerf --quiet``: no progress bar in this process or in the processes it starts
QUIET_ENV = "SPIKENERF_QUIET"


def quiet() -> bool:
    """Whether ``spikenerf --quiet`` hid every progress bar (:data:`QUIET_ENV`)."""
    return os.environ.get(QUIET_ENV, "0") == "1"


def bar(iterable: Iterable[Any] | None = None, *, show: bool | None = True, **kwargs: Any) -> Any:
    """A ``tqdm`` bar over ``iterable`` (or a manual one, with ``total=``), shown where ``show`` and not
    :func:`quiet` (``show`` None: only on a terminal); other keyword arguments go to ``tqdm``."""
    from tqdm import tqdm

    hidden = show is False or quiet()
    return tqdm(iterable, disable=True if hidden else None if show is None else False, **kwargs)


def close_bars() -> None:
    """Close every progress bar still open (as at its end: its last state stays on screen), so that the line
    printed next, such as an error, starts a line of its own instead of following a bar's text."""
    module = sys.modules.get("tqdm")  # no bar was ever made without it
    for open_bar in list(getattr(getattr(module, "tqdm", None), "_instances", ())):
        open_bar.close()

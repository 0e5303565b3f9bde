"""The evaluation's typed choices, defined once, without importing torch (the CLI's ``eval`` choices)."""

from __future__ import annotations

from typing import Literal, get_args

#: the views a run is scored on: held-out novel views, or the sharp GT along the training path
Split = Literal["test", "train"]
SPLITS: tuple[str, ...] = get_args(Split)
#: when the no-reference checks run (auto: for imported datasets)
NorefMode = Literal["auto", "on", "off"]
NOREF_MODES: tuple[str, ...] = get_args(NorefMode)

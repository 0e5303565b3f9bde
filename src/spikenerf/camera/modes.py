"""The spike camera's choices as ``Literal`` types, defined once (no torch import: the CLI reads them)."""

from __future__ import annotations

from typing import Literal, get_args

#: colour modes of the spike camera (rgb: one stream a channel; bayer: an RGGB mosaic)
ColorMode = Literal["gray", "rgb", "bayer"]
COLORS: tuple[str, ...] = get_args(ColorMode)
#: noise models of the spike camera (``camera/noise.py``)
NoiseKind = Literal["ideal", "realistic"]
NOISES: tuple[str, ...] = get_args(NoiseKind)

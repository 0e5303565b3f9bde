"""The spike camera's choices as ``Literal`` types, defined once (no torch import: the CLI reads them)."""

from __future__ import annotations

from typing import Literal, get_args

#: colour modes of the spike camera (rgb: one stream a channel; bayer: an RGGB mosaic)
ColorMode = Literal["gray", "rgb", "bayer"]
COLORS: tuple[str, ...] = get_args(ColorMode)
#: noise models of the spike camera (``camera/noise.py``)
NoiseKind = Literal["ideal", "realistic"]
NOISES: tuple[str, ...] = get_args(NoiseKind)
#: row orders of a ``.dat`` file (``camera/io.py``): SpikeCV's bottom-up rows, or top-down rows
DatLayout = Literal["spikecv", "topdown"]
LAYOUTS: tuple[str, ...] = get_args(DatLayout)

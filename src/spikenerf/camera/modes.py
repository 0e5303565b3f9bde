"""The spike camera's choices as ``Literal`` types, defined once (no torch import: the CLI reads them)."""

from __future__ import annotations

import math
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

#: Each parameter of the realistic noise (``camera/noise.py`` ``RealisticNoise``) and its range (low, high,
#: unit): ample room around the defaults (docs/camera.md), kept where the float32 patterns and buffers stay
#: finite (a relative std of 1e40 overflows them, a dead time of 1e300 steps turns into NaN). Here, not in
#: camera/noise.py, so that the CLI names the parameters without importing torch.
NOISE_RANGES: dict[str, tuple[float, float, str]] = {
    # intensity units per step: from 1 (white) on, every pixel fires every step
    "dark_mean": (0.0, 100.0, " intensity units per step (1.0 = white)"),
    "dark_std": (0.0, 100.0, " intensity units per step (1.0 = white)"),
    # relative stds, the defaults below 0.06: 10 is a spread of 1000 %
    "threshold_std": (0.0, 10.0, " (relative std)"),
    "capacitance_std": (0.0, 10.0, " (relative std)"),
    "prnu_std": (0.0, 10.0, " (relative std)"),
    "jitter_std": (0.0, 10.0, " (relative std)"),
    # electrons a white pixel collects in a step: below one the shot noise's Gaussian approximation fails
    "photons_per_white": (1.0, math.inf, " electrons per white step"),
    # steps of dead time after a spike (0.25 s at 40 kHz; float32 counts them down exactly)
    "readout_delay": (0.0, 1e4, " steps"),
    # the fraction of a saturated pixel's whole thresholds left in its accumulator after it fired
    "excess_carry": (0.0, 1.0, " (fraction kept)"),
}

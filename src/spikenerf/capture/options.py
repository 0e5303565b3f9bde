"""What ``simulate`` is asked for besides the scene: :class:`SimulateOptions` (colour modes, the camera,
GT and blur frames, a raw recording, ``config.yaml`` extras) and :func:`check_options`, which refuses bad
ones before any rendering starts."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import yaml

from spikenerf.camera.model import CameraConfig
from spikenerf.camera.noise import noise_with
from spikenerf.capture.blur import parse_blur_views
from spikenerf.core.errors import InputError, is_integer, is_number
from spikenerf.data.dataset import MODES


@dataclass(frozen=True)
class SimulateOptions:
    """What to simulate and write besides the scene itself.

    Attributes:
        colors: colour modes, each of ``gray``, ``rgb``, ``bayer`` (one spike camera each); a string is
            read as a comma-separated list (``"gray,rgb"``, ``"all"``: the three).
        threshold: φ. noise: ``ideal`` or ``realistic``. seed: camera seed. warmup: camera warm-up steps.
        noise_params: ``realistic`` only: parameters that replace the preset's (``{"dark_mean": 0.0}``;
            camera/noise.py :class:`RealisticNoise`), recorded in ``config.yaml``; empty: the preset.
        gt_every: store the sharp render of every k-th step in ``gt/``.
        blur_fps: conventional camera rate (Hz); each frame averages ``round(fps / blur_fps)`` step renders
            (a window cut by the end of the path keeps its real exposure). 0 writes no blur frames.
        blur_views: which exposures (capture/blur.py): ``frames`` (consecutive, as PNGs), ``all`` (one centred
            on every step, the paper's) or N evenly spaced centres (both stored in ``blur/views.npy``).
        overwrite: replace an existing ``out``. command: recorded in ``config.yaml``.
        extra: more entries for ``config.yaml`` (e.g. the trajectory parameters).
        raw_width: also write the gray stream as a raw recording with this row width, no poses
            (``raw/``, capture/recording.py); None: not.
    """

    colors: tuple[str, ...] = ("gray",)
    threshold: float = 1.0
    noise: str = "ideal"
    noise_params: dict = field(default_factory=dict)
    seed: int = 0
    warmup: int = 0
    gt_every: int = 10
    blur_fps: float = 400.0
    blur_views: str | int = "frames"
    overwrite: bool = False
    command: str = ""
    extra: dict = field(default_factory=dict)
    raw_width: int | None = None

    def __post_init__(self) -> None:
        colors = self.colors
        if isinstance(colors, str):  # ("gray" was read as the modes g, r, a, y)
            colors = tuple(MODES) if colors == "all" else tuple(c.strip() for c in colors.split(","))
        if isinstance(colors, np.ndarray):  # (an array of names, as a list)
            colors = colors.tolist()
        if not isinstance(colors, (tuple, list)):  # (a set has no order: the files' order would be chance)
            raise InputError(f"colors must be a list of colour modes, found {colors!r}", param="colors")
        object.__setattr__(self, "colors", tuple(colors))


def check_options(options: SimulateOptions) -> None:
    """InputError on unknown colour modes, wrong types or out-of-range numbers, and on ``extra`` entries
    that ``config.yaml`` cannot hold or that would replace its own keys (before any rendering starts)."""
    colors = options.colors
    if not colors or any(not isinstance(c, str) or c not in MODES for c in colors):
        raise InputError(
            f"colors: expected gray, rgb, bayer or all, found {', '.join(map(str, colors)) or 'none'}",
            param="colors",
        )
    if len(set(colors)) < len(colors):
        twice = next(c for c in colors if colors.count(c) > 1)
        raise InputError(f"colors: {twice} is given twice", param="colors")
    if not is_integer(options.gt_every) or options.gt_every < 1:
        raise InputError(f"gt_every must be an integer ≥ 1, found {options.gt_every!r}", param="gt_every")
    blur = options.blur_fps
    if not is_number(blur) or not 0 <= blur < math.inf:
        raise InputError(
            f"blur_fps must be a finite number ≥ 0 (0 = no blur frames), found {blur!r}", param="blur_fps"
        )
    if options.raw_width is not None and not is_integer(options.raw_width):
        raise InputError(
            f"raw_width must be an integer or None, found {options.raw_width!r}", param="raw_width"
        )
    _check_extra(options.extra)
    parse_blur_views(options.blur_views)
    if options.raw_width is not None and "gray" not in options.colors:
        raise InputError(
            "raw_width writes the gray stream as a raw recording: it needs colors to include gray",
            param=("raw_width", "colors"),
        )
    for color in options.colors:  # CameraConfig validates threshold, noise, seed, warmup
        CameraConfig(options.threshold, color, options.noise, options.seed, options.warmup)
    if options.noise_params and options.noise != "realistic":
        raise InputError(
            f"noise_params: set the realistic noise's parameters, and noise is {options.noise!r}",
            param=("noise_params", "noise"),
        )
    noise_with(options.noise_params)


#: the ``config.yaml`` keys ``simulate.dataset_config`` writes itself (``extra`` may add others, not replace
#: them)
OWN_KEYS = ("filename", "is_labeled", "labeled_data_type", "labeled_data_suffix", "spike_h", "spike_w",
            "fps", "threshold", "colors", "noise", "noise_params", "seed", "scene", "steps", "warmup",
            "gt_every", "blur_fps", "blur_views", "test_views", "spikenerf_version", "command", "layout",
            "bayer_pattern")  # fmt: skip


def _check_extra(extra: object) -> None:
    """InputError unless ``extra`` is a mapping of new keys that YAML can write."""
    if not isinstance(extra, dict):
        raise InputError(f"extra must be a dict, found {type(extra).__name__}", param="extra")
    if shadowed := [key for key in extra if key in OWN_KEYS]:
        raise InputError(f"extra: {shadowed} would replace config.yaml's own keys", param="extra")
    try:
        yaml.safe_dump(extra)
    except yaml.YAMLError as err:  # (its message names the value)
        raise InputError(f"extra: config.yaml cannot hold it ({err})", param="extra") from None

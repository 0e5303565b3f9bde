"""What ``import`` is asked for: :class:`ImportOptions` (the recording, the keyframes, the pose source,
COLMAP's settings, the orientation) and :func:`check_options`, which refuses bad ones (naming the option)
before any work."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from spikenerf.camera.reconstruct import check_window
from spikenerf.core.errors import InputError
from spikenerf.importing.orientation import ORIENTS, Orient, check_orient
from spikenerf.scenes import transforms

#: ``import --orient`` (defined with the geometry: :data:`spikenerf.importing.orientation.ORIENTS`)
ORIENT_CHOICES: tuple[str, ...] = ORIENTS


@dataclass(frozen=True)
class ImportOptions:
    """How to import a recording (see :func:`spikenerf.importing.importer.import_recording`; the CLI flags
    have the same names).

    Attributes:
        poses: ``colmap``, ``orbit`` (with ``orbit``) or a pose file/folder. height, width, config, raw_width,
        fps, threshold, layout: the recording (``fps`` and ``threshold`` win over the config.yaml; a size or
        layout that differs from its own is refused; layout None: the config's, else spikecv). frame_range:
        a slice of steps.
        keyframe_every: steps between keyframes. window: TFP window (frames). test_every: every n-th
        keyframe becomes a test view (0: none). fov_deg: horizontal field of view (wins over the pose
        source's intrinsics; needed where it has none). overlap: COLMAP sequential-matching overlap.
        loop_pairs: also match every pair of keyframes (up to ``ColmapSettings.exhaustive_up_to``
        keyframes), which closes an orbit's loop; off: sequential matching only (symmetric scenes).
        min_registered: fraction of keyframes COLMAP must register. verbose: show COLMAP's log.
        keyframe_images: ``tfp`` (window ``window``) or ``learned`` (the shipped learned reconstructor, at its
        trained window). max_features, sift_peak, affine_sift, final_ba, contrast: COLMAP settings
        (:class:`spikenerf.importing.colmap.ColmapSettings`). smooth: local quadratic smoothing of the
        keyframe poses over this many steps (0: off; :func:`spikenerf.importing.interpolation.smooth_poses`).
        orient: ``up`` turns a frame without a stated scene box upright and its vertical planes onto the axes
        (the smallest box where the points show none), ``up-box`` upright and for the smallest box, before
        the unit box is fitted (:func:`spikenerf.importing.orientation.upright`); ``none`` keeps the source's
        axes.
    """

    poses: str = "colmap"
    orbit: str | None = None
    height: int | None = None
    width: int | None = None
    config: Path | None = None
    raw_width: int | None = None
    fps: float | None = None
    threshold: float | None = None
    layout: str | None = None
    frame_range: slice | None = None
    keyframe_every: int = 20
    window: int = 21
    test_every: int = 8
    fov_deg: float | None = None
    overlap: int = 10
    loop_pairs: bool = True
    min_registered: float = 0.5
    overwrite: bool = False
    verbose: bool = False
    keyframe_images: str = "tfp"
    max_features: int = 8192
    sift_peak: float = round(0.02 / 3, 6)  # the CLI default, exactly
    affine_sift: bool = False
    final_ba: bool = True
    contrast: float = 0.0
    smooth: int = 0
    orient: Orient = "up"
    command: str = ""


#: the settings of the COLMAP estimate (``poses="colmap"``), meaningless with given poses (``smooth`` too:
#: only COLMAP's keyframe poses are smoothed, see
#: :func:`spikenerf.importing.keyframes.keyframe_poses`)
COLMAP_ONLY = (
    "overlap",
    "loop_pairs",
    "min_registered",
    "max_features",
    "sift_peak",
    "affine_sift",
    "final_ba",
    "contrast",
    "smooth",
    "verbose",
)


def check_options(options: ImportOptions) -> None:
    """InputError (naming the option) for out-of-range numbers, unknown choices and options that the pose
    source makes meaningless (``orbit`` without ``poses`` orbit, COLMAP settings with given poses)."""
    for name in ("keyframe_every", "window", "overlap"):
        if getattr(options, name) < 1:
            raise InputError(f"{name} must be ≥ 1, found {getattr(options, name)}", param=name)
    check_window(options.window, "window")
    if not 0 <= options.min_registered <= 1:
        raise InputError(
            f"min_registered must be in [0, 1], found {options.min_registered}", param="min_registered"
        )
    check_orient(options.orient)
    if options.keyframe_images not in ("tfp", "learned"):
        raise InputError(
            f"keyframe_images must be tfp or learned, found {options.keyframe_images!r}",
            param="keyframe_images",
        )
    if options.max_features < 64:
        raise InputError(f"max_features must be ≥ 64, found {options.max_features}", param="max_features")
    for name in ("sift_peak", "contrast", "smooth"):
        value = getattr(options, name)
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"{name} must be a finite number ≥ 0, found {value}", param=name)
    if options.test_every < 0:
        raise InputError(
            f"test_every must be ≥ 0 (0 = no test views), found {options.test_every}", param="test_every"
        )
    if options.fov_deg is not None and not 0 < options.fov_deg < 180:
        raise InputError(f"fov_deg must be in (0, 180) degrees, found {options.fov_deg}", param="fov_deg")
    if options.fov_deg is not None:  # a camera the dataset loader takes (a focal length of sane proportions)
        lo, hi = (math.degrees(2 * math.atan(0.5 / ratio)) for ratio in reversed(transforms.FOCAL_RANGE))
        if not lo <= options.fov_deg <= hi:
            raise InputError(f"fov_deg must be within [{lo:.3g}, {hi:.8g}] degrees, found {options.fov_deg}",
                             param="fov_deg")  # fmt: skip
    for name in ("fps", "threshold"):
        value = getattr(options, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a finite number > 0, found {value}", param=name)
    if options.poses == "orbit" and options.orbit is None:
        raise InputError(
            "orbit R,ELEV[,TURNS[,AZIMUTH]] (the known path) is needed with poses orbit",
            param=("orbit", "poses"),
        )
    if options.poses != "orbit" and options.orbit is not None:
        raise InputError(
            f"orbit R,ELEV[,TURNS[,AZIMUTH]] is only used with poses orbit, not {options.poses!r}",
            param=("orbit", "poses"),
        )
    defaults = ImportOptions()
    colmap_only = [n for n in COLMAP_ONLY if getattr(options, n) != getattr(defaults, n)]
    if options.poses != "colmap" and colmap_only:
        raise InputError(
            f"{', '.join(colmap_only)}: only used with poses colmap (COLMAP's estimate); poses "
            f"{options.poses!r} gives the poses",
            param=(*colmap_only, "poses"),
        )
    if options.keyframe_images == "learned" and options.window != defaults.window:
        raise InputError(
            "window sets the TFP keyframes; keyframe_images learned reads the network's own window",
            param=("window", "keyframe_images"),
        )

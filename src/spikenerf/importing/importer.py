"""``spikenerf import``: a raw ``.dat`` recording (+ poses: COLMAP, a file or an orbit) → a dataset folder.

Steps (docs/real-data.md): read the frame size from the flags or the SpikeCV ``config.yaml``; select
``--range``; reconstruct keyframes (TFP) every ``keyframe_every`` steps; get keyframe poses (COLMAP on the
keyframes, a pose file, or an orbit); interpolate them to every step; normalise the scene to ``[-1, 1]^3``;
pick near/far (from COLMAP's sparse points where there are some); hold out every ``test_every``-th keyframe
reconstruction as a test view; write the standard dataset folder. Work happens in ``<out>.partial/`` (the
COLMAP model is kept there and reused after an interruption); only a finished folder becomes ``out``.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from spikenerf import __version__
from spikenerf.camera.io import count_frames, iter_dat, raw_width_guess, read_dat, resolve_frames
from spikenerf.camera.reconstruct import check_window
from spikenerf.camera.spikecv import recording_config, refuse_size_conflicts
from spikenerf.core.errors import InputError
from spikenerf.core.faults import failpoint
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import (
    MARKER,
    check_inputs_outside,
    check_output,
    folder_kind,
    mark,
    replace_dir,
)
from spikenerf.core.yamlio import load_yaml
from spikenerf.data.dataset import load_dataset, near_far
from spikenerf.data.reconstruction import reconstructor
from spikenerf.data.writer import DatasetWriter, open_work, recover_replaced, work_dir
from spikenerf.importing.alignment import (
    ORIENTS,
    Orient,
    check_orient,
    frustum_box,
    held_steps,
    near_far_from_points,
    normalisation,
    per_step_poses,
    smooth_poses,
)
from spikenerf.importing.poses import PoseSet, orbit_poses, read_pose_source
from spikenerf.scenes import transforms
from spikenerf.scenes.trajectory import Intrinsics, Trajectory

DEFAULT_FPS = 40000.0
COLMAP_WORK = "colmap"
COLMAP_SEQUENTIAL = "colmap-sequential"  # the refit without loop pairs (colmap_poses)
COLMAP_FOLDERS = (COLMAP_WORK, COLMAP_SEQUENTIAL)
#: ``import --orient`` (defined with the geometry: :data:`spikenerf.importing.alignment.ORIENTS`)
ORIENT_CHOICES: tuple[str, ...] = ORIENTS


@dataclass(frozen=True)
class ImportOptions:
    """How to import a recording (see :func:`import_recording`; the CLI flags have the same names).

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
        keyframe poses over this many steps (0: off; :func:`spikenerf.importing.alignment.smooth_poses`).
        orient: ``up`` turns a frame without a stated scene box upright and its vertical planes onto the axes
        (the smallest box where the points show none), ``up-box`` upright and for the smallest box, before
        the unit box is fitted (:func:`spikenerf.importing.alignment.upright`); ``none`` keeps the source's
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
#: only COLMAP's keyframe poses are smoothed, see :func:`keyframe_poses`)
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


def _check(options: ImportOptions) -> None:
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


def count_steps(dat: Path, height: int, width: int, raw_width: int | None) -> int:
    """Frames in the recording (``count_frames``, whose error names a raw layout that fits); a file whose
    size fits both the plain and the raw sps10 layout, and reads as raw rows with silent padding
    (``raw_width_guess``), is refused until ``raw_width`` says which."""
    total = count_frames(dat, height, width, raw_width)
    if raw_width is None and (raw := raw_width_guess(dat, height, width)) is not None:
        raise InputError(
            f"reads both as {width}-column frames and as raw sps10 rows of {raw} columns whose last "
            f"{raw - width} stay silent: pass raw_width {raw} for a raw recording, or {width} for plain "
            "frames",
            dat,
            param="raw_width",
        )
    return total


def keyframe_steps(n: int, every: int, window: int) -> np.ndarray:
    """Keyframe steps (relative, int64) every ``every`` steps where the whole TFP window fits in the ``n``
    steps (a clipped window is centred off its step: a biased pose), plus the last such step."""
    half = min(window // 2, (n - 1) // 2)
    return np.unique(np.append(np.arange(half, n - half, every), n - 1 - half)).astype(np.int64)


def held_out_keyframes(
    key_steps: np.ndarray, test_every: int, pose_steps: np.ndarray | None = None, n: int | None = None
) -> np.ndarray:
    """The keyframe steps held out as test views: every ``test_every``-th from the second (none for 0),
    less those that the poses at ``pose_steps`` (of ``n`` steps) leave at a held pose
    (:func:`spikenerf.importing.alignment.held_steps`): a test view there would be scored at a pose that
    is not the one its image shows."""
    tests = key_steps[1::test_every] if test_every else key_steps[:0]
    if pose_steps is None or len(pose_steps) < 2:
        return tests
    if n is None:
        raise TypeError("held_out_keyframes: pose_steps needs n, the number of steps")
    before, after = held_steps(pose_steps, n)
    return tests[(tests >= before) & (tests < n - after)]


def keyframe_window(opts: ImportOptions) -> int:
    """The window (steps) of one keyframe image: ``window`` for TFP, the network's for ``learned``."""
    if opts.keyframe_images != "learned":
        return opts.window
    from spikenerf.recon.net import load_weights

    return int(load_weights(None, "gray")[0].config.window)


def keyframe_images(
    dat: Path,
    steps: np.ndarray,
    first: int,
    stop: int,
    shape: tuple[int, int, int | None],
    opts: ImportOptions,
    threshold: float,
) -> np.ndarray:
    """TFP (or learned) keyframes (N, H, W) float32 linear at absolute ``steps``, windows in [first, stop)."""
    (h, w, raw), learned = shape, opts.keyframe_images == "learned"
    recon = reconstructor(opts.keyframe_images, None if learned else opts.window, threshold)
    read = lambda a, b: read_dat(dat, h, w, slice(first + a, first + b), opts.layout, raw)  # noqa: E731
    out = []
    for s in steps:
        out.append(recon(read, stop - first, int(s) - first, int(s) - first + 1)[0])
        if not learned:
            failpoint("import.keyframe")
    return np.stack(out)


def keyframe_poses(
    opts: ImportOptions, images: np.ndarray, key_steps: np.ndarray, work: Path, n: int, fps: float, first: int
) -> PoseSet:
    """Keyframe poses with steps relative to the selection (0..n-1)."""
    if opts.poses == "colmap":
        found = colmap_poses(opts, images, key_steps, work)
        return replace(found, poses=smooth_poses(found.poses, found.steps, opts.smooth))  # by relative step
    if opts.poses == "orbit":
        return orbit_poses(str(opts.orbit), n, fps)
    found = read_pose_source(opts.poses)
    if found.steps is None and len(found.poses) > n:
        raise InputError(
            f"{len(found.poses)} poses without steps for {n} selected steps: give each pose its step (a "
            "'step' field, or numbered names), or select at least as many steps",
            path=opts.poses,
        )
    if found.steps is None:  # spread evenly over the selected steps
        steps = np.round(np.linspace(0, n - 1, len(found.poses))).astype(np.int64)
    else:
        steps = found.steps + imported_offset(opts.poses) - first
        _check_pose_steps(steps, n, first, opts.poses)
    return replace(found, steps=steps)


def imported_offset(source: str | Path) -> int:
    """The recording step that step 0 of ``source`` is: an imported dataset's ``transforms.json`` or
    ``colmap/model`` counts its steps from its own range's start (``config.yaml``'s ``imported.range``);
    0 for any other pose file."""
    path = Path(source)
    folder = path if path.is_dir() else path.parent
    for dataset in (folder, *list(folder.parents)[:2]):
        if folder_kind(dataset) != "dataset" or not (dataset / "config.yaml").is_file():
            continue
        try:
            imported = load_yaml((dataset / "config.yaml").read_text(encoding="utf-8")).get("imported")
            return int(imported["range"][0])
        except (OSError, yaml.YAMLError, AttributeError, KeyError, IndexError, TypeError, ValueError):
            return 0
    return 0


def colmap_poses(opts: ImportOptions, images: np.ndarray, key_steps: np.ndarray, work: Path) -> PoseSet:
    """COLMAP's poses of the keyframes (N, H, W) at ``key_steps`` (N,), checked for folds
    (:func:`spikenerf.importing.colmap.unfolded_colmap`)."""
    from spikenerf.importing.colmap import ColmapSettings, unfolded_colmap

    focal = None
    if opts.fov_deg is not None:
        focal = Intrinsics.from_fov(images.shape[2], images.shape[1], math.radians(opts.fov_deg)).fl_x
    settings = ColmapSettings(
        focal=focal,
        overlap=opts.overlap,
        exhaustive_up_to=ColmapSettings.exhaustive_up_to if opts.loop_pairs else 0,
        max_features=opts.max_features,
        peak_threshold=opts.sift_peak,
        affine=opts.affine_sift,
        final_ba=opts.final_ba,
        contrast=opts.contrast,
    )
    return unfolded_colmap(
        images,
        key_steps,
        (work / COLMAP_WORK, work / COLMAP_SEQUENTIAL),
        settings,
        (opts.min_registered, opts.keyframe_every, opts.verbose),
    )


def _check_pose_steps(steps: np.ndarray, n: int, first: int, source: str) -> None:
    """InputError unless a pose file's steps (relative to the selection) lie in ``[0, n)`` and span more
    than half of it (frame numbers that are not spike steps, such as frame_00001.png, would hold the
    rest)."""
    lo, hi = int(steps.min()), int(steps.max())
    where = f"steps {lo + first}..{hi + first} of the poses"
    if lo < 0 or hi >= n:
        raise InputError(
            f"{where} fall outside the selected steps {first}..{first + n - 1}: import a range that holds "
            f"them (frame_range {lo + first}:{hi + first + 1}), or drop the poses outside it",
            path=source,
            param="frame_range",
        )
    posed = f"frame_range {lo + first}:{hi + first + 1}"
    if hi - lo + 1 <= n / 2:
        raise InputError(
            f"{where} cover only {hi - lo + 1} of the {n} selected steps {first}..{first + n - 1}; the rest "
            f"would keep a held pose: select the posed steps ({posed}), or, if the frame numbers are not "
            "spike steps, give 'step' per frame",
            path=source,
            param="frame_range",
        )


def intrinsics_for(found: PoseSet, width: int, height: int, fov_deg: float | None) -> Intrinsics:
    """The camera at the recording's size: ``--fov`` wins, then the pose source's intrinsics or its fov. The
    source's lens distortion stays under ``--fov`` too (its terms are in units of the focal length)."""
    k = found.intrinsics
    lens = found.lens if k is None else k.distortion
    if fov_deg is None and k is not None:
        return k if (k.width, k.height) == (width, height) else k.scaled(width, height)
    if fov_deg is None and found.camera_angle_x is None:
        raise InputError(
            "the pose source carries no camera intrinsics: pass fov_deg (horizontal field of view, degrees)",
            param="fov_deg",
        )
    fov = math.radians(fov_deg) if fov_deg is not None else found.camera_angle_x
    k = Intrinsics.from_fov(width, height, fov)
    try:
        return k if lens is None else replace(k, distortion=lens)
    except InputError as err:  # (the lens at this field of view)
        given = f" at fov_deg {fov_deg:g}" if fov_deg is not None else " at the pose source's field of view"
        raise InputError(err.message + given, param="fov_deg" if fov_deg is not None else ()) from None


def import_recording(dat: str | Path, out: str | Path, opts: ImportOptions) -> Path:
    """Import a ``.dat`` recording into the dataset folder ``out`` (see the module doc); returns ``out``."""
    dat, out = Path(dat), Path(out)
    _check(opts)
    rc = recording_config(dat, opts.height, opts.width, opts.config)
    refuse_size_conflicts(rc.path, opts.height, opts.width, opts.raw_width)  # a typo writes garbage
    if opts.layout is not None and rc.layout is not None and opts.layout != rc.layout:
        raise InputError(
            f"layout {opts.layout} differs from layout {rc.layout} in {rc.path}, which describes this "
            "recording: leave it out, or correct that file if it is wrong",
            param="layout",
        )
    opts = replace(opts, layout=opts.layout or rc.layout or "spikecv")
    h, w = int(rc.height or 0), int(rc.width or 0)
    raw = opts.raw_width if opts.raw_width is not None else rc.raw_width
    fps = next(v for v in (opts.fps, rc.fps, DEFAULT_FPS) if v is not None)
    threshold = next(v for v in (opts.threshold, rc.threshold, 1.0) if v is not None)
    total = count_steps(dat, h, w, raw)
    sel = resolve_frames(opts.frame_range, total, dat, param="frame_range")
    n = len(sel)
    if n == 0:
        raise InputError(
            "the recording holds no steps" if total == 0 else "frame_range selects no steps",
            dat,
            param="frame_range",
        )
    check_output(out, "dataset", overwrite=opts.overwrite, replace=True)
    pose_file = None if opts.poses in ("colmap", "orbit") else opts.poses
    for folder in (out, work_dir(out)):  # replacing out, or publishing its work folder, would delete them
        check_inputs_outside(folder, [dat, rc.path, opts.config, pose_file])
    window = keyframe_window(opts)
    if n < window:  # every keyframe's window would be clipped, centred off its step
        raise InputError(
            f"frame_range: {n} selected steps are fewer than the {window} steps of window (one keyframe's)",
            param=("frame_range", "window"),
        )
    rel_keys = keyframe_steps(n, opts.keyframe_every, window)
    if len(rel_keys) < 2:
        raise InputError(
            f"{n} steps give {len(rel_keys)} keyframe at keyframe_every {opts.keyframe_every} with a window "
            f"of {window} steps; need at least 2 (select more steps, or a shorter window)",
            param=("keyframe_every", "window"),
        )
    with output_lock(out):
        recover_replaced(out)
        check_output(
            out, "dataset", overwrite=opts.overwrite, replace=True
        )  # again, now that no one else writes
        _import_locked(dat, out, opts, (sel, fps, threshold, raw, rc.path), (h, w, rel_keys))
    return out


def _import_locked(dat: Path, out: Path, opts: ImportOptions, rec: tuple, keys: tuple) -> None:
    sel, fps, threshold, raw, _ = rec
    h, w, rel_keys = keys
    work, fresh = open_work(out)
    try:
        images = keyframe_images(dat, rel_keys + sel.start, sel.start, sel.stop, (h, w, raw), opts, threshold)
        found = keyframe_poses(opts, images, rel_keys, work, len(sel), fps, sel.start)
        k = intrinsics_for(found, w, h, opts.fov_deg)
        _write(dat, out, work, opts, found, k, (images, rel_keys), rec)
    except BaseException:
        if fresh and not any((work / f / "model").exists() for f in COLMAP_FOLDERS):  # nothing to resume
            shutil.rmtree(work, ignore_errors=True)
        raise


def _write(
    dat: Path,
    out: Path,
    work: Path,
    opts: ImportOptions,
    found: PoseSet,
    k: Intrinsics,
    keys: tuple[np.ndarray, np.ndarray],
    rec: tuple,
) -> None:
    sel, fps, threshold, raw, config_path = rec
    images, rel_keys = keys
    n = len(sel)
    steps = np.arange(n, dtype=np.int64)
    poses = per_step_poses(found.poses, found.steps, steps)
    scene_box = found.scene_box
    if scene_box is None and found.depth_bounds is not None:
        scene_box = frustum_box(found.poses, *found.depth_bounds)
    norm = normalisation(found.poses, found.points, scene_box, k.view_angle_x, opts.orient, found.focus)
    poses = norm.poses(poses)
    box = np.array([[-1.0] * 3, [1.0] * 3])
    bounds = None if found.depth_bounds is None else tuple(d * norm.scale for d in found.depth_bounds)
    if found.points is not None:
        bounds = near_far_from_points(norm.poses(found.poses), norm.points(found.points))
    near, far = bounds if bounds is not None else near_far(poses, box)
    used = (COLMAP_WORK, COLMAP_SEQUENTIAL) if found.note else (COLMAP_WORK,)  # the refit only when used
    for stale in work.iterdir():  # outputs of an earlier attempt (its COLMAP model only if ours now)
        if stale.name != MARKER and (stale.name not in used or opts.poses != "colmap"):
            shutil.rmtree(stale) if stale.is_dir() else stale.unlink()
    writer = DatasetWriter(work, k, fps, box, near, far)
    writer.start_spikes(["gray"])
    for _, chunk in iter_dat(
        dat, k.height, k.width, frames=slice(sel.start, sel.stop), layout=opts.layout, raw_width=raw
    ):
        writer.append_spikes("gray", chunk)
        failpoint("import.spikes")
    held = held_out_keyframes(rel_keys, opts.test_every, found.steps, n)
    for i in np.searchsorted(rel_keys, held):
        writer.add_test(np.repeat(images[i][..., None], 3, -1), poses[rel_keys[i]])
    registered = len(found.poses)
    config = {
        "spike_h": k.height,
        "spike_w": k.width,
        "fps": float(fps),
        "threshold": float(threshold),
        "colors": ["gray"],
        "noise": "recorded",
        "scene": f"imported:{dat.stem}",
        "steps": int(n),
        "imported": {
            "recording": str(dat),
            "spikecv_config": None if config_path is None else str(config_path),
            "range": [int(sel.start), int(sel.stop)],
            "raw_width": raw,
            "layout": opts.layout,
            "poses": opts.poses if opts.poses in ("colmap", "orbit") else str(opts.poses),
            "orbit": opts.orbit,
            "keyframe_every": int(opts.keyframe_every),
            "window": keyframe_window(opts),
            "keyframe_images": opts.keyframe_images,
            "keyframes": len(rel_keys),
            "poses_known": int(registered),
            "pose_steps": [int(s) for s in np.sort(found.steps)],
            **({"pose_note": found.note} if found.note else {}),
            "test_keyframes": [int(s) for s in held],
            "normalisation": norm.record(),
        },
        "test_views": len(held),
        "spikenerf_version": __version__,
        "command": opts.command,
        "layout": "spikecv",
    }
    for folder in COLMAP_FOLDERS:
        for name in ("images", "sparse", "database.db"):  # big and rebuildable: not part of the dataset
            path = work / folder / name
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
    writer.finish(Trajectory(poses, steps / fps, steps, fps), config, None)
    load_dataset(work, train_images=False)  # what the loader refuses is never published
    mark(work, "dataset", files=True)
    failpoint("import.publish")
    replace_dir(work, out)

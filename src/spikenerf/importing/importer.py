"""``spikenerf import``: a raw ``.dat`` recording (+ poses: COLMAP, a file or an orbit) → a dataset folder.

Steps (docs/real-data.md): read the frame size from the flags or the SpikeCV ``config.yaml``; select
``--range``; reconstruct keyframes (TFP) every ``keyframe_every`` steps; get keyframe poses (COLMAP on the
keyframes, a pose file, or an orbit); interpolate them to every step; normalise the scene to ``[-1, 1]^3``;
pick near/far (from COLMAP's sparse points where there are some); hold out every ``test_every``-th keyframe
reconstruction as a test view; write the standard dataset folder. Work happens in ``<out>.partial/`` (the
COLMAP model is kept there and reused after an interruption); only a finished folder becomes ``out``.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from spikenerf import __version__
from spikenerf.camera.frame_range import resolve_frames
from spikenerf.camera.io import count_frames, iter_dat, raw_width_guess
from spikenerf.camera.spikecv import recording_config, refuse_size_conflicts
from spikenerf.core.errors import InputError
from spikenerf.core.faults import failpoint
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import MARKER, check_inputs_outside, check_output, mark
from spikenerf.core.replacement import replace_dir
from spikenerf.data.dataset import load_dataset, near_far
from spikenerf.data.writer import DatasetWriter, open_work, recover_replaced, work_dir
from spikenerf.importing.interpolation import per_step_poses
from spikenerf.importing.keyframes import (
    COLMAP_FOLDERS,
    COLMAP_SEQUENTIAL,
    COLMAP_WORK,
    held_out_keyframes,
    intrinsics_for,
    keyframe_images,
    keyframe_poses,
    keyframe_steps,
    keyframe_window,
)
from spikenerf.importing.normalisation import frustum_box, near_far_from_points, normalisation
from spikenerf.importing.options import ImportOptions, check_options
from spikenerf.importing.pose_set import PoseSet
from spikenerf.scenes.trajectory import Intrinsics, Trajectory

DEFAULT_FPS = 40000.0


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


def import_recording(dat: str | Path, out: str | Path, opts: ImportOptions) -> Path:
    """Import a ``.dat`` recording into the dataset folder ``out`` (see the module doc); returns ``out``."""
    dat, out = Path(dat), Path(out)
    check_options(opts)
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

"""The keyframes of an ``import``: their steps (:func:`keyframe_steps`, the held-out ones), their TFP or
learned images (:func:`keyframe_images`), their poses (:func:`keyframe_poses`: COLMAP on the images, a pose
file or an orbit) and the camera (:func:`intrinsics_for`)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from spikenerf.camera.io import read_dat
from spikenerf.core.errors import InputError
from spikenerf.core.faults import failpoint
from spikenerf.core.marker import folder_kind
from spikenerf.core.yamlio import load_yaml
from spikenerf.data.reconstruction import reconstructor
from spikenerf.importing.interpolation import held_steps, smooth_poses
from spikenerf.importing.options import ImportOptions
from spikenerf.importing.pose_set import PoseSet
from spikenerf.importing.poses import orbit_poses, read_pose_source
from spikenerf.scenes.trajectory import Intrinsics

COLMAP_WORK = "colmap"
COLMAP_SEQUENTIAL = "colmap-sequential"  # the refit without loop pairs (colmap_poses)
COLMAP_FOLDERS = (COLMAP_WORK, COLMAP_SEQUENTIAL)


def keyframe_steps(n: int, every: int, window: int) -> np.ndarray:
    """Keyframe steps (relative, int64) every ``every`` steps where the whole TFP window fits in the ``n``
    steps (a clipped window is centred off its step: a biased pose), plus the last such step."""
    half = min(window // 2, (n - 1) // 2)
    return np.unique(np.append(np.arange(half, n - half, every), n - 1 - half)).astype(np.int64)


def held_out_keyframes(
    key_steps: np.ndarray, test_every: int, pose_steps: np.ndarray | None = None, n: int | None = None
) -> np.ndarray:
    """The keyframe steps held out as test views (K,) of ``key_steps`` (N,): every ``test_every``-th from the
    second (none for 0), less those that the poses at ``pose_steps`` (P,) (of ``n`` steps) leave at a held
    pose (:func:`spikenerf.importing.interpolation.held_steps`): a test view there would be scored at a pose
    that is not the one its image shows."""
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
        _check_pose_steps(steps, n, first, opts.poses, found.steps_named)
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


def _check_pose_steps(steps: np.ndarray, n: int, first: int, source: str, named: bool) -> None:
    """InputError unless a pose file's steps (relative to the selection) lie in ``[0, n)`` and span more
    than half of it (frame numbers that are not spike steps, such as frame_00001.png, would hold the
    rest); ``named``: the steps are the numbers ending the frames' names, not ``step`` fields."""
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
        fix = (
            "if the numbers ending the frame names are not spike steps, give each frame its 'step' (a "
            "transforms.json field)"
            if named
            else "if the frames' 'step' values are not spike steps, correct them"
        )
        raise InputError(
            f"{where} cover only {hi - lo + 1} of the {n} selected steps {first}..{first + n - 1}; the rest "
            f"would keep a held pose: select the posed steps ({posed}), or, {fix}",
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

"""The frame cache of ``simulate``: every step rendered once into ``<out>.partial/.frames/NNNNN.npy``
(float16; the held-out views in ``test.npz``), reused after an interruption while the source's renders are
the same (:func:`open_cache` empties it otherwise)."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np

from spikenerf.capture.render_workers import render_frames
from spikenerf.core.atomic import atomic_path
from spikenerf.core.errors import InputError
from spikenerf.core.faults import failpoint
from spikenerf.core.progress import bar as progress_bar
from spikenerf.scenes.base import FrameSource

CACHE = ".frames"
#: the brightest linear intensity a rendered frame may hold: the frame cache stores float16
FRAME_MAX = float(np.finfo(np.float16).max)


def _fingerprint(source: FrameSource) -> dict:
    """What identifies the renders of a source: a changed scene or camera invalidates the frame cache."""
    digest = hashlib.sha256(np.ascontiguousarray(source.trajectory.poses, dtype=np.float64).tobytes())
    keys = ("supersample", "spp", "seed", "settings", "steps_per_frame", "interpolate", "frame_images")
    extra = {key: getattr(source, key) for key in keys if hasattr(source, key)}
    test_poses = getattr(source, "test_poses", None)
    if test_poses is not None:
        digest.update(np.ascontiguousarray(test_poses, dtype=np.float64).tobytes())
    k = source.intrinsics
    return {
        "scene": source.name,
        "camera": [k.width, k.height, k.fl_x, k.fl_y, k.cx, k.cy]
        + ([k.distortion.as_json()] if k.distortion else []),
        "steps": [int(s) for s in source.trajectory.steps[[0, -1]]] + [len(source.trajectory)],
        "poses_sha256": digest.hexdigest(),
        **{key: v if isinstance(v, (int, float, str)) else str(v) for key, v in extra.items()},
    }


def _save_npy(path: Path, array: np.ndarray) -> None:
    """``np.save`` through a temporary sibling so an interrupted write never leaves a corrupt cache entry."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.save(fh, array)


def open_cache(source: FrameSource, work: Path) -> Path:
    """The frame cache folder of ``source`` in ``work``; emptied when it holds renders of another source."""
    cache = work / CACHE
    stamp, want = cache / "source.json", _fingerprint(source)
    if cache.exists():
        try:
            same = json.loads(stamp.read_text()) == want
        except (OSError, ValueError):
            same = False
        if not same:
            shutil.rmtree(cache)
    cache.mkdir(parents=True, exist_ok=True)
    if not stamp.exists():
        stamp.write_text(json.dumps(want))
    return cache


def _cached(path: Path, shape: tuple[int, ...]) -> bool:
    """True when ``path`` holds a whole cached frame of ``shape`` (a truncated or foreign file is False)."""
    try:
        frame = np.load(path, mmap_mode="r", allow_pickle=False)
        return frame.shape == shape and frame.dtype == np.float16
    except (OSError, ValueError, EOFError):
        return False


def render_missing(source: FrameSource, cache: Path, progress: bool = True, jobs: int = 1) -> int:
    """Render the steps (and the test views) not yet in ``cache``; returns the number of steps rendered.

    ``jobs`` > 1 renders in that many processes where the source sets ``parallel_render`` (analytic
    scenes); Blender and image sequences render in this process."""
    k = source.intrinsics
    shape = (k.height, k.width, 3)
    missing = [int(s) for s in source.trajectory.steps if not _cached(cache / f"{int(s):05d}.npy", shape)]
    bar = progress_bar(total=len(missing), desc="render", unit="step", show=progress and bool(missing))
    for step, frame in zip(missing, render_frames(source, missing, jobs), strict=True):
        frame = np.asarray(frame)
        if frame.shape != (k.height, k.width, 3) or not np.isfinite(frame).all():
            raise InputError(
                f"scene {source.name!r} gave a frame of shape {frame.shape} (or non-finite values) "
                f"for step {step}; expected finite ({k.height}, {k.width}, 3)"
            )
        if frame.size and frame.max() > FRAME_MAX:
            raise InputError(
                f"scene {source.name!r} gave a linear intensity of {frame.max():g} for step {step}; the "
                f"camera takes at most {FRAME_MAX:g} (scale the images down)"
            )
        frame = np.maximum(frame, 0.0)  # no negative light (a denoiser's −1e-4): it would be a charge debt
        _save_npy(cache / f"{step:05d}.npy", frame.astype(np.float16))
        failpoint("simulate.render")
        bar.update()
    bar.close()
    if not _test_cached(cache / "test.npz"):
        poses, frames = source.test_views()
        with atomic_path(cache / "test.npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, poses=np.asarray(poses, np.float64), frames=np.asarray(frames, np.float32))
    return len(missing)


def _test_cached(path: Path) -> bool:
    """True when ``path`` is a readable test-view archive."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return z["frames"].dtype == np.float32 and z["poses"].shape[0] == z["frames"].shape[0]
    except Exception:  # missing, truncated (zipfile.BadZipFile), foreign: render the test views again
        return False

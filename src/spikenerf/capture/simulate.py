"""The ``simulate`` pipeline: scene frames → spike cameras → a finished dataset folder (docs/scenes.md).

Work happens in ``<out>.partial/``: every step is rendered once into a float16 frame cache
(``<out>.partial/.frames/NNNNN.npy``, reused after an interruption), then the cached frames stream through one
:class:`~spikenerf.camera.model.SpikeCamera` per colour mode while GT, blur and test images are written. Only
a complete folder is renamed to ``out``, so a half-written dataset is never mistaken for a finished one.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from spikenerf import __version__
from spikenerf.camera.layout import to_camera_layout
from spikenerf.camera.model import CameraConfig, SpikeCamera
from spikenerf.camera.noise import noise_with
from spikenerf.capture.blur import RunningExposures, blur_windows, exposure_length
from spikenerf.capture.frame_cache import CACHE, open_cache, render_missing
from spikenerf.capture.options import SimulateOptions, check_options
from spikenerf.capture.recording import RAW_DIR, check_raw_width, write_raw_recording
from spikenerf.core.atomic import clean_stale_temps
from spikenerf.core.errors import InputError, is_integer
from spikenerf.core.faults import failpoint
from spikenerf.core.limits import check_resources
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import MARKER, check_output, mark
from spikenerf.core.progress import bar as progress_bar
from spikenerf.core.replacement import replace_dir
from spikenerf.data.dataset import near_far, spike_files
from spikenerf.data.writer import DatasetWriter, open_work, recover_replaced
from spikenerf.scenes.base import FrameSource
from spikenerf.scenes.poses import pose_at
from spikenerf.scenes.trajectory import Trajectory, check_trajectory

#: spike steps buffered per colour mode before they are appended to the .dat files
SPIKE_CHUNK = 64


def estimate_resources(
    width: int, height: int, steps: int, colors: tuple[str, ...] = ("gray",), test_views: int = 8,
    spp: int | None = 4, gt_every: int = 10, blur_frames: int = 0,
) -> tuple[float, float]:  # fmt: skip
    """(peak memory, disk) in bytes of a ``simulate`` run, upper-ish estimates from its sizes.

    Memory: one frame's supersampled rays and their intermediates (~256 B per ray), the cameras' state and
    spike buffers per mode, the held-out views and the poses. Disk: the float16 frame cache, the ``.dat``
    streams, 16-bit PNGs (GT, blur, test; uncompressed bound) and the JSON lines of the steps.
    """
    px, channels = float(width) * float(height), sum(3 if c == "rgb" else 1 for c in colors)
    rays = px * max(1, spp or 1)
    memory = rays * 256 + px * (len(colors) * (160 + SPIKE_CHUNK * 3) + 12 * test_views + 48) + steps * 200
    pngs = steps / max(gt_every, 1) + blur_frames + test_views
    disk = steps * px * 6 + px * channels * steps / 8 + pngs * px * 6 + steps * 700 + test_views * px * 16
    return memory, disk


def check_simulate_resources(out: Path, params: str, **sizes: Any) -> None:
    """InputError (naming ``params``, e.g. ``width/height/frames``) when :func:`estimate_resources` exceeds
    the memory or disk at hand."""
    check_resources(*estimate_resources(**sizes), out, params)


def check_bounds_of(poses: np.ndarray, box: np.ndarray) -> tuple[float, float]:
    """The (near, far) ray bounds of cameras ``poses`` (N, 4, 4) around ``box``; InputError (naming
    ``trajectory``) when the poses are not finite or the cameras lie so far away that the bounds collapse."""
    poses = np.asarray(poses, dtype=np.float64)
    if not np.isfinite(poses).all():
        raise InputError("the trajectory or test poses hold a NaN or an infinity", param="trajectory")
    with np.errstate(over="ignore", invalid="ignore"):
        near, far = near_far(poses, box)
    if not (math.isfinite(near) and math.isfinite(far) and near < far):
        raise InputError(
            f"the ray bounds of these cameras collapse (near {near:g}, far {far:g}): they lie too far from "
            "the scene box, or a box smaller than the 0.05 near plane is too close to them",
            param="trajectory",
        )
    return near, far


def stream_steps(
    writer: DatasetWriter,
    cache: Path,
    traj: Trajectory,
    options: SimulateOptions,
    windows: list[tuple[int, int]],
    progress: bool = True,
) -> None:
    """Feed the cached frames, in step order, to one spike camera per colour mode; write spikes, GT, blur.

    Blur views come from a running sum over the same stream (frames leaving an exposure are re-read from the
    cache), so overlapping exposures cost no more memory than one image.
    """
    h, w = writer.intrinsics.height, writer.intrinsics.width
    params = noise_with(options.noise_params) if options.noise == "realistic" else None
    configs = {
        c: CameraConfig(options.threshold, c, options.noise, options.seed, options.warmup)
        for c in options.colors
    }
    cameras = {c: SpikeCamera(h, w, config, None, params) for c, config in configs.items()}
    writer.start_spikes(list(options.colors))
    buffers: dict[str, list[np.ndarray]] = {c: [] for c in options.colors}

    def frame_at(i: int) -> np.ndarray:
        return np.load(cache / f"{int(traj.steps[i]):05d}.npy").astype(np.float32)

    if windows and options.blur_views != "frames":
        writer.start_blur_array(len(windows))
    blur = RunningExposures(windows, frame_at)
    for i in progress_bar(range(len(traj)), desc="spikes", unit="step", show=progress):
        step, frame = traj.steps[i], frame_at(i)
        chw = np.ascontiguousarray(to_camera_layout(frame, frame=True))
        for c, camera in cameras.items():
            buffers[c].append(camera.step(chw).copy())
            if len(buffers[c]) == SPIKE_CHUNK or i == len(traj) - 1:
                writer.append_spikes(c, np.stack(buffers[c]))
                buffers[c].clear()
        failpoint("simulate.spikes")
        if i % options.gt_every == 0:
            writer.add_gt(int(step), frame)
        for w, image in blur.push(frame):
            start, end = windows[w]
            pose = pose_at(traj.poses, (start + end - 1) / 2)
            writer.add_blur(image, pose, int(traj.steps[start]), int(traj.steps[end - 1]) + 1)


def spikecv_keys(name: str, height: int, width: int) -> dict:
    """The keys SpikeCV's dataset loader reads from ``config.yaml``: the recording is unlabeled raw spikes
    (``labeled_data_type`` [0] = SpikeCV's ``raw`` task); the sharp renders are our own ``gt/``."""
    return {
        "filename": name,
        "spike_h": int(height),
        "spike_w": int(width),
        "is_labeled": False,
        "labeled_data_type": [0],
        "labeled_data_suffix": None,
    }


def dataset_config(source: FrameSource, options: SimulateOptions, test_views: int) -> dict:
    """The ``config.yaml`` entries (SpikeCV keys first, then the simulation settings)."""
    k, traj = source.intrinsics, source.trajectory
    return {
        **spikecv_keys(source.name, k.height, k.width),
        "fps": float(traj.fps),
        "threshold": float(options.threshold),
        "colors": list(options.colors),
        "noise": options.noise,
        **({"noise_params": _replaced(options.noise_params)} if options.noise_params else {}),
        "seed": int(options.seed),
        "scene": source.name,
        "steps": len(traj),
        "warmup": int(options.warmup),
        "gt_every": int(options.gt_every),
        "blur_fps": float(options.blur_fps),
        "blur_views": options.blur_views,
        "test_views": int(test_views),
        "spikenerf_version": __version__,
        "command": options.command,
        "layout": "spikecv",
        **({"bayer_pattern": "RGGB"} if "bayer" in options.colors else {}),
        **options.extra,
    }


def _replaced(noise_params: dict) -> dict[str, float]:
    """The replaced noise parameters as the camera took them (plain floats: a numpy number given through
    the Python API was a RepresenterError of the YAML writer, at the end of the run)."""
    params = noise_with(noise_params)
    return {str(name): float(getattr(params, name)) for name in noise_params}


def simulate_dataset(
    source: FrameSource, out: Path, options: SimulateOptions, progress: bool = True, jobs: int = 1
) -> Path:
    """Render ``source`` along its trajectory, simulate the spike cameras and write a dataset folder.

    Args:
        source: the scene (its trajectory, intrinsics, scene box and test views).
        out: the dataset folder to create; refused if it exists unless ``options.overwrite``.
        options: :class:`SimulateOptions`. progress: show tqdm bars.
        jobs: processes rendering frames at once (sources with ``parallel_render``, :func:`render_missing`).
    Returns:
        ``out``. After an interruption, running again with the same source reuses the cached renders.
    """
    out = Path(out)
    if not is_integer(jobs) or jobs < 1:
        raise InputError(f"jobs must be an integer ≥ 1, found {jobs!r}", param="jobs")
    check_options(options)
    missing = [key for key in ("trajectory", "intrinsics", "scene_box") if not hasattr(source, key)]
    if missing:  # (None, or another object, was an AttributeError here)
        raise InputError(
            f"source must be a scene source (make_scene_source(...)), found {type(source).__name__} "
            f"without {', '.join(missing)}",
            param="source",
        )
    check_trajectory(source.trajectory, "source.trajectory")  # before any frame is rendered
    test = np.asarray(getattr(source, "test_poses", np.zeros((0, 4, 4))), dtype=np.float64).reshape(-1, 4, 4)
    check_bounds_of(np.concatenate([source.trajectory.poses, test]), np.asarray(source.scene_box, float))
    check_raw_width(options.raw_width, source.intrinsics.height, source.intrinsics.width)
    check_output(out, "dataset", overwrite=options.overwrite, replace=True)
    with output_lock(out):
        recover_replaced(out)
        check_output(
            out, "dataset", overwrite=options.overwrite, replace=True
        )  # again, now that no one else writes
        return _simulate_locked(source, out, options, progress, jobs)


def _simulate_locked(
    source: FrameSource, out: Path, options: SimulateOptions, progress: bool, jobs: int
) -> Path:
    traj, k = source.trajectory, source.intrinsics
    windows = blur_windows(len(traj), traj.fps, options.blur_fps, options.blur_views)
    work, fresh = open_work(out)
    cache = open_cache(source, work)
    clean_stale_temps(cache)
    try:
        render_missing(source, cache, progress, jobs)
    except BaseException as err:
        # a fresh run with nothing worth resuming, or stopped by an input file it cannot read (a sequence
        # frame): leave nothing behind. A resumed run, or a scene's bad frame after hours of renders, keeps
        # its cache.
        bad_file = isinstance(err, InputError) and err.path is not None
        if fresh and (bad_file or not any(cache.glob("*.npy"))):
            shutil.rmtree(work, ignore_errors=True)
        raise

    box = np.asarray(source.scene_box, dtype=np.float64)
    with np.load(cache / "test.npz") as z:
        test_poses, test_frames = z["poses"].reshape(-1, 4, 4), z["frames"]
    near, far = check_bounds_of(np.concatenate([traj.poses, test_poses]), box)
    for stale in work.iterdir():  # outputs of an earlier, interrupted run: rewritten from the cache
        if stale.name not in (CACHE, MARKER):
            shutil.rmtree(stale) if stale.is_dir() else stale.unlink()
    writer = DatasetWriter(work, k, traj.fps, box, near, far)
    stream_steps(writer, cache, traj, options, windows, progress)
    for pose, image in zip(test_poses, test_frames, strict=True):
        writer.add_test(image, pose)
    config = dataset_config(source, options, len(test_poses))
    blur_rate = traj.fps / exposure_length(traj.fps, options.blur_fps) if windows else None  # as realised
    writer.finish(traj, config, blur_rate)
    if options.raw_width is not None:
        write_raw_recording(
            work / spike_files("gray")[0], k.height, k.width, traj.fps, work / RAW_DIR, options.raw_width
        )
    mark(work, "dataset", files=True, leaving=CACHE)  # (the cache stays until the list is written)
    failpoint("simulate.publish")
    shutil.rmtree(cache)
    replace_dir(work, out)
    return out

"""The ``simulate`` pipeline: scene frames → spike cameras → a finished dataset folder (docs/scenes.md).

Work happens in ``<out>.partial/``: every step is rendered once into a float16 frame cache
(``<out>.partial/.frames/NNNNN.npy``, reused after an interruption), then the cached frames stream through one
:class:`~spikenerf.camera.model.SpikeCamera` per colour mode while GT, blur and test images are written. Only
a complete folder is renamed to ``out``, so a half-written dataset is never mistaken for a finished one.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import multiprocessing
import os
import pickle
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from spikenerf import __version__
from spikenerf.camera.layout import to_camera_layout
from spikenerf.camera.model import CameraConfig, SpikeCamera
from spikenerf.capture.blur import RunningExposures, blur_windows, exposure_length, parse_blur_views
from spikenerf.capture.recording import RAW_DIR, check_raw_width, write_raw_recording
from spikenerf.core.atomic import atomic_path, clean_stale_temps
from spikenerf.core.errors import InputError, is_integer, is_number
from spikenerf.core.faults import failpoint
from spikenerf.core.limits import check_resources
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import MARKER, check_output, mark, replace_dir
from spikenerf.core.progress import bar as progress_bar
from spikenerf.data.dataset import MODES, near_far, spike_files
from spikenerf.data.writer import DatasetWriter, open_work, recover_replaced
from spikenerf.scenes.base import FrameSource
from spikenerf.scenes.poses import pose_at
from spikenerf.scenes.trajectory import Trajectory, check_trajectory

#: spike steps buffered per colour mode before they are appended to the .dat files
SPIKE_CHUNK = 64
CACHE = ".frames"


@dataclass(frozen=True)
class SimulateOptions:
    """What to simulate and write besides the scene itself.

    Attributes:
        colors: colour modes, each of ``gray``, ``rgb``, ``bayer`` (one spike camera each); a string is
            read as a comma-separated list (``"gray,rgb"``, ``"all"``: the three).
        threshold: φ. noise: ``ideal`` or ``realistic``. seed: camera seed. warmup: camera warm-up steps.
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


#: the source a render worker process draws from (set once per worker by :func:`_init_render_worker`)
_WORKER_SOURCE: FrameSource | None = None


def _init_render_worker(source_file: str) -> None:
    """Load the source the parent pickled to ``source_file``: passed by name, it keeps the pickle that
    starts each worker small, so starting one does not wait for it to import torch (see :func:`_frames`)."""
    global _WORKER_SOURCE
    with open(source_file, "rb") as fh:
        _WORKER_SOURCE = pickle.load(fh)


def _render_step(step: int) -> np.ndarray:
    assert _WORKER_SOURCE is not None
    return np.asarray(next(iter(_WORKER_SOURCE.frames([step]))))


#: thread-count variables of the math libraries a render worker may use (numpy's BLAS, OpenMP, MKL)
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


def usable_jobs(jobs: int, work: int) -> int:
    """Worker processes worth starting for ``work`` items: ``jobs``, but no more than the items and the
    CPU cores this process may use (``--jobs 100000`` starts a process per core, not per step)."""
    return max(1, min(jobs, work, _cores()))


def worker_env(jobs: int) -> dict[str, str]:
    """Thread counts for ``jobs`` worker processes: each its share of the cores, so that their math
    libraries (numpy's BLAS threads a frame's large products) do not start a pool per core in every worker;
    a variable already set is kept."""
    share = str(max(1, _cores() // jobs))
    return {name: os.environ.get(name, share) for name in THREAD_VARS}


#: the brightest linear intensity a rendered frame may hold: the frame cache stores float16
FRAME_MAX = float(np.finfo(np.float16).max)


def _frames(source: FrameSource, steps: list[int], jobs: int) -> Iterator[np.ndarray]:
    """The frames of ``steps`` in order: from ``jobs`` worker processes when the source allows it
    (``parallel_render``: a picklable source whose frames depend on the step alone), else in this one."""
    jobs = usable_jobs(jobs, len(steps))
    if jobs <= 1 or not getattr(source, "parallel_render", False):
        yield from source.frames(steps)
        return
    ctx = multiprocessing.get_context("spawn")  # no fork of a process that may hold torch threads
    saved = {name: os.environ.get(name) for name in THREAD_VARS}
    pool = None
    with tempfile.TemporaryDirectory(prefix="spikenerf-render-") as folder:
        source_file = os.path.join(folder, "source.pkl")
        with open(source_file, "wb") as fh:
            pickle.dump(source, fh)
        try:
            os.environ.update(worker_env(jobs))  # read by the workers as they start (all of them in map())
            # the workers start with Ctrl-C ignored, so that one during their start prints no traceback and
            # the parent alone stops the run; starting them takes milliseconds (the source goes by file),
            # so the parent's own Ctrl-C is not lost meanwhile
            with _sigint_ignored():
                pool = ProcessPoolExecutor(jobs, ctx, _init_render_worker, (source_file,))
                frames = pool.map(_render_step, steps, chunksize=max(1, min(8, len(steps) // (4 * jobs))))
            _restore(saved)  # the workers have started: the caller iterates with its own settings
            yield from frames
        finally:
            _restore(saved)
            if pool is not None:  # on an interrupt the workers finish their chunk of frames, no more
                pool.shutdown(wait=True, cancel_futures=True)


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored in this process meanwhile (the main thread only), so that processes started in it
    inherit the ignoring (Python keeps an inherited SIG_IGN) and print no traceback on a Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _restore(saved: dict[str, str | None]) -> None:
    for name, value in saved.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


def render_missing(source: FrameSource, cache: Path, progress: bool = True, jobs: int = 1) -> int:
    """Render the steps (and the test views) not yet in ``cache``; returns the number of steps rendered.

    ``jobs`` > 1 renders in that many processes where the source sets ``parallel_render`` (analytic
    scenes); Blender and image sequences render in this process."""
    k = source.intrinsics
    shape = (k.height, k.width, 3)
    missing = [int(s) for s in source.trajectory.steps if not _cached(cache / f"{int(s):05d}.npy", shape)]
    bar = progress_bar(total=len(missing), desc="render", unit="step", show=progress and bool(missing))
    for step, frame in zip(missing, _frames(source, missing, jobs), strict=True):
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


#: the ``config.yaml`` keys :func:`dataset_config` writes itself (``extra`` may add others, not replace them)
OWN_KEYS = ("filename", "is_labeled", "labeled_data_type", "labeled_data_suffix", "spike_h", "spike_w",
            "fps", "threshold", "colors", "noise", "seed", "scene", "steps", "warmup", "gt_every", "blur_fps",
            "blur_views", "test_views", "spikenerf_version", "command", "layout",
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
    cameras = {
        c: SpikeCamera(h, w, CameraConfig(options.threshold, c, options.noise, options.seed, options.warmup))
        for c in options.colors
    }
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
    mark(work, "dataset", files=True)
    failpoint("simulate.publish")
    shutil.rmtree(cache)
    replace_dir(work, out)
    return out

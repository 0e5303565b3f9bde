"""What ``spikenerf render`` writes: views as PNG, depth (colour-mapped PNG + .npy), a video, spike streams.

``render_run(run, out, trajectory)`` renders every pose of a trajectory — ``test`` (the held-out views),
``orbit`` (a closed orbit at the training path's mean radius and elevation), ``spiral`` (an LLFF-style
spiral around the mean training camera, for forward-facing captures), ``interpolate`` (a smooth path through
the training poses in time order), a transforms.json with ``frames[].transform_matrix`` or a nerfstudio
camera_path.json — and writes, each file atomically:

- ``images/NNNNN.png``: 8-bit sRGB-encoded colour (gray runs: 8-bit gray);
- ``depth/NNNNN.npy``: float32 (H, W) expected ray distance in world units (0 where empty);
- ``depth/NNNNN.png``: depth through the ``turbo`` colour map over the 1st–99th percentile of the depths
  of opaque pixels (opacity > 0.5) of the whole trajectory, composited on white by opacity;
- ``<name>.mp4`` (``orbit.mp4``, ``spiral.mp4``, ``interpolate.mp4``, ``test.mp4``, ``<file stem>.mp4``):
  the colour frames (H.264, yuv420p; frames edge-padded to even sizes);
- with ``spikes=True``: a novel-view spike stream along the trajectory, one step per pose (a generated
  path, orbit, spiral or interpolate, is re-sampled to ``spike_steps`` steps, by default the dataset's),
  fired from a seeded uniform start in [0, φ) with the dataset's threshold φ: ``spikes_gray.dat`` or
  ``spikes_rgb_{r,g,b}.dat`` (SpikeCV layout) and ``spikes_tfp.png``, the TFP reconstruction of its middle
  step;
- ``render.json``: what was written.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spikenerf.camera.io import write_dat, write_dat_rgb
from spikenerf.camera.layout import to_channels_last
from spikenerf.camera.reconstruct import DEFAULT_WINDOW, fitting_window
from spikenerf.camera.spikecv import CONFIG_NAME as SPIKECV_CONFIG
from spikenerf.camera.spikecv import write_spikecv_config
from spikenerf.core.atomic import write_bytes_atomic, write_text_atomic
from spikenerf.core.color import srgb_encode
from spikenerf.core.errors import InputError
from spikenerf.core.limits import check_resources
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import check_output, mark
from spikenerf.core.progress import bar as progress_bar
from spikenerf.core.video import check_fps, ffmpeg_module, to_uint8, write_video
from spikenerf.data.dataset import SpikeDataset
from spikenerf.data.reconstruction import frame_at
from spikenerf.eval.render_cache import RenderCache, cache_bytes, digest_array, render_key
from spikenerf.eval.render_output import (
    clear_previous_render,
    colorize_depth,
    depth_range,
    listed_files,
    planned_files,
    png_bytes,
    write_npy,
)
from spikenerf.eval.trajectories import (
    ALONG,
    DEFAULT_ORBIT_FRAMES,
    GENERATORS,
    TRAJECTORIES,
    RenderPath,
    refined_poses,
    resolve_trajectory,
)
from spikenerf.render.inference import inference_chunk, resolve_precision
from spikenerf.render.model import render_image
from spikenerf.render.spiking import iter_spike_states
from spikenerf.scenes.render_paths import GENERATED_PATHS
from spikenerf.scenes.trajectory import Intrinsics
from spikenerf.train.run import open_run

TFP_WINDOW = DEFAULT_WINDOW


def write_spikes(
    model: Any, path: RenderPath, dataset: SpikeDataset, out: Path, seed: int, chunk: int, progress: bool,
    cache: RenderCache, config: bool = True,
) -> list[str]:  # fmt: skip
    """Fire a novel-view spike stream along ``path`` (one step a pose), continuing what ``cache`` holds of
    it; write .dat file(s), a TFP preview and (with ``config``) their SpikeCV ``config.yaml`` (size, the
    dataset's rate, φ)."""
    k = path.intrinsics
    shape = (k.height, k.width) if model.channels == 1 else (3, k.height, k.width)
    resumed = cache.spike_state(shape)
    done, start = resumed if resumed is not None else ([], seed)
    cache.start_spikes(len(done), shape)
    states = iter_spike_states(
        model, path.poses[len(done) :], k, dataset.threshold, torch.as_tensor(start) if done else seed,
        chunk, path.near, path.far,
    )  # fmt: skip
    bar = progress_bar(total=len(path.poses), initial=len(done), desc="spikes", unit="step", show=progress)
    steps = list(done)
    for spikes, acc in states:
        steps.append(spikes.numpy())
        cache.put_spike_step(len(steps), steps[-1], acc)
        bar.update()
    bar.close()
    stream = np.stack(steps).astype(np.uint8)  # camera layout: (T, H, W) | (T, 3, H, W)
    if stream.ndim == 3:
        files = [out / "spikes_gray.dat"]
        write_dat(files[0], stream)
    else:
        files = write_dat_rgb(out / "spikes_rgb", stream)
    t = len(stream)
    window = fitting_window(t, TFP_WINDOW)
    preview = frame_at(stream, t // 2, "tfp", max(window, 1), dataset.threshold)
    preview = to_channels_last(preview, frame=True)
    write_bytes_atomic(out / "spikes_tfp.png", png_bytes(to_uint8(srgb_encode(preview))))
    names = [p.name for p in files] + ["spikes_tfp.png"]
    if config:  # the frame size, rate and φ beside the stream, so that info and reconstruct read it as it is
        write_spikecv_config(out, k.height, k.width, dataset.trajectory.fps, dataset.threshold)
        names.append(SPIKECV_CONFIG)
    return names


def render_run(
    run_dir: str | Path,
    out: str | Path,
    trajectory: str = "test",
    spikes: bool = False,
    fps_video: float = 30.0,
    orbit_frames: int = DEFAULT_ORBIT_FRAMES,
    spike_steps: int | None = None,
    seed: int = 0,
    device: str = "cpu",
    dataset_root: str | Path | None = None,
    chunk: int = 8192,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    precision: str = "auto",
) -> dict[str, Any]:
    """Render a run along ``trajectory`` into ``out`` (see the module doc); returns render.json's content.
    ``chunk``: rays per render call (0 = automatic); ``precision``: auto | fp32 | fp16 | bf16 of the views
    (:mod:`spikenerf.render.inference`; the spike stream renders in fp32)."""
    bad_steps = spike_steps is not None and spike_steps < 1
    check_fps(fps_video, "fps_video")  # ffmpeg writes too few frames or clamps outside FPS_VIDEO
    if orbit_frames < 1:
        raise InputError(f"orbit_frames must be ≥ 1, found {orbit_frames}", param="orbit_frames")
    if bad_steps:
        raise InputError(f"spike_steps must be ≥ 1, found {spike_steps}", param="spike_steps")
    ffmpeg_module()  # before any work: the video is the last file written
    out = Path(out)
    check_output(out, "render", overwrite=True)
    with output_lock(out), output_lock(run_dir, "RUN"):  # no train may write the run meanwhile
        return _render_locked(
            run_dir, out, trajectory, spikes, fps_video, orbit_frames, spike_steps, seed, device,
            dataset_root, chunk, progress, log, precision,
        )  # fmt: skip


#: memory a view holds until the video is written, (bytes a pixel, bytes a view): its colour, depth and
#: opacity, their stacks and the video's RGB frame (19.9 a pixel measured at 128×128), and its arrays with
#: the tensors under them (2.7 KiB a view measured at 16×16: a 400 000-pose trajectory file holds 3 GB)
VIEW_MEMORY = (20, 4096)
#: disk a view takes, (bytes a pixel, bytes a view): its PNGs, depth .npy and cache entry, and the least
#: size of those four files on disk (a 4 KiB block each: at 16×16, 2.6 times the pixels' share)
VIEW_DISK = (25, 4 * 4096)
#: memory a spike step holds, (bytes a pixel, bytes a step): measured 4.5 a pixel at 128×128, 4.7 KiB a
#: step at 16×16
SPIKE_MEMORY = (5, 4096)


def check_render_resources(k: Intrinsics, views: int, spike_steps: int, out: Path) -> None:
    """Refuse a render whose frames (kept for the video and the depth range), its cache or its files exceed
    the machine (``k``: the camera rendered; the space an interrupted render's cache holds counts as
    free)."""
    px = float(k.width) * k.height
    view, step = px * VIEW_MEMORY[0] + VIEW_MEMORY[1], px * SPIKE_MEMORY[0] + SPIKE_MEMORY[1]
    memory = views * view + spike_steps * step
    disk = views * (px * VIEW_DISK[0] + VIEW_DISK[1]) + spike_steps * (px * 3 / 4 + 256) - cache_bytes(out)
    check_resources(memory, disk, out, "orbit_frames/spike_steps/trajectory")


def package_version() -> str:
    """spikenerf's installed version ("source" when it runs from a checkout that is not installed)."""
    try:
        return metadata.version("spikenerf")
    except metadata.PackageNotFoundError:
        return "source"


def render_views(
    model: Any, path: RenderPath, cache: RenderCache, chunk: int, precision: str, progress: bool
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Each view of ``path`` as (8-bit sRGB colour (H, W) or (H, W, 3), depth (H, W), opacity (H, W)),
    from ``cache`` where it holds the view, else rendered and kept there."""
    k, views = path.intrinsics, ([], [], [])
    for i, pose in enumerate(
        progress_bar(path.poses, desc=f"render {path.name}", unit="view", show=progress)
    ):
        found = cache.view(i, (k.height, k.width), model.channels)
        if found is None:
            r = render_image(model, pose, k, path.near, path.far, chunk, precision)
            found = (
                to_uint8(srgb_encode(r.color.float().cpu().numpy())),
                r.depth.float().cpu().numpy(),
                r.opacity.float().cpu().numpy(),
            )
            cache.put_view(i, *found)
        for kept, value in zip(views, found, strict=True):
            kept.append(value)
    return views


def _render_locked(
    run_dir: str | Path, out: Path, trajectory: str, spikes: bool, fps_video: float, orbit_frames: int,
    spike_steps: int | None, seed: int, device: str, dataset_root: str | Path | None, chunk: int,
    progress: bool, log: Callable[[str], None] | None, precision: str = "auto",
) -> dict[str, Any]:  # fmt: skip
    t0 = time.perf_counter()
    previous = listed_files(out)  # a malformed render.json is refused before any work
    model, config, dataset, ckpt = open_run(run_dir, dataset_root, device, train_images=False)  # new views
    dataset = refined_poses(ckpt, config, dataset)
    precision = resolve_precision(precision, model.device)
    requested, chunk = chunk, inference_chunk(model, chunk)
    generated = trajectory in GENERATED_PATHS  # (a file called orbit.json is not: it fires one step a pose)
    views = orbit_frames if generated else len(dataset.test) if trajectory == "test" else 0
    n_spikes = (spike_steps or len(dataset.trajectory)) if generated else views
    check_render_resources(dataset.intrinsics, views, n_spikes if spikes else 0, out)
    path = resolve_trajectory(trajectory, dataset, orbit_frames)  # a file: its camera, one step a pose
    k, poses, n_spikes = path.intrinsics, path.poses, n_spikes if generated else len(path.poses)
    if spikes and (k.width * k.height) % 8:  # a .dat stores 8 pixels a byte: refused before any work
        raise InputError(
            f"spikes: a spike stream needs W·H a multiple of 8, but the trajectory's camera is "
            f"{k.width}×{k.height}",
            param=("spikes", "trajectory"),
        )
    check_render_resources(k, len(poses), n_spikes if spikes else 0, out)
    spike_path = None
    if spikes:
        spike_poses = GENERATORS[trajectory](dataset, n_spikes) if generated else poses
        spike_path = RenderPath(path.name, spike_poses, k, path.near, path.far, path.file)
    lens = [k.distortion.as_json()] if k.distortion else []  # (a pinhole keeps the key it had)
    key = render_key(
        model, config=model.hparams(), versions=[package_version(), torch.__version__], poses=poses,
        camera=[*(float(v) for v in dataclasses.astuple(k)[:6]), *lens],
        bounds=[path.near, path.far], precision=precision,
        device=model.device.type,
        spikes=None if spike_path is None else [digest_array(spike_path.poses), seed, dataset.threshold],
    )  # fmt: skip
    for sub in ("images", "depth"):  # written into and cleared: never through a link to someone's folder
        if (out / sub).is_symlink() or ((out / sub).exists() and not (out / sub).is_dir()):
            raise InputError(f"out: {sub} in it is a symbolic link or a file; move it", path=out, param="out")
    mark(out, "render")
    clear_previous_render(out, previous)
    # a config.yaml still there after clear_previous_render is not one a render wrote: it stays untouched
    own_config = not (out / SPIKECV_CONFIG).exists()
    plan = planned_files(path.name, model.channels, spike_path is not None, own_config)
    cache = RenderCache.open(out, key, pinned={"chunk": chunk}, plan=plan)
    if not requested and cache.pinned["chunk"] > 0:  # resumed: the automatic chunk it began with
        chunk = cache.pinned["chunk"]
    colors, depths, opacities = render_views(model, path, cache, chunk, precision, progress)
    depth_all, op_all = np.stack(depths), np.stack(opacities)
    lo, hi = depth_range(depth_all, op_all)
    for i, (color, depth, opacity) in enumerate(zip(colors, depths, opacities, strict=True)):
        write_bytes_atomic(out / "images" / f"{i:05d}.png", png_bytes(color))
        write_npy(out / "depth" / f"{i:05d}.npy", depth.astype(np.float32))
        write_bytes_atomic(out / "depth" / f"{i:05d}.png", png_bytes(colorize_depth(depth, opacity, lo, hi)))
    video = f"{path.name}.mp4"
    write_video(out / video, colors, fps_video)
    files: dict[str, Any] = {"images": "images/NNNNN.png", "depth": "depth/NNNNN.{png,npy}", "video": video}
    if spike_path is not None:
        files["spikes"] = write_spikes(model, spike_path, dataset, out, seed, chunk, progress, cache,
                                       own_config)  # fmt: skip
        if not own_config and log:
            log(f"kept the {SPIKECV_CONFIG} already in {out} (render did not write it): the stream is "
                f"{k.width}×{k.height}")  # fmt: skip
    manifest = {
        "run": str(Path(run_dir).resolve()),
        "iteration": int(ckpt["iteration"]),  # of the run's iterations: a render of an unfinished run says so
        "run_iterations": config.iters,
        "trajectory": path.file or path.name,
        "trajectory_file": None if trajectory in TRAJECTORIES else str(Path(trajectory).resolve()),
        "trajectory_kind": path.kind,
        "views": len(poses),
        "channels": model.channels,
        "size": [k.width, k.height],
        "camera": {"fl_x": float(k.fl_x), "fl_y": float(k.fl_y), "cx": float(k.cx), "cy": float(k.cy)}
        | (k.distortion.as_json() if k.distortion else {}),
        "near_far": [float(path.near), float(path.far)],
        "depth_range": [lo, hi],
        "fps_video": fps_video,
        "video_size": [k.width + k.width % 2, k.height + k.height % 2],  # write_video's even padding
        "spike_steps": None if spike_path is None else len(spike_path.poses),
        "spike_seed": seed if spikes else None,
        "precision": precision,
        "threshold": dataset.threshold,
        "files": files,
        "seconds": round(time.perf_counter() - t0, 3),
    }
    write_text_atomic(out / "render.json", json.dumps(manifest, indent=2) + "\n")
    cache.close()
    if log:
        along = f"along the trajectory file {path.file}" if path.file else ALONG[path.name]
        views = f"{len(poses)} view{'' if len(poses) == 1 else 's'} {along}"
        log(f"wrote {out}: {views}, {video}" + (", spike stream" if spikes else ""))
    return manifest

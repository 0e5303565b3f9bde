"""``describe(path)``: a text summary of a dataset folder plus ``DIR/preview.png`` (TFP next to the GT)."""

from __future__ import annotations

import io
import math
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import yaml

from spikenerf.camera.layout import to_channels_last
from spikenerf.camera.modes import COLORS as MODES
from spikenerf.camera.reconstruct import DEFAULT_WINDOW, fitting_window
from spikenerf.camera.stats import dat_rate_summary
from spikenerf.core.atomic import write_bytes_atomic
from spikenerf.core.color import display_uint8, rgb_to_gray, srgb_encode
from spikenerf.core.errors import InputError
from spikenerf.core.marker import folder_kind, listed, mark
from spikenerf.core.yamlio import load_yaml
from spikenerf.data.dataset import (
    CONFIG,
    TRANSFORMS,
    TRANSFORMS_BLUR,
    UNFINISHED,
    SpikeDataset,
    load_dataset,
    read_mapping,
    recording_in,
    spike_files,
)
from spikenerf.data.reconstruction import frame_at
from spikenerf.scenes.projection import image_motion
from spikenerf.scenes.transforms import number, read_transforms

PREVIEW = "preview.png"
#: TFP window of the preview (frames), shortened for streams with fewer steps
PREVIEW_WINDOW = DEFAULT_WINDOW
#: the preview is upscaled (nearest neighbour) to at least this height in pixels
PREVIEW_MIN_HEIGHT = 128


def preview_image(ds: SpikeDataset, mode: str | None = None) -> tuple[np.ndarray, str]:
    """TFP reconstruction and GT side by side at the GT step nearest the middle of the path.

    Args:
        ds: the dataset. mode: colour mode to reconstruct (default: gray, else rgb, else bayer).
    Returns:
        display image uint8 (H·s, (2W + 2)·s, 3) sRGB-encoded, and a caption.
    """
    mode = mode or next(m for m in MODES if m in ds.modes)
    n = len(ds.trajectory)
    steps = ds.trajectory.steps
    if len(ds.gt):
        target = ds.gt.steps[np.abs(ds.gt.steps - steps[n // 2]).argmin()]
        pos = int(np.searchsorted(steps, target))
    else:
        pos = n // 2
    imported = (ds.config or {}).get("imported") or {}
    keyframe_window = imported.get("window") if imported.get("keyframe_images", "tfp") == "tfp" else None
    window = fitting_window(n, keyframe_window if isinstance(keyframe_window, int) else PREVIEW_WINDOW)
    read = lambda a, b: ds.spikes(mode, slice(a, b))  # noqa: E731
    recon = frame_at(read, pos, "tfp", window, ds.threshold, n)
    recon = np.repeat(to_channels_last(recon, frame=True), 3 if mode != "rgb" else 1, -1)  # (H, W, 3)
    h = recon.shape[0]
    panels = [recon]
    caption = f"{PREVIEW}: TFP ({mode}, window {window}) at step {int(steps[pos])}"
    if len(ds.gt):
        gt = ds.gt.images[list(ds.gt.steps).index(steps[pos])]
        gt = np.repeat(rgb_to_gray(gt, channel_axis=-1)[..., None], 3, -1) if mode == "gray" else gt
        panels += [np.full((h, 2, 3), 0.5, np.float32), gt]
        caption += " | GT render"
    image = display_uint8(srgb_encode(np.concatenate(panels, axis=1)))
    s = max(1, math.ceil(PREVIEW_MIN_HEIGHT / h))
    return np.repeat(np.repeat(image, s, 0), s, 1), caption


def view_counts(root: str | Path) -> dict:
    """What a dataset folder offers for training, from its JSON/YAML files only (no images are read).

    Returns:
        ``steps`` (spike steps = poses), ``gt`` (stored sharp renders), ``blur`` (blur views, 0 without
        ``transforms_blur.json``) and ``blur_views`` (``config.yaml``; ``frames`` for older datasets).
    """
    root = Path(root)
    frames = read_mapping(root / TRANSFORMS).get("frames") or []
    blur_data = read_mapping(root / TRANSFORMS_BLUR) if (root / TRANSFORMS_BLUR).is_file() else {}
    blur = blur_data.get("frames") or []
    train = blur_data.get("train_filenames")  # a nerfstudio view lists its held-out frames too
    if isinstance(train, list):
        blur = [f for f in blur if isinstance(f, dict) and f.get("file_path") in train]
    try:
        config = load_yaml((root / CONFIG).read_text(encoding="utf-8")) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        config = {}
    return {
        "steps": len(frames),
        "gt": sum(isinstance(f, dict) and "file_path" in f for f in frames),
        "blur": len(blur),
        "blur_views": config.get("blur_views", "frames") if isinstance(config, dict) else "frames",
    }


def _imported_lines(imported: dict) -> list[str]:
    """What ``import`` recorded (``config.yaml``'s ``imported``): the recording and its steps, the pose
    source, the keyframes, and which of them are the test views."""
    first, stop = (imported.get("range") or [None, None])[:2]
    steps = f" (steps {first}..{stop - 1})" if isinstance(first, int) and isinstance(stop, int) else ""
    source = imported.get("poses")
    if source == "orbit" and imported.get("orbit"):
        source = f"orbit {imported['orbit']}"
    images = imported.get("keyframe_images", "tfp")
    window = f", window {imported['window']}" if images == "tfp" and imported.get("window") else ""
    lines = [
        f"imported: {imported.get('recording')}{steps}   poses: {source}",
        f"keyframes: {imported.get('keyframes')} every {imported.get('keyframe_every')} steps "
        f"({images}{window})",
    ]
    if tests := imported.get("test_keyframes"):  # dataset steps; the recording's where its range is known
        shift, whose = (first, "recording ") if isinstance(first, int) else (0, "")
        at = ", ".join(str(shift + int(t)) for t in tests)
        lines[-1] += f"   test views: the keyframes at {whose}steps {at} (no sharp ground truth)"
    return lines


def describe(path: str | Path) -> str:
    """Summarise a dataset folder (views, steps, size, spike rates per mode); writes ``DIR/preview.png``."""
    path = Path(path)
    if not (path / TRANSFORMS).is_file():
        if path.name.endswith(".partial"):
            raise InputError(UNFINISHED, path)
        if recording := recording_in(path):
            raise InputError(recording, path=path)
        raise InputError(f"not a dataset folder (no {TRANSFORMS})", path=path)
    ds = load_dataset(path)
    cfg, k, traj = ds.config, ds.intrinsics, ds.trajectory
    n = len(traj)
    lines = [
        f"dataset: {path}",
        f"scene: {cfg.get('scene', '?')}   resolution: {k.width}×{k.height}   "
        f"fov: {math.degrees(k.view_angle_x):.1f}°"
        + (f" (through the lens)   lens: {k.distortion.describe()}" if k.distortion else ""),
        f"steps: {n} at {traj.fps:g} Hz ({n / traj.fps * 1e3:.4g} ms)   threshold φ = {ds.threshold:g}"
        + "".join(f"   {key}: {cfg[key]}" for key in ("noise", "seed") if key in cfg)  # (simulated only)
        + _noise_params(cfg.get("noise_params")),
        f"scene box: {ds.scene_box.tolist()}   near/far: {ds.near:.3g}/{ds.far:.3g}",
        f"GT renders: {len(ds.gt) or 'none'}"
        + (f" (every {cfg['gt_every']} steps)" if len(ds.gt) and "gt_every" in cfg else "")
        + f"   test views: {len(ds.test)}",
    ]
    if isinstance(imported := cfg.get("imported"), dict):
        lines += _imported_lines(imported)
    if n >= 2:  # what --integral-window should span (docs/spike-integral.md, Choosing L and S)
        motion = image_motion(traj.poses, k, ds.scene_box)
        lines.append(f"image motion: {motion:.3g} px a step (median over points in the scene box)")
    if ds.blur is not None and len(ds.blur):
        span = ds.blur.step_ranges[:, 1] - ds.blur.step_ranges[:, 0]
        steps = f"{int(span.min())}" if span.min() == span.max() else f"{int(span.min())}–{int(span.max())}"
        blur_meta = read_transforms(path / TRANSFORMS_BLUR)
        rate = traj.fps / int(span.max())  # as realised, where the file gives no rate
        if blur_meta.get("fps") is not None:
            rate = number(blur_meta, "fps", path / TRANSFORMS_BLUR, positive=True)
        starts, ends = ds.blur.step_ranges[:, 0], ds.blur.step_ranges[:, 1]
        overlap = bool(np.any(starts[1:] < ends[:-1]))  # blur_views all: one exposure centred on each step
        lines.append(
            f"blur frames: {len(ds.blur)} at {rate:.4g} fps ({steps} steps of exposure each"
            + ("; overlapping exposures, not consecutive frames)" if overlap else ")")
        )
    else:
        lines.append("blur frames: none")
    for mode in ds.modes:
        parts = []
        for name in spike_files(mode):
            r = dat_rate_summary(path / name, k.height, k.width)
            parts.append(
                f"{name} {r['mean_rate']:.4g} spikes/pixel/step ({r['mean_rate'] * traj.fps:.4g} Hz), "
                f"silent {r['silent_fraction'] * 100:.3g}%, saturated {r['saturated_fraction'] * 100:.3g}%"
            )
        lines.append(f"spikes [{mode}]: " + "; ".join(parts))
    image, caption = preview_image(ds)
    buf = io.BytesIO()
    iio.imwrite(buf, image, extension=".png")
    try:
        write_bytes_atomic(path / PREVIEW, buf.getvalue())
        own = listed(path)
        if own and PREVIEW not in own and folder_kind(path) == "dataset":  # ours: `--overwrite` replaces it
            mark(path, "dataset", [*own, PREVIEW])
    except OSError as err:  # a read-only folder (a share, another user's): the summary without a preview
        lines.append(f"preview: not written, {path} is not writable ({err.strerror or err})")
        return "\n".join(lines)
    lines.append(caption)
    return "\n".join(lines)


def _noise_params(params: object) -> str:
    """`` (dark_mean=0, ...)``: the realistic preset's parameters that ``simulate --noise-param`` replaced."""
    if not isinstance(params, dict) or not params:
        return ""
    return " (" + ", ".join(f"{key}={value:g}" if isinstance(value, float) else f"{key}={value}"
                            for key, value in params.items()) + ")"  # fmt: skip

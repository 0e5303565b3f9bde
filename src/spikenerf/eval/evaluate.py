"""Evaluate a trained run on held-out views and write ``RUN/metrics.json`` (see docs/metrics.md).

Every view is rendered from the run's model, then prediction and ground truth are compared as *displayed*:
linear radiance → :func:`~spikenerf.core.color.srgb_encode` → [0, 1]. Gray runs (one channel) are compared
with the gray of the linear GT (0.299R + 0.587G + 0.114B, then encoded). Means are plain averages of the
per-view values (the NeRF convention: mean PSNR, not the PSNR of the mean MSE).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spikenerf.camera.reconstruct import check_window
from spikenerf.core.atomic import clean_stale_temps, write_text_atomic
from spikenerf.core.color import rgb_to_gray, srgb_encode
from spikenerf.core.errors import InputError, as_path
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import owned
from spikenerf.core.progress import bar as progress_bar
from spikenerf.data.dataset import PosedImages, SpikeDataset
from spikenerf.data.holdout import check_steps, read_record
from spikenerf.data.targets import image_channels, window_steps
from spikenerf.eval import lpips as lp
from spikenerf.eval.choices import SPLITS
from spikenerf.eval.metrics import SSIMConfig, mean_or_none, psnr, ssim
from spikenerf.eval.noref import NoRefOptions, check_noref, noref_metrics, wants_noref
from spikenerf.render.inference import inference_chunk, resolve_precision
from spikenerf.render.model import render_mean
from spikenerf.train.pose_fit import check_fit_args, fit_view_poses
from spikenerf.train.pose_refine import refined_dataset, refined_views
from spikenerf.train.run import open_run, run_iteration

METRICS_FILE = "metrics.json"


def metrics_file(split: str) -> str:
    """The file a ``split``'s scores go to in the run folder: :data:`METRICS_FILE` for the held-out test
    views (what ``info``, the benchmark and the report read), ``metrics_train.json`` for the train split, so
    that scoring the training path keeps the held-out scores."""
    return METRICS_FILE if split == "test" else f"metrics_{split}.json"


SPACE = "sRGB-encoded [0,1]"
#: random pixels per view and step of the test-time pose optimisation
POSE_BATCH = 1024
POSE_PROTOCOL = (
    "each test view's pose fitted to its own test image (6 numbers per view, Adam on the linear MSE of "
    "random pixels; the field frozen; a view scored against the mean of view_poses renders moves them "
    "together), then scored; a view whose fitted pose scores a lower PSNR keeps its given pose and plain "
    "score; reported beside the plain score, never instead of it"
)


def has_views(dataset: SpikeDataset, split: str) -> bool:
    """Whether the dataset has views of ``split`` (``test`` or ``train``) to score against."""
    views = dataset.test if split == "test" else dataset.gt
    return views is not None and len(views) > 0


def split_views(dataset: SpikeDataset, split: str) -> PosedImages:
    """Posed GT images of a split: ``test`` = held-out views, ``train`` = sharp GT on the training path."""
    if split not in SPLITS:
        raise InputError(f"split must be one of {', '.join(SPLITS)}, found {split!r}", param="split")
    views = dataset.test if split == "test" else dataset.gt
    if not has_views(dataset, split):
        source = "transforms_test.json" if split == "test" else "gt/ frames in transforms.json"
        listed = split == "test" and (dataset.root / source).is_file()
        source = f"{source} lists none" if listed else f"expected {source}"
        fix = "; add test views when simulating it, or score the train split" if split == "test" else ""
        raise InputError(f"the dataset has no {split} views ({source}){fix}", path=dataset.root)
    return views


def keyframe_windows(dataset: SpikeDataset, count: int, views: PosedImages) -> np.ndarray | None:
    """Trajectory indices (V, S) whose mean render each test view is scored against, or None (one render
    at each view's pose).

    Only where the test views are TFP keyframes of the stream, i.e. an imported dataset with
    ``keyframe_images: tfp`` whose test views are its ``test_keyframes`` (in that order, as ``import``
    writes them; each the mean light of its keyframe window), and the run was trained with window-aware
    targets (``count`` = its poses per target > 1): it then renders sharp images, and the mean of
    ``count`` renders over the keyframe's window is what the keyframe shows. None as well for an import
    that did not record its keyframe ``window`` (older versions), or without recorded test keyframes.
    InputError (naming the dataset) when the recorded keyframes or window are malformed, or the test views
    are not as many as the recorded keyframes (the dataset was edited after ``import``; scoring one render
    instead would hide it).
    """
    imported = (dataset.config or {}).get("imported") or {}
    keys, window = imported.get("test_keyframes") or [], imported.get("window")
    tfp = imported.get("keyframe_images", "tfp") == "tfp"
    if count < 2 or not tfp or window is None or not keys:
        return None  # one pose, learned keyframes, or an import from before the window was recorded
    check_window(window, "imported.window", path=Path(dataset.root) / "config.yaml")
    if not len(views):  # nothing to score (the no-reference checks alone)
        return None
    steps, _ = check_steps(dataset, 0)  # the recorded keyframes' stream indices, checked
    if len(steps) != len(views):
        raise InputError(
            f"the dataset has {len(views)} test views but config.yaml records {len(steps)} imported test "
            "keyframes (imported.test_keyframes); re-run import, or restore the test views it wrote",
            path=dataset.root,
        )
    return window_steps(len(dataset.trajectory), window, count)[steps]


def display(linear: torch.Tensor | np.ndarray, channels: int) -> torch.Tensor:
    """Linear (H, W, 3 or C) → displayed (C, H, W) float32 in [0, 1]; 3 → 1 channel via ``rgb_to_gray``."""
    x = torch.as_tensor(np.asarray(linear) if not isinstance(linear, torch.Tensor) else linear).float().cpu()
    if channels == 1 and x.shape[-1] == 3:
        x = rgb_to_gray(x, channel_axis=-1)[..., None]
    if x.shape[-1] != channels:
        raise ValueError(f"cannot show an image with {x.shape[-1]} channels as {channels}")
    return srgb_encode(x).permute(2, 0, 1).contiguous()


def _finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def score_view(
    pred: torch.Tensor, target: torch.Tensor, lpips_backbone: str | None
) -> dict[str, float | None]:
    """PSNR (dB), SSIM and LPIPS of one displayed pair (C, H, W); a metric that cannot run, or is not finite
    (a NaN in the render; PSNR +∞ of a perfect view), is None."""
    side = min(pred.shape[-2:])
    out: dict[str, float | None] = {"psnr": _finite(float(psnr(pred, target)))}
    out["ssim"] = _finite(float(ssim(pred, target))) if side >= SSIMConfig().window else None
    out["lpips"] = _finite(float(lp.lpips(pred, target, lpips_backbone))) if lpips_backbone else None
    return out


def lpips_status(backbone: str | None, height: int, width: int) -> tuple[str | None, str | None]:
    """(backbone to use or None, reason it is not used or None)."""
    if backbone is None:
        return None, "no LPIPS backbone was chosen"
    if backbone not in lp.MIN_SIZE:
        known = ", ".join(lp.MIN_SIZE)
        raise InputError(
            f"lpips_backbone must be {known} or None, found {backbone!r}", param="lpips_backbone"
        )
    reason = lp.lpips_unavailable_reason(backbone)
    if reason is None and min(height, width) < lp.MIN_SIZE[backbone]:
        need = lp.MIN_SIZE[backbone]
        reason = f"images {width}×{height} are smaller than LPIPS-{backbone}'s minimum of {need} px a side"
    return (None, reason) if reason else (backbone, None)


def pose_optimised(
    model: Any, views: PosedImages, k: Any, dataset: SpikeDataset, backbone: str | None, chunk: int,
    test_pose: tuple[int, float], window: np.ndarray | None = None, precision: str = "fp32",
    given: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:  # fmt: skip
    """Scores of ``views`` (V poses (V, 4, 4), images (V, H, W, 3)) after fitting each pose to its own image
    with the model frozen (:func:`spikenerf.train.pose_fit.fit_view_poses`, ``test_pose`` = (steps, lr)).
    ``window`` (V, S, 4, 4): each view's S poses whose mean render it shows (``keyframe_windows``), fitted
    with one correction per view and scored by their mean render; None: the views' own poses. ``given``: the
    plain per-view scores at those poses; a view whose fitted pose scores a lower PSNR keeps them (the fit,
    on random pixels, can end worse than it began), with ``fit_kept`` False and a zero correction."""
    steps, lr = test_pose
    targets = image_channels(np.asarray(views.images), "gray" if model.channels == 1 else "rgb")
    start = np.asarray(views.poses)[:, None] if window is None else np.asarray(window)
    fit = fit_view_poses(model, torch.as_tensor(start), targets, k, dataset.near, dataset.far, steps=steps,
                         lr=lr, batch=POSE_BATCH)  # fmt: skip
    per_view = []
    for i, poses in enumerate(fit.poses):
        color = render_mean(model, poses, k, dataset.near, dataset.far, chunk, precision)
        pred = display(color, model.channels)
        scores = score_view(pred, display(views.images[i], model.channels), backbone)
        size = {"rotation_deg": float(fit.rotation_deg[i]), "translation": float(fit.translation[i])}
        plain, fitted = (None, None) if given is None else (given[i]["psnr"], scores["psnr"])
        # kept unless the given pose images the view better, or either PSNR is not a number (None: an
        # exact render's inf or a broken one's NaN): then the plain score stands
        kept = given is None or (plain is not None and fitted is not None and plain <= fitted)
        if not kept:
            scores = {m: given[i][m] for m in ("psnr", "ssim", "lpips")}  # type: ignore[index]
            size = {"rotation_deg": 0.0, "translation": 0.0}
        per_view.append({"index": i, **scores, **size, "fit_kept": kept})
    keys = ("psnr", "ssim", "lpips", "rotation_deg", "translation")
    return {
        "protocol": POSE_PROTOCOL,
        "steps": steps,
        "lr": lr,
        "batch": POSE_BATCH,
        "mean": {m: mean_or_none([v[m] for v in per_view]) for m in keys},
        "fits_kept": sum(v["fit_kept"] for v in per_view),
        "per_view": per_view,
    }


def evaluate_run(
    run_dir: str | Path,
    split: str = "test",
    device: str = "cpu",
    dataset_root: str | Path | None = None,
    lpips_backbone: str | None = "alex",
    chunk: int = 8192,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    noref: str = "auto",
    noref_options: NoRefOptions | None = None,
    test_pose: tuple[int, float] = (0, 2e-3),
    precision: str = "auto",
) -> dict[str, Any]:
    """Render every view of ``split``, score it and write ``RUN/metrics.json`` (:func:`metrics_file`)
    atomically.

    Args:
        run_dir: a run folder written by ``spikenerf train``.
        split: ``test`` (held-out novel views) or ``train`` (sharp GT along the training path).
        device: auto | cpu | cuda[:N] | mps. dataset_root: the dataset if it moved since training.
        lpips_backbone: ``alex`` (default), ``vgg`` or None (skip LPIPS).
        chunk: rays per render call; 0 = automatic (8192 off CUDA, sized from the free GPU memory on CUDA;
            :func:`spikenerf.render.inference.inference_chunk`).
        precision: auto (default: fp16 on CUDA, fp32 elsewhere), fp32, fp16 (CUDA) or bf16: the renders'
            autocast precision (the no-reference checks render in fp32); metrics.json records the one used.
        noref: ``auto`` (on for imported datasets), ``on`` or ``off``: the no-reference checks against the
            recording itself (:mod:`spikenerf.eval.noref`). noref_options: their settings.
        progress: progress bars. log: called with each warning line (None: silent; the result holds
            the scores, ``eval.describe`` words them).
        test_pose: (iterations, learning rate) of the test-view pose fit (iterations 0: off;
            ``eval --test-pose-opt``, ``--test-pose-lr``).
    Returns:
        The metrics.json content (see docs/formats.md): split, method, color, field, iterations, views,
        mean {psnr, ssim, lpips}, per_view, lpips_backbone, lpips_reason, space, no_reference,
        test_pose_optimised (None when off), precision, seconds.
    """
    run_dir = as_path(run_dir, "run_dir")
    noref_options = NoRefOptions() if noref_options is None else noref_options
    noref_options.check()
    check_noref(noref)
    if log is not None and not callable(log):
        found = type(log).__name__
        raise InputError(f"log must be a function of one line or None, found {found}", param="log")
    if not isinstance(test_pose, tuple | list) or len(test_pose) != 2:
        raise InputError(
            f"test_pose must be (iterations, learning rate), found {test_pose!r:.60}", param="test_pose"
        )
    names = ("test_pose iterations", "test_pose learning rate", "POSE_BATCH")
    check_fit_args(test_pose[0], test_pose[1], POSE_BATCH, names)
    with output_lock(run_dir, "RUN"):
        if owned(run_dir):
            clean_stale_temps(run_dir)  # what a killed writer left (a train's checkpoint, an eval's metrics)
        return _evaluate_locked(
            Path(run_dir), split, device, dataset_root, lpips_backbone, chunk, progress, log,
            (noref, noref_options), test_pose, precision,
        )  # fmt: skip


def _evaluate_locked(
    run_dir: Path, split: str, device: str, dataset_root: str | Path | None, lpips_backbone: str | None,
    chunk: int, progress: bool, log: Callable[[str], None] | None, noref: tuple[str, NoRefOptions],
    test_pose: tuple[int, float], precision: str,
) -> dict[str, Any]:  # fmt: skip
    t0 = time.perf_counter()
    model, config, dataset, ckpt = open_run(run_dir, dataset_root, device, train_images=split != "test")
    precision = resolve_precision(precision, model.device)
    chunk = inference_chunk(model, chunk)
    held = read_record(run_dir)
    use_noref = wants_noref(noref[0], dataset, held is not None)
    default = dataclasses.asdict(NoRefOptions())
    changed = [f"{k} {v}" for k, v in dataclasses.asdict(noref[1]).items() if v != default[k]]
    if not use_noref and noref[0] == "auto" and changed and log is not None:
        log(  # before the renders, not after them
            f"spikenerf: warning: the no-reference settings ({', '.join(changed)}) are unused: the checks do "
            "not run on this dataset, which was not imported (noref auto; noref on runs them here)"
        )
    if use_noref and not has_views(dataset, split):  # real data without test views: the checks alone
        k = dataset.intrinsics
        views = PosedImages(np.zeros((0, 4, 4), np.float32), np.zeros((0, k.height, k.width, 3), np.float32))
    else:
        views = refined_views(ckpt, config, dataset, split_views(dataset, split))
    k = dataset.intrinsics
    backbone, reason = lpips_status(lpips_backbone, k.height, k.width)
    if reason and log and lpips_backbone is not None:  # (asked for and not possible: a warning)
        log(f"spikenerf: warning: LPIPS skipped: {reason}")
    per_view = []
    windows = keyframe_windows(dataset, config.window_poses(), views) if split == "test" else None
    window = None  # each test keyframe's S poses on the run's (refined) path: (V, S, 4, 4)
    if windows is not None:
        window = np.asarray(refined_dataset(ckpt, config, dataset).trajectory.poses)[windows]
    for i in progress_bar(range(len(views)), desc=f"eval {split}", unit="view", show=progress):
        poses = [views.poses[i]] if window is None else window[i]  # one pose, or a keyframe's window
        color = render_mean(model, poses, k, dataset.near, dataset.far, chunk, precision)
        pred = display(color, model.channels)
        target = display(views.images[i], model.channels)
        per_view.append({"index": i, **score_view(pred, target, backbone)})
    result = {
        "split": split,
        "method": config.method,
        "color": config.color,
        "field": config.field,
        "iterations": run_iteration(run_dir),
        "views": len(per_view),
        "view_poses": 1 if windows is None else int(windows.shape[1]),
        "mean": {m: mean_or_none([v[m] for v in per_view]) for m in ("psnr", "ssim", "lpips")},
        "per_view": per_view,
        "lpips_backbone": backbone,
        "lpips_reason": reason,
        "space": SPACE,
        "no_reference": None,
        "test_pose_optimised": None,
        "precision": precision,
        "seconds": 0.0,
    }
    if test_pose[0] > 0 and len(views):
        result["test_pose_optimised"] = pose_optimised(
            model, views, k, dataset, backbone, chunk, test_pose, window, precision, per_view
        )
    if use_noref:

        def bar(steps: Any) -> Any:
            return progress_bar(steps, desc="no-reference", unit="step", show=progress)

        path = refined_dataset(ckpt, config, dataset)  # the poses the model was fitted to
        result["no_reference"] = noref_metrics(model, config, path, noref[1], chunk, display, bar, held)
    result["seconds"] = round(time.perf_counter() - t0, 3)
    write_text_atomic(run_dir / metrics_file(split), json.dumps(result, indent=2, allow_nan=False) + "\n")
    return result

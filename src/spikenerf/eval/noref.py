"""No-reference checks of a run against its own recording (for real data, which has no ground truth).

At a few *check steps* k of the training path (an imported dataset's test keyframes, else evenly spaced
steps) the model is scored against the recorded spike stream alone (docs/metrics.md, docs/real-data.md):

* **masked PSNR / SSIM** of the render at the pose of step k (for a run with window-aware targets, the
  mean of its S renders over the TFP window, what it was trained to match) against the run's own
  reconstruction ``Î_k`` (TFP, TFI or the learned reconstructor, with the run's window), counted only where
  the spike mask ``M_k`` is set (a spike fell in steps k−n..k+n, the run's mask n): elsewhere the
  reconstruction says only "dark".
  Both are displayed values (sRGB-encoded [0, 1]), as every eval metric.
* the **interval-violation rate** of the L steps around k: the fraction of sampled pixel windows whose
  rendered integral lies outside the interval that the recorded spike count allows — the spike loss's own
  constraint (:func:`spikenerf.train.losses.spike_interval_violation`, whole windows) — and the **mean
  violation** in units of φ. The same numbers for ``Î_k`` held constant over the window are given as a
  reference point.
* **PIQE** (:mod:`spikenerf.eval.piqe`), a no-reference image score that needs no trained weights, of the
  same displayed render (``piqe_render``) and, as a reference point again, of ``Î_k`` (``piqe_recon``):
  0…100, higher = worse; it judges how natural one image looks, not whether it matches the recording.

A run trained with the hold-out (``train --holdout``, on by default for imported datasets) never saw the
check steps: training drew no image target and no spike window within its guard band of them
(:mod:`spikenerf.data.holdout`, recorded in ``RUN/holdout.json``; a TFI or TFSTP image of a check step is
then made from the steps within its ``check_reach``). The checks then score those very steps and
report ``steps_trained_on: false`` (and ``windows_in_guard: false`` where a spike window longer than the band,
``spike_window``, reaches steps that training saw); otherwise the run fitted them too (``true``) and the
scores say how well the model explains the recording, not how well it generalises.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from spikenerf.camera.layout import to_channels_last
from spikenerf.camera.masks import spike_masks
from spikenerf.camera.reconstruct import WINDOWLESS
from spikenerf.core.config import Bound, check_config
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import SpikeDataset
from spikenerf.data.holdout import check_steps, is_imported
from spikenerf.data.reconstruction import frames_reconstructor
from spikenerf.data.targets import reconstruct_stream, stream_mode, window_steps
from spikenerf.eval.choices import NOREF_MODES
from spikenerf.eval.metrics import SSIMConfig, mean_or_none, psnr, ssim
from spikenerf.eval.piqe import BLOCK, piqe
from spikenerf.render.base import RadianceModel
from spikenerf.render.model import render_mean
from spikenerf.render.spiking import render_spike_window
from spikenerf.train.config import TrainConfig
from spikenerf.train.losses import spike_interval_violation

#: why the image score is null, where it is (PIQE scores whole 16 × 16 blocks)
SMALL_IMAGE_REASON = (
    f"not computed: the images are under {BLOCK} px a side (PIQE scores {BLOCK}x{BLOCK} blocks)"
)


def image_score_info() -> dict[str, Any]:
    """The ``image_score`` entry of the checks: the score's name, the per-step (and ``mean``) keys that
    hold it for the render and the reconstruction, its range and its direction (docs/metrics.md)."""
    return {
        "name": "PIQE",
        "render": "piqe_render",
        "reconstruction": "piqe_recon",
        "range": [0, 100],
        "higher_is_worse": True,
    }


@dataclass(frozen=True)
class NoRefOptions:
    """steps: check steps for a dataset without imported test keyframes. spike_window: L (None: the run's
    spike window). spike_pixels: pixels sampled per check step (0: all). seed: pixel sampling seed."""

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "steps": Bound(least=1), "spike_window": Bound(least=1), "spike_pixels": Bound(least=0),
    }  # fmt: skip

    steps: int = 8
    spike_window: int | None = None
    spike_pixels: int = 4096
    seed: int = 0

    def check(self) -> None:
        """InputError naming the option on a wrong type or an out-of-range value."""
        check_config(self)


def check_noref(noref: object) -> str:
    """``noref`` itself when it is one of :data:`NOREF_MODES`; else InputError naming ``noref``."""
    if not isinstance(noref, str) or noref not in NOREF_MODES:
        raise InputError(f"noref must be one of {', '.join(NOREF_MODES)}, found {noref!r}", param="noref")
    return noref


def wants_noref(noref: str, dataset: SpikeDataset, held: bool = False) -> bool:
    """Whether the no-reference checks run: ``noref`` ``auto`` turns them on for an imported dataset (its
    config has an ``imported`` section) or a run that ``held`` steps out; ``on``/``off`` decide alone."""
    noref = check_noref(noref)
    return noref == "on" or (noref == "auto" and (held or is_imported(dataset)))


def windows_in_guard(steps: Any, length: int, total: int, radius: Any) -> bool:
    """Whether the ``length``-step spike window of every check step lies in its guard band (``step ±
    radius``, none of which training saw); a longer window (``spike_window``) reaches trained steps."""
    if not isinstance(radius, int) or isinstance(radius, bool):
        return False
    for step in (int(s) for s in steps):
        start = window_start(step, length, total)
        if start < step - radius or start + length - 1 > step + radius:
            return False
    return True


def window_start(step: int, length: int, total: int) -> int:
    """First step of the ``length``-step window centred on ``step``, shifted to lie inside ``total`` steps."""
    return int(min(max(step - length // 2, 0), max(total - length, 0)))


def violation_stats(intensity: torch.Tensor, recorded: torch.Tensor, threshold: float) -> tuple[float, float]:
    """(violation rate, mean violation / φ) of whole windows. intensity, recorded: (L, P, C)."""
    violation, _, valid = spike_interval_violation(intensity, recorded, threshold, pairs="window")
    v = violation[valid].double()
    return float((v > 0).double().mean()), float(v.mean() / threshold)


def _sample_pixels(height: int, width: int, count: int, seed: int) -> torch.Tensor:
    """(P, 2) int64 ``(x, y)``: all pixels when ``count`` is 0 or covers the image, else a seeded sample."""
    total = height * width
    gen = torch.Generator().manual_seed(seed)
    idx = (
        torch.arange(total) if count == 0 or count >= total else torch.randperm(total, generator=gen)[:count]
    )
    return torch.stack([idx % width, idx // width], dim=1)


def _render_window(
    model: RadianceModel, dataset: SpikeDataset, start: int, length: int, pixels: torch.Tensor, chunk: int
) -> torch.Tensor:
    """Rendered intensity (L, P, C) over steps ``start..start+L-1`` at ``pixels``, ``chunk`` rays a call."""
    poses = dataset.trajectory.poses[start : start + length]
    per_call = max(1, chunk // length)
    parts = []
    for i in range(0, len(pixels), per_call):
        px = pixels[i : i + per_call]
        zero = torch.zeros(len(px), model.channels)
        args = (dataset.intrinsics, px, zero, dataset.threshold, dataset.near, dataset.far)
        parts.append(render_spike_window(model, poses, *args).intensity.float().cpu())
    return torch.cat(parts, dim=1)


def _channels_last(x: np.ndarray | torch.Tensor) -> torch.Tensor:
    """A camera-layout stream (T, H, W) or (T, 3, H, W) as a tensor (T, H, W, C)."""
    return to_channels_last(torch.as_tensor(x))


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def piqe_score(image: torch.Tensor) -> float | None:
    """The PIQE score of a displayed image (C, H, W), C = 1 or 3; None under 16 px a side or where the image
    is not finite (a NaN in the render, which PSNR also reports as None)."""
    if min(image.shape[-2:]) < BLOCK or not bool(torch.isfinite(image).all()):
        return None
    return _finite(piqe(image[0] if image.shape[0] == 1 else to_channels_last(image, frame=True)).score)


def score_step(
    model: RadianceModel,
    config: TrainConfig,
    dataset: SpikeDataset,
    step: int,
    length: int,
    pixels: torch.Tensor,
    chunk: int,
    display: Callable[[Any, int], torch.Tensor],
    image: np.ndarray | None = None,
) -> dict[str, Any]:
    """The no-reference scores of one check step (see the module doc); ``display`` maps linear (H, W, C)
    to the displayed (C, H, W) (eval's convention). ``image``: the run's reconstruction of the step, (H, W)
    or (3, H, W) linear, when the caller made it already (:func:`step_reconstructions`); None: made here."""
    total, t = len(dataset.trajectory), config.targets
    half = t.window // 2
    start = window_start(step, length, total)
    reach = max(half, t.mask_n)  # the reconstruction window and the mask's steps
    lo, hi = max(0, min(step - reach, start)), min(total, max(step + reach + 1, start + length))
    lo, hi = max(0, min(lo, hi - t.window)), min(total, max(hi, lo + t.window))  # a whole window (learned)
    if image is None and t.recon in WINDOWLESS:  # TFI/TFSTP read out to the neighbouring spikes (and
        # TFSTP from frame 0), however far: the whole stream, as training
        lo, hi = 0, total
    raw = dataset.spikes(stream_mode(config.color), frames=slice(lo, hi))
    i = step - lo
    if image is None:
        image = reconstruct_stream(raw, t.recon, t.window, dataset.threshold, slice(i, i + 1))[0]
    recon = _channels_last(np.asarray(image)[None])[0]
    mask = torch.as_tensor(spike_masks(raw, n=t.mask_n, frames=slice(i, i + 1))[0])  # (H, W) or (3, H, W)
    # what the run was trained to match: one render at the step, or the mean over its TFP window's poses
    count = config.window_poses()
    poses = window_steps(total, t.window, count)[step] if count > 1 else [step]
    color = render_mean(
        model, dataset.trajectory.poses[poses], dataset.intrinsics, dataset.near, dataset.far, chunk
    )
    pred, target = display(color, model.channels), display(recon, model.channels)
    m = mask.expand_as(pred)
    side = min(pred.shape[-2:]) >= SSIMConfig().window
    row: dict[str, Any] = {
        "step": int(dataset.trajectory.steps[step]),
        "mask_fraction": float(m.double().mean()),
    }
    row["masked_psnr"] = _finite(float(psnr(pred, target, mask=m)))
    row["masked_ssim"] = _finite(float(ssim(pred, target, mask=m))) if side else None
    row["piqe_render"], row["piqe_recon"] = piqe_score(pred), piqe_score(target)
    recorded = _channels_last(raw[start - lo : start - lo + length])[:, pixels[:, 1], pixels[:, 0]].float()
    rendered = _render_window(model, dataset, start, length, pixels, chunk)
    held = recon[pixels[:, 1], pixels[:, 0]].float().expand(length, -1, -1)
    for prefix, intensity in (("", rendered), ("recon_", held)):  # None where no window's bounds apply
        rate, mean = violation_stats(intensity, recorded, dataset.threshold)
        row[f"{prefix}interval_violation_rate"], row[f"{prefix}interval_violation_mean"] = (
            _finite(rate),
            _finite(mean),
        )
    return row


def step_reconstructions(
    config: TrainConfig, dataset: SpikeDataset, steps: np.ndarray, reach: int | None = None
) -> list[np.ndarray] | None:
    """The run's TFI or TFSTP reconstruction of each check step (``steps`` (N,)), each (H, W) or (3, H, W),
    made in one call (TFSTP: one scan from frame 0 for all the steps, not one each); None for TFP and
    learned, whose reconstruction of a step reads only its window (:func:`score_step` makes it).
    ``reach`` e (a run held out with its reconstruction cut, ``holdout.json``'s ``check_reach``): that of
    step c from steps c−e..c+e alone, as a stream of its own, so it reads no step that training read."""
    t = config.targets
    if t.recon not in WINDOWLESS:
        return None
    mode, total = stream_mode(config.color), len(dataset.trajectory)
    if reach is not None:
        out = []
        for c in (int(s) for s in steps):
            lo, hi = max(0, c - reach), min(total, c + reach + 1)
            raw = np.asarray(dataset.spikes(mode, frames=slice(lo, hi)))
            out.append(
                reconstruct_stream(raw, t.recon, t.window, dataset.threshold, slice(c - lo, c - lo + 1))[0]
            )
        return out
    frames = np.unique(steps)
    images = frames_reconstructor(t.recon, t.window, dataset.threshold)(
        lambda a, b: np.asarray(dataset.spikes(mode, frames=slice(a, b))), total, frames
    )
    return [images[j] for j in np.searchsorted(frames, steps)]


def noref_metrics(
    model: RadianceModel,
    config: TrainConfig,
    dataset: SpikeDataset,
    options: NoRefOptions,
    chunk: int,
    display: Callable[[Any, int], torch.Tensor],
    progress: Callable[[Any], Any] = iter,
    held: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``no_reference`` section of metrics.json: settings, ``mean`` and ``per_step`` scores. ``held``:
    the run's hold-out record (``data.holdout.read_record``); its check steps are scored, else those of
    :func:`check_steps`."""
    options.check()
    total = len(dataset.trajectory)
    length = min(options.spike_window or config.spike.window, total)
    if held is None:
        steps, source = check_steps(dataset, options.steps)
    else:
        steps, source = np.asarray(held["check_steps"], dtype=np.int64), str(held.get("source", ""))
        if len(steps) == 0 or steps.min() < 0 or steps.max() >= total:
            raise InputError(f"the run's held-out steps lie outside the {total}-step stream", dataset.root)
    k = dataset.intrinsics
    small = min(k.height, k.width) < BLOCK
    rows, pixels = [], torch.zeros(0, 2)
    cut = held is not None and held.get("recon_cut") is True and config.targets.recon in WINDOWLESS
    reach = held["check_reach"] if cut else None  # (no recon_cut: a record from before the cut, the whole
    # stream; read_record refuses a cut record without check_reach)
    images = step_reconstructions(config, dataset, steps, reach) or [None] * len(steps)
    with torch.no_grad():
        for i, step in enumerate(progress(steps)):
            pixels = _sample_pixels(k.height, k.width, options.spike_pixels, options.seed + i)
            row = score_step(model, config, dataset, int(step), length, pixels, chunk, display, images[i])
            rows.append(row)
    mean = {key: mean_or_none([r[key] for r in rows]) for key in rows[0] if key != "step"}
    t = config.targets
    radius = None if held is None else held.get("radius")
    return {
        "steps_from": source,
        "steps_trained_on": held is None,
        "guard_radius": radius,
        "windows_in_guard": None if held is None else windows_in_guard(steps, length, total, radius),
        "target": f"{t.recon} (window {t.window})" if reach is None else f"{t.recon} (steps k±{reach} alone)",
        "mask": f"a spike in steps k-{t.mask_n}..k+{t.mask_n}",
        "spike_window": length,
        "spike_pixels": len(pixels),
        "mean": mean,
        "per_step": rows,
        "image_score": image_score_info(),
        "image_score_reason": SMALL_IMAGE_REASON if small else None,
    }

"""The report's matplotlib figures, each returned as PNG bytes (Agg canvas, no pyplot global state), and the
data behind the less obvious ones (raster pixels, novel-view spike streams).

Images handed in are *display* values in [0, 1] (sRGB-encoded): (H, W) gray or (H, W, 3) colour.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from spikenerf.camera.reconstruct import DEFAULT_WINDOW, fitting_window
from spikenerf.core.color import rgb_to_gray, srgb_encode
from spikenerf.core.psnr import mse_to_psnr

#: error maps share this colour scale: |pred − GT| of display values, 0 … ERROR_VMAX
ERROR_VMAX = 0.3
ERROR_CMAP = "inferno"
DPI = 100
#: method labels above the views are wrapped at this many characters (a panel is 1.9 in wide)
LABEL_WIDTH = 24
#: TFP window (frames) and the length of the static-pose novel-view spike streams (steps)
TFP_WINDOW, NOVEL_STEPS = DEFAULT_WINDOW, 101


def _png(fig: Figure) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight", pad_inches=0.05)
    return buf.getvalue()


def _show(ax, image: np.ndarray | None, title: str, **kwargs) -> object | None:
    """One image panel (nearest-neighbour, no axes); a missing image shows a centred dash."""
    ax.set_title(title, fontsize=8)
    ax.set_xticks([])
    ax.set_yticks([])
    if image is None:
        ax.text(0.5, 0.5, "–\n(missing)", ha="center", va="center", fontsize=10, transform=ax.transAxes)
        return None
    if image.ndim == 2 and "cmap" not in kwargs:
        kwargs = {"cmap": "gray", "vmin": 0.0, "vmax": 1.0, **kwargs}
    return ax.imshow(
        np.clip(image, 0.0, 1.0) if image.ndim == 3 else image, interpolation="nearest", **kwargs
    )


def error_map(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """|pred − GT| (H, W) of display images (H, W) or (H, W, 3), averaged over channels."""
    err = np.abs(np.asarray(pred, np.float64) - np.asarray(gt, np.float64))
    return err.mean(-1) if err.ndim == 3 else err


def crop_box(gt: np.ndarray, background: float = 1.0, pad: int = 2, tol: float = 0.02) -> tuple[slice, slice]:
    """Rows and columns around the pixels that differ from the white background (the whole image if none)."""
    diff = np.abs(np.asarray(gt, np.float64) - background)
    mask = (diff.max(-1) if diff.ndim == 3 else diff) > tol
    h, w = mask.shape
    if not mask.any():
        return slice(0, h), slice(0, w)
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    return (
        slice(max(rows[0] - pad, 0), min(rows[-1] + pad + 1, h)),
        slice(max(cols[0] - pad, 0), min(cols[-1] + pad + 1, w)),
    )


def views_figure(gt: np.ndarray, preds: Mapping[str, np.ndarray | None], title: str) -> bytes:
    """Top row: GT then each method's render; bottom row: each method's error map (shared scale).

    Args:
        gt: (H, W) or (H, W, 3) display values. preds: method label -> same-shaped image or None (missing).
    """
    rs, cs = crop_box(gt)
    n = len(preds) + 1
    fig = Figure(figsize=(1.9 * n, 4.1))
    axes = fig.subplots(2, n, squeeze=False)
    _show(axes[0, 0], gt[rs, cs], "ground truth")
    axes[1, 0].axis("off")
    mappable, lines = None, 2
    for j, (label, pred) in enumerate(preds.items(), start=1):
        parts = (textwrap.fill(line, LABEL_WIDTH, break_on_hyphens=False) for line in label.split("\n"))
        wrapped = "\n".join(parts)
        lines = max(lines, wrapped.count("\n") + 1)
        _show(axes[0, j], None if pred is None else pred[rs, cs], wrapped)
        err = None if pred is None else error_map(pred, gt)[rs, cs]
        title_err = "|pred − GT|" if err is None else f"|pred − GT|\nmean {err.mean():.3f}"
        m = _show(axes[1, j], err, title_err, cmap=ERROR_CMAP, vmin=0.0, vmax=ERROR_VMAX)
        mappable = m or mappable
    if mappable is not None:
        cb = fig.colorbar(mappable, ax=list(axes[1, 1:]), fraction=0.02, pad=0.01)
        cb.ax.tick_params(labelsize=7)
    fig.suptitle(title, fontsize=9, y=0.98 + 0.035 * (lines - 2))  # above labels of more than two lines
    return _png(fig)


def raster_figure(spikes: np.ndarray, labels: Sequence[str], title: str) -> bytes:
    """Spike raster: one row per pixel, a tick at every step it fired.

    Args:
        spikes: (T, N) 0/1 spikes of N pixels over T steps. labels: N row labels.
    """
    t, n = spikes.shape
    fig = Figure(figsize=(7.5, 0.35 * n + 1.0))
    ax = fig.subplots()
    events = [np.flatnonzero(spikes[:, i]) for i in range(n)]
    ax.eventplot(events, lineoffsets=np.arange(n), linelengths=0.8, linewidths=0.8, colors="black")
    ax.set_yticks(np.arange(n), labels, fontsize=7)
    ax.set_ylim(-0.6, n - 0.4)
    ax.set_xlim(-0.5, t - 0.5)
    ax.invert_yaxis()
    ax.set_xlabel("spike step k (25 µs at 40 kHz)", fontsize=8)
    ax.tick_params(axis="x", labelsize=7)
    ax.set_title(title, fontsize=9)
    return _png(fig)


def panels_figure(
    panels: Sequence[tuple[str, np.ndarray | None]],
    title: str,
    points: np.ndarray | None = None,
    cmaps: Mapping[int, tuple[str, float]] | None = None,
) -> bytes:
    """A row of image panels (GT / TFP / mask, or GT-simulated vs predicted spikes).

    Args:
        panels: (title, image or None) each; images are display values or masks.
        points: optional (N, 2) pixel ``(x, y)`` marked on every panel (the raster's pixels).
        cmaps: panel index -> (colour map, vmax) for non-display panels such as error maps.
    """
    fig = Figure(figsize=(2.3 * len(panels), 2.6))
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for i, (name, image) in enumerate(panels):
        kwargs = {}
        if cmaps and i in cmaps:
            kwargs = {"cmap": cmaps[i][0], "vmin": 0.0, "vmax": cmaps[i][1]}
        m = _show(axes[i], image, name, **kwargs)
        if m is not None and kwargs:
            fig.colorbar(m, ax=axes[i], fraction=0.046, pad=0.02).ax.tick_params(labelsize=6)
        if points is not None and image is not None:
            axes[i].scatter(points[:, 0], points[:, 1], s=14, facecolors="none", edgecolors="cyan", lw=0.8)
    fig.suptitle(title, fontsize=9)
    return _png(fig)


def curves_figure(curves: Mapping[str, Sequence[Mapping[str, float]]], title: str) -> bytes:
    """Test PSNR (dB) against training time (s), one line per method.

    Args:
        curves: method label -> rows of ``curves.csv`` (``seconds``, ``test_psnr``); empty rows are skipped.
    """
    fig = Figure(figsize=(6.0, 3.2))
    ax = fig.subplots()
    for label, rows in curves.items():
        pts = [(r["seconds"], r["test_psnr"]) for r in rows if np.isfinite(r.get("test_psnr", np.nan))]
        if pts:
            x, y = zip(*pts, strict=True)
            ax.plot(x, y, marker="o", ms=3, lw=1.2, label=label)
    ax.set_xlabel("training time (s, evaluation excluded)", fontsize=8)
    ax.set_ylabel("test PSNR (dB)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    if ax.lines:
        ax.legend(fontsize=7, loc="lower right")
    ax.set_title(title, fontsize=9)
    return _png(fig)


# ------------------------------------------------------------------------------------------------- data
def raster_pixels(rates: np.ndarray, count: int) -> np.ndarray:
    """Flat indices of up to ``count`` distinct pixels whose spike rates spread evenly from min to max.

    Args:
        rates: (H·W,) spikes per step of each pixel.
    Returns:
        (N,) int64 indices, N ≤ count, in increasing rate.
    """
    order = np.argsort(rates, kind="stable")
    sorted_rates = rates[order]
    targets = np.linspace(rates.min(), rates.max(), count)
    hi = np.clip(np.searchsorted(sorted_rates, targets), 1, len(order) - 1)
    lo = hi - 1
    nearest = np.where(targets - sorted_rates[lo] <= sorted_rates[hi] - targets, lo, hi)
    picks = np.unique(order[nearest] if len(order) > 1 else order)
    return picks[np.argsort(rates[picks], kind="stable")]


@dataclass
class NovelSpikes:
    """TFP images (display values) of a predicted and a GT-simulated static-pose stream, with their rates."""

    method: str
    steps: int
    step: int
    window: int
    gt_tfp: np.ndarray
    pred_tfp: np.ndarray
    gt_rate: float
    pred_rate: float
    psnr: float


def novel_spikes(
    run: Path,
    view: int = 0,
    steps: int = NOVEL_STEPS,
    seed: int = 0,
    device: str = "cpu",
    dataset_root: Path | None = None,
) -> NovelSpikes:
    """Spike streams of ``steps`` steps at the static pose of test view ``view``, and their TFP at the middle.

    Predicted: the run's model rendered at that pose (no perturbation, so one render stands for every step)
    fired by the spiking renderer's rule (:func:`spikenerf.render.spiking.fire_sequence`). Reference: the GT
    test image through the ideal camera simulator (:func:`spikenerf.camera.simulation.simulate`). Both start
    from a seeded uniform [0, φ) accumulator and use the dataset's threshold φ. ``dataset_root``: the run's
    dataset where it is now (None: the path the run recorded).
    """
    from spikenerf.camera.layout import to_camera_layout, to_channels_last
    from spikenerf.camera.model import CameraConfig
    from spikenerf.camera.simulation import simulate
    from spikenerf.data.reconstruction import frame_at
    from spikenerf.render.model import render_image
    from spikenerf.render.spiking import fire_sequence, random_start
    from spikenerf.train.run import load_run

    model, config, ds = load_run(run, dataset_root, device=device)
    k, phi = ds.intrinsics, ds.threshold
    pred = render_image(model, ds.test.poses[view], k, ds.near, ds.far).color.float().cpu()  # (H, W, C)
    start = random_start(tuple(pred.shape), phi, seed)
    fired, _ = fire_sequence(pred.expand(steps, *pred.shape), start, phi)
    pred_spikes = to_camera_layout(fired.numpy().astype(np.uint8))  # (T, H, W) | (T, 3, H, W)
    gt = ds.test.images[view]
    frame = rgb_to_gray(gt, channel_axis=-1) if pred.shape[-1] == 1 else to_camera_layout(gt, frame=True)
    color = "gray" if pred.shape[-1] == 1 else "rgb"
    gt_spikes = simulate(
        [frame] * steps, k.height, k.width, CameraConfig(threshold=phi, color=color, seed=seed)
    )
    window = fitting_window(steps, TFP_WINDOW)
    images = []
    for s in (gt_spikes, pred_spikes):
        rec = frame_at(s.astype(np.uint8), steps // 2, "tfp", window, phi)
        images.append(srgb_encode(rec if rec.ndim == 2 else to_channels_last(rec, frame=True)))
    mse = float(np.mean((images[0] - images[1]) ** 2))
    return NovelSpikes(
        config.method, steps, steps // 2, window, images[0], images[1], float(gt_spikes.mean()),
        float(pred_spikes.mean()), mse_to_psnr(mse),
    )  # fmt: skip

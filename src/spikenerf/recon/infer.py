"""Learned reconstruction of spike streams of any size: per frame, per channel or Bayer plane, in tiles.

Memory is bounded by the tile: a frame's window stays uint8 and each tile (plus a margin that covers most of
the network's receptive field) is converted and run on its own; tile origins are multiples of 4 so the
U-Net's down-sampling grid matches the untiled one. Frames within K/2 of the stream's ends use a window
mirrored in time (step −j reads step j).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from spikenerf.core.errors import InputError
from spikenerf.recon.net import ReconNet

#: tile side (pixels) and margin on each side; a 250 × 400 frame runs as one tile
TILE = 512
MARGIN = 32


def frame_scale(window: np.ndarray | torch.Tensor) -> float:
    """The brightness scale of a whole frame's window (K, H, W): its mean rate (see ``brightness_scale``)."""
    from spikenerf.recon.features import MIN_SCALE

    w = torch.as_tensor(np.asarray(window) if not isinstance(window, torch.Tensor) else window)
    total = sum(float(w[i].float().sum()) for i in range(w.shape[0]))  # frame by frame: no float copy
    return max(total / max(w.numel(), 1), MIN_SCALE)


@torch.no_grad()
def predict_plane(net: ReconNet, window: np.ndarray | torch.Tensor, tile: int = TILE) -> np.ndarray:
    """Rate (intensity / φ) of the middle step of one single-channel window.

    Args:
        window: (K, H, W) 0/1 spikes, K = the network's window. tile: tile side (multiple of 4, ≥ 16).
    Returns:
        float32 (H, W).
    """
    if tile < 16 or tile % 4:
        raise InputError(f"tile must be a multiple of 4 and ≥ 16, found {tile}")
    w = torch.as_tensor(np.asarray(window) if not isinstance(window, torch.Tensor) else window)
    _k, h, wd = w.shape
    scale = torch.tensor([frame_scale(w)], dtype=torch.float32)
    device = next(net.parameters()).device
    out = np.empty((h, wd), np.float32)
    for y in range(0, h, tile):
        for x in range(0, wd, tile):
            y0, x0 = max(0, y - MARGIN), max(0, x - MARGIN)
            y1, x1 = min(h, y + tile + MARGIN), min(wd, x + tile + MARGIN)
            piece = w[:, y0:y1, x0:x1].to(device=device, dtype=torch.float32)[None]
            pred = net(piece, scale.to(device))[0].cpu().numpy()
            ty, tx = min(tile, h - y), min(tile, wd - x)
            out[y : y + ty, x : x + tx] = pred[y - y0 : y - y0 + ty, x - x0 : x - x0 + tx]
    return out


def check_window(net: ReconNet, window: int | None) -> None:
    """InputError unless ``window`` is None or the network's trained window K."""
    if window is not None and window != net.config.window:
        raise InputError(
            f"window: the learned reconstructor runs at its trained window of {net.config.window} steps, "
            f"found {window}",
            param="window",
        )


def mirrored(k: int, half: int, total: int) -> np.ndarray:
    """Step indices ``k-half .. k+half`` reflected into ``[0, total)`` (−j → j, T−1+j → T−1−j)."""
    idx = np.arange(k - half, k + half + 1)
    idx = np.where(idx < 0, -idx, idx)
    return np.where(idx >= total, 2 * (total - 1) - idx, idx)


def predict_frame(net: ReconNet, window: np.ndarray, mode: str, tile: int = TILE) -> np.ndarray:
    """One frame from its window: gray (K, H, W) → (H, W); rgb (K, 3, H, W) → (3, H, W), channel by channel
    (or one channel's stream (K, H, W) → (H, W)); bayer (K, H, W) RGGB mosaic → (H, W), each of the four CFA
    planes on its own. Rates (intensity / φ)."""
    if mode == "rgb" and window.ndim != 3:
        if window.ndim != 4 or window.shape[1] != 3:
            raise InputError(f"an rgb stream must be (T, 3, H, W), found a window of shape {window.shape}")
        return np.stack([predict_plane(net, window[:, c], tile) for c in range(3)])
    if window.ndim != 3:
        raise InputError(f"a {mode} stream must be (T, H, W), found a window of shape {window.shape}")
    if mode in ("gray", "rgb"):
        return predict_plane(net, window, tile)
    out = np.empty(window.shape[1:], np.float32)
    for i in (0, 1):
        for j in (0, 1):
            if window.shape[1] > i and window.shape[2] > j:
                out[i::2, j::2] = predict_plane(net, np.ascontiguousarray(window[:, i::2, j::2]), tile)
    return out


def learned_frames(
    net: ReconNet,
    read: Callable[[int, int], np.ndarray],
    total: int,
    start: int,
    stop: int,
    mode: str = "gray",
    threshold: float = 1.0,
    tile: int = TILE,
    progress: Callable[[int], None] | None = None,
) -> np.ndarray:
    """Learned reconstruction of frames ``start:stop`` of a long stream, reading only the frames needed.

    Args:
        read: ``read(a, b)`` returns frames ``a:b``, (b-a, H, W) or (b-a, 3, H, W) 0/1. total: T.
        mode: gray | rgb | bayer. threshold: φ (intensity = rate · φ).
        progress: called with 1 after each frame.
    Returns:
        float32 (stop-start, H, W) or (stop-start, 3, H, W) linear intensity.
    Raises:
        InputError: the window is longer than the stream.
    """
    k = net.config.window
    if total < k:
        raise InputError(
            f"the learned reconstructor's window of {k} steps is longer than the stream ({total} steps)"
        )
    half = k // 2
    lo, hi = max(0, start - half), min(total, stop + half)
    sub = read(lo, hi)
    frames = []
    for f in range(start, stop):
        frames.append(
            predict_frame(net, sub[mirrored(f, half, total) - lo], mode, tile) * np.float32(threshold)
        )
        if progress is not None:
            progress(1)
    return np.stack(frames).astype(np.float32)


def reconstruct_learned(
    spikes: np.ndarray,
    mode: str = "gray",
    threshold: float = 1.0,
    weights=None,
    frames: slice | None = None,
    window: int | None = None,
) -> np.ndarray:
    """Learned reconstruction of an in-memory stream (the counterpart of ``tfp``/``tfi``).

    Args:
        spikes: (T, H, W) gray/bayer or (T, 3, H, W) rgb 0/1. mode: gray | rgb | bayer. threshold: φ.
        weights: a weights file (None = the shipped one). frames: output frames (None = all).
        window: if given, must equal the weights' window K (the network only runs at its trained window).
    Returns:
        float32 (N, ...) linear intensity.
    """
    from spikenerf.recon.net import load_weights

    net, _ = load_weights(weights, mode)
    check_window(net, window)
    x = np.asarray(spikes)
    sel = range(x.shape[0])[frames if frames is not None else slice(None)]
    if len(sel) == 0:
        raise InputError(f"frames: the selection {frames} of {x.shape[0]} frames is empty")
    lo, hi = min(sel), max(sel) + 1  # the span, then the selected frames (any step, also negative)
    out = learned_frames(net, lambda a, b: x[a:b], x.shape[0], lo, hi, mode, threshold)
    return out if sel.step == 1 else out[[i - lo for i in sel]]


def learned_reconstructor(
    weights=None, mode: str = "gray", window: int | None = None, threshold: float = 1.0
) -> Callable[[Callable[[int, int], np.ndarray], int, int, int], np.ndarray]:
    """Check the weights now; return ``recon(read, total, start, stop)``, see :func:`learned_frames`."""
    from spikenerf.recon.net import load_weights

    net, _ = load_weights(weights, mode)
    check_window(net, window)
    return lambda read, total, start, stop: learned_frames(net, read, total, start, stop, mode, threshold)

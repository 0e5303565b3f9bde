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

from spikenerf.camera.frame_range import resolve_frames
from spikenerf.camera.modes import COLORS
from spikenerf.camera.streams import check_threshold, flat_stream, spike_bytes
from spikenerf.core.errors import InputError, check_choice
from spikenerf.recon.features import RunningFeatures
from spikenerf.recon.net import ReconNet

#: tile side (pixels) and margin on each side; a 250 × 400 frame runs as one tile
TILE = 512
MARGIN = 32
#: frames per network call on CUDA (16 frames of 400 × 400: about 1 GiB of activations by estimate, not
#: measured)
CUDA_BATCH = 16


def frame_scale(window: np.ndarray | torch.Tensor) -> float:
    """The brightness scale of a whole frame's window (K, H, W): its mean rate (see ``brightness_scale``)."""
    from spikenerf.recon.features import MIN_SCALE

    w = torch.as_tensor(np.asarray(window) if not isinstance(window, torch.Tensor) else window)
    total = sum(float(w[i].float().sum()) for i in range(w.shape[0]))  # frame by frame: no float copy
    return max(total / max(w.numel(), 1), MIN_SCALE)


def tiled(
    run: Callable[[int, int, int, int], torch.Tensor], h: int, w: int, tile: int = TILE,
    lead: tuple[int, ...] = (),
) -> np.ndarray:  # fmt: skip
    """Assemble an (..., H, W) float32 image from ``run(y0, y1, x0, x1)`` → (..., y1-y0, x1-x0) tiles with
    margins; ``lead``: the leading dimensions ``...`` (e.g. (B,) for a batch of frames; () for one)."""
    if tile < 16 or tile % 4:
        raise InputError(f"tile must be a multiple of 4 and ≥ 16, found {tile}")
    out = np.empty((*lead, h, w), np.float32)
    for y in range(0, h, tile):
        for x in range(0, w, tile):
            y0, x0 = max(0, y - MARGIN), max(0, x - MARGIN)
            pred = run(y0, min(h, y + tile + MARGIN), x0, min(w, x + tile + MARGIN)).cpu().numpy()
            ty, tx = min(tile, h - y), min(tile, w - x)
            out[..., y : y + ty, x : x + tx] = pred[..., y - y0 : y - y0 + ty, x - x0 : x - x0 + tx]
    return out


@torch.no_grad()
def predict_plane(net: ReconNet, window: np.ndarray | torch.Tensor, tile: int = TILE) -> np.ndarray:
    """Rate (intensity / φ) of the middle step of one single-channel window (the reference path: features of
    the whole window per tile; :func:`learned_frames` computes the same for consecutive frames, faster).

    Args:
        window: (K, H, W) 0/1 spikes, K = the network's window. tile: tile side (multiple of 4, ≥ 16).
    Returns:
        float32 (H, W).
    """
    w = torch.as_tensor(np.asarray(window) if not isinstance(window, torch.Tensor) else window)
    scale = torch.tensor([frame_scale(w)], dtype=torch.float32)
    device = next(net.parameters()).device

    def run(y0: int, y1: int, x0: int, x1: int) -> torch.Tensor:
        return net(w[:, y0:y1, x0:x1].to(device=device, dtype=torch.float32)[None], scale.to(device))[0]

    return tiled(run, w.shape[1], w.shape[2], tile)


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


def plane_views(shape: tuple[int, ...], mode: str) -> list[tuple[slice | int, ...]]:
    """Where each single-channel plane of a frame of ``shape`` (the stream's ``shape[1:]``) lies in it.

    gray → the frame; rgb (3, H, W) → each channel (an (H, W) frame: one channel's stream); bayer (H, W) RGGB
    mosaic → each of the four CFA planes. An index into a frame, e.g. ``out[view] = plane``.
    """
    if mode == "rgb" and len(shape) != 2:
        if len(shape) != 3 or shape[0] != 3:
            raise InputError(f"an rgb stream must be (T, 3, H, W), found frames of shape {tuple(shape)}")
        return [(c,) for c in range(3)]
    if len(shape) != 2:
        raise InputError(f"a {mode} stream must be (T, H, W), found frames of shape {tuple(shape)}")
    if mode in ("gray", "rgb"):
        return [()]
    cfa = [(i, j) for i in (0, 1) for j in (0, 1) if shape[0] > i and shape[1] > j]
    return [(slice(i, None, 2), slice(j, None, 2)) for i, j in cfa]


def predict_frame(net: ReconNet, window: np.ndarray, mode: str, tile: int = TILE) -> np.ndarray:
    """One frame from its window with :func:`predict_plane` per plane (see :func:`plane_views`): gray
    (K, H, W) → (H, W); rgb (K, 3, H, W) → (3, H, W); bayer (K, H, W) → (H, W). Rates (intensity / φ)."""
    out = np.empty(window.shape[1:], np.float32)
    for view in plane_views(window.shape[1:], mode):
        out[view] = predict_plane(net, np.ascontiguousarray(window[(slice(None), *view)]), tile)
    return out


def fast_layout(net: ReconNet) -> ReconNet:
    """Convert ``net`` in place for fast CPU inference: channels-last weights, in-place activations (the same
    values; still trainable)."""
    for m in net.modules():
        if isinstance(m, torch.nn.LeakyReLU):
            m.inplace = True
    return net.to(memory_format=torch.channels_last)


def spike_tensor(frames: np.ndarray) -> torch.Tensor:
    """(T, ...) spikes as a 0/1 uint8 tensor (:func:`~spikenerf.camera.streams.spike_bytes`: any
    non-zero integer is a spike, a float other than 0.0/1.0 an InputError), sharing memory where the array
    is writable bool."""
    a = spike_bytes(np.asarray(frames))
    return torch.from_numpy(a if a.flags.writeable else a.copy())


@torch.inference_mode()
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
    device: torch.device | str | None = None,
    batch: int = 1,
) -> np.ndarray:
    """Learned reconstruction of frames ``start:stop`` of a long stream, reading only the frames needed.

    Equals :func:`predict_frame` of each frame's (mirrored) window to float rounding, but computes the
    features of consecutive frames with running counts (:class:`~spikenerf.recon.features.RunningFeatures`)
    and runs the network in channels-last layout (``net`` is converted in place, see :func:`fast_layout`).

    Args:
        read: ``read(a, b)`` returns frames ``a:b``, (b-a, H, W) or (b-a, 3, H, W) 0/1. total: T.
        mode: gray | rgb | bayer. threshold: φ (intensity = rate · φ).
        progress: called with the number of frames done after each batch of frames.
        device: where the features and the network run (None: the network's device; ``net`` is moved
            there in place); the stream's frames are copied there once.
        batch: frames per network call (each of them tiled; 1 = frame by frame).
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
    if batch < 1:
        raise InputError(f"batch must be ≥ 1, found {batch}", param="batch")
    half = k // 2
    lo, hi = max(0, start - half), min(total, stop + half)
    device = next(net.parameters()).device if device is None else torch.device(device)
    sub = spike_tensor(read(lo, hi))
    if device.type != "cpu":
        sub = sub.to(device)
    views = plane_views(tuple(sub.shape[1:]), mode)
    runs = [RunningFeatures(sub[(slice(None), *view)], k) for view in views]
    fast_layout(net.to(device))
    out = np.empty((stop - start, *sub.shape[1:]), np.float32)
    for a in range(start, stop, batch):
        frames = range(a, min(stop, a + batch))
        rows = slice(a - start, a - start + len(frames))
        for view, run in zip(views, runs, strict=True):
            made = [run(mirrored(f, half, total) - lo) for f in frames]  # in order: running counts
            feats, scale = torch.cat([m[0] for m in made]), torch.cat([m[1] for m in made])

            def piece(y0: int, y1: int, x0: int, x1: int, feats=feats, scale=scale) -> torch.Tensor:
                x = feats[:, :, y0:y1, x0:x1].to(device).contiguous(memory_format=torch.channels_last)
                return net.decode(x, scale.to(device))

            out[(rows, *view)] = tiled(piece, feats.shape[2], feats.shape[3], tile, (len(frames),))
        out[rows] *= np.float32(threshold)
        if progress is not None:
            progress(len(frames))
    return out


def reconstruct_learned(
    spikes: np.ndarray,
    mode: str = "gray",
    threshold: float = 1.0,
    weights=None,
    frames: slice | None = None,
    window: int | None = None,
    device: torch.device | str | None = None,
    batch: int | None = None,
) -> np.ndarray:
    """Learned reconstruction of an in-memory stream (the counterpart of ``tfp``/``tfi``).

    Args:
        spikes: (T, H, W) gray/bayer or (T, 3, H, W) rgb 0/1. mode: gray | rgb | bayer. threshold: φ.
        weights: a weights file (None = the shipped one). frames: output frames (None = all).
        window: if given, must equal the weights' window K (the network only runs at its trained window).
        device: where the network runs (None: the CPU). batch: frames per network call (None: 1 on a
            CPU, :data:`CUDA_BATCH` on CUDA).
    Returns:
        float32 (N, ...) linear intensity.
    """
    from spikenerf.recon.net import load_weights

    check_threshold(threshold)
    check_choice(mode, COLORS, "mode")  # before the weights: a wrong mode is the caller's, not the file's
    x = np.asarray(spikes)
    flat_stream(x, None)  # (T, H, W) or (T, 3, H, W), as for tfp and tfi
    if (x.ndim == 4) != (mode == "rgb"):
        want = "(T, 3, H, W)" if mode == "rgb" else "(T, H, W)"
        raise InputError(
            f"spikes of mode {mode!r} must be {want}, found shape {x.shape}", param=("spikes", "mode")
        )
    net, _ = load_weights(weights, mode)
    check_window(net, window)
    if isinstance(frames, (int, np.integer)) and not isinstance(frames, bool):
        sel = resolve_frames(frames, x.shape[0])  # one frame, as tfp and tfi take it
    else:
        sel = range(x.shape[0])[frames if frames is not None else slice(None)]
    if len(sel) == 0:
        raise InputError(f"frames: the selection {frames} of {x.shape[0]} frames is empty")
    lo, hi = min(sel), max(sel) + 1  # the span, then the selected frames (any step, also negative)
    device = torch.device("cpu") if device is None else torch.device(device)
    batch = (CUDA_BATCH if device.type == "cuda" else 1) if batch is None else batch
    out = learned_frames(net, lambda a, b: x[a:b], x.shape[0], lo, hi, mode, threshold, device=device,
                         batch=batch)  # fmt: skip
    return out if sel.step == 1 else out[[i - lo for i in sel]]


def learned_reconstructor(
    weights=None, mode: str = "gray", window: int | None = None, threshold: float = 1.0
) -> Callable[[Callable[[int, int], np.ndarray], int, int, int], np.ndarray]:
    """Check the weights now; return ``recon(read, total, start, stop)``, see :func:`learned_frames`.
    ``weights``: a weights file (None = shipped), or a :class:`~spikenerf.recon.net.ReconNet` the caller
    loaded already (``load_weights(path, mode)``, which checked its colour modes) and reuses."""
    from spikenerf.recon.net import load_weights

    check_threshold(threshold)
    net = weights if isinstance(weights, ReconNet) else load_weights(weights, mode)[0]
    check_window(net, window)
    return lambda read, total, start, stop: learned_frames(net, read, total, start, stop, mode, threshold)

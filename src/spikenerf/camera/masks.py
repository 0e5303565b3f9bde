"""Spike masks (Spike-NeRF): ``M_k`` marks the pixels that fired at least once in frames ``k-n..k+n``."""

from __future__ import annotations

from typing import TYPE_CHECKING, TypeVar

import numpy as np

from spikenerf.camera.reconstruct import iter_window_counts
from spikenerf.camera.streams import Frames, flat_stream, like
from spikenerf.core.errors import InputError, is_integer

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", np.ndarray, "torch.Tensor")


def spike_masks(spikes: Array, n: int = 5, frames: Frames = None) -> Array:
    """``M_k = s_{k-n} ∨ … ∨ s_{k+n}``: exactly 2n+1 frames, clipped to the stream at its edges.

    The paper's code ORs a 10-frame window instead (not centred); see docs/reconstruction.md.

    Args:
        spikes: (T, H, W) or (T, 3, H, W) 0/1 spikes (numpy or torch; bool, integer, or float 0.0/1.0); any
            other shape is an InputError (see :func:`~spikenerf.camera.streams.flat_stream`).
        n: the half window, ≥ 0 (n = 0 gives the single-frame masks).
        frames: the output frames (slice, index, None = all, or ascending indices (N,)).
    Returns:
        bool (N, ...), the same array type as ``spikes``.
    """
    if not is_integer(n) or n < 0:
        raise InputError(f"mask half window n must be an integer ≥ 0, found {n!r}", param="n")
    flat, rest, out_idx = flat_stream(spikes, frames)
    masks = np.empty((out_idx.size, flat.shape[1]), np.bool_)
    for j, counts, _ in iter_window_counts(flat, int(n), out_idx):
        np.greater(counts, 0, out=masks[j])
    return like(masks.reshape(out_idx.size, *rest), spikes)

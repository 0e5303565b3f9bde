"""Spike-rate summaries of a stream, computed chunk by chunk (a memory-mapped ``.dat`` never loads whole)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from spikenerf.camera.dat_codec import as_numpy
from spikenerf.camera.io import CHUNK_FRAMES, iter_dat
from spikenerf.core.color import is_tensor
from spikenerf.core.errors import InputError

if TYPE_CHECKING:
    import torch

#: per-pixel firing-rate percentiles reported by :func:`spike_rate_summary`
PERCENTILES = (1, 5, 50, 95, 99)


def spike_rate_summary(spikes: np.ndarray | torch.Tensor | Iterable[np.ndarray]) -> dict:
    """Firing statistics of a spike stream.

    Args:
        spikes: 0/1 spikes (T, H, W) or (T, 3, H, W), or an iterable of such chunks (streamed).
    Returns:
        ``frames`` (T), ``pixels`` (H·W, or 3·H·W), ``spikes`` (total count), ``mean_rate`` (spikes per pixel
        per step), ``rate_percentiles`` ({1, 5, 50, 95, 99} → per-pixel spikes per step) and
        ``silent_fraction`` (pixels that never fire) and ``saturated_fraction`` (pixels that fire at every
        step: light at or above the threshold φ a step, whose brightness the stream cannot tell apart).
    """
    chunks = [spikes] if isinstance(spikes, np.ndarray) or is_tensor(spikes) else spikes
    counts: np.ndarray | None = None
    frames = 0
    for chunk in chunks:
        arr = as_numpy(chunk)
        per_pixel = np.count_nonzero(arr, axis=0).astype(np.int64)
        if counts is None:
            counts = per_pixel
        elif per_pixel.shape != counts.shape:
            raise InputError(
                f"chunk frame shape {arr.shape[1:]} differs from the first chunk's {counts.shape}"
            )
        else:
            counts += per_pixel
        frames += arr.shape[0]
    if counts is None or frames == 0:
        raise InputError("the spike stream holds no frames; nothing to summarise")
    rates = counts.reshape(-1) / frames
    return {
        "frames": frames,
        "pixels": int(rates.size),
        "spikes": int(counts.sum()),
        "mean_rate": float(rates.mean()),
        "rate_percentiles": {
            q: float(v) for q, v in zip(PERCENTILES, np.percentile(rates, PERCENTILES), strict=True)
        },
        "silent_fraction": float(np.mean(counts == 0)),
        "saturated_fraction": float(np.mean(counts == frames)),
    }


def dat_rate_summary(
    path: str | Path,
    height: int,
    width: int,
    layout: str = "spikecv",
    raw_width: int | None = None,
    chunk_frames: int = CHUNK_FRAMES,
) -> dict:
    """:func:`spike_rate_summary` of a ``.dat`` file, streamed in chunks of ``chunk_frames`` frames."""
    return spike_rate_summary(
        chunk for _, chunk in iter_dat(path, height, width, chunk_frames, layout=layout, raw_width=raw_width)
    )

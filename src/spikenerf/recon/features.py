"""Input features of the learned reconstructor, computed from a spike window of K steps centred on a step.

All features are firing *rates* (spikes per step, so intensity / φ) divided by a per-image brightness scale
``s`` (the image mean of the full-window rate): the network sees brightness-normalised inputs and its output
is multiplied back by ``s`` (see :mod:`spikenerf.recon.net`). Channels, in order:

* nested TFP windows centred on the step, lengths :data:`NESTED` (clipped to K), then K itself;
* the TFI rate ``1 / Δ`` of the inter-spike interval containing the step, found inside the window
  (a missing spike before/after counts as one at the window edge, so a silent pixel gives ``1 / (K + 1)``);
* :data:`CHUNKS` consecutive sub-window rates covering the window in time order (motion cues);
* ``log s`` as a constant plane (the absolute light level sets the noise level).

:func:`spike_features` computes them from whole windows (training, single frames); :class:`RunningFeatures`
computes the same values for consecutive frames of a stream with running counts (inference).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import torch
from torch import Tensor

#: nested centred window lengths used as TFP features (those < K), before the full window itself
NESTED = (5, 11, 21)
#: number of consecutive sub-windows the window is split into
CHUNKS = 6
#: the smallest brightness scale (a nearly black frame is not blown up)
MIN_SCALE = 1e-2


def nested_lengths(window: int) -> list[int]:
    """The TFP window lengths of the nested channels: those of :data:`NESTED` below K, then K."""
    return [n for n in NESTED if n < window] + [window]


def rate_spans(window: int) -> list[tuple[int, int]]:
    """Window positions ``[a, b)`` of the rate channels: the nested centred windows, then the chunks."""
    c = window // 2
    bounds = [round(i * window / min(CHUNKS, window)) for i in range(min(CHUNKS, window) + 1)]
    return [(c - n // 2, c + n // 2 + 1) for n in nested_lengths(window)] + list(itertools.pairwise(bounds))


def feature_count(window: int) -> int:
    """Channels of :func:`spike_features` for a window of K steps."""
    return len(rate_spans(window)) + 2


def brightness_scale(window: Tensor) -> Tensor:
    """Per-image scale ``s``: the mean full-window firing rate, at least :data:`MIN_SCALE`.

    Args:
        window: (N, K, H, W) 0/1 spikes.
    Returns:
        (N,) float32.
    """
    return window.float().mean(dim=(1, 2, 3)).clamp_min(MIN_SCALE)


def stack_features(window: int, counts: list[Tensor], prev: Tensor, nxt: Tensor, scale: Tensor) -> Tensor:
    """The channels from the spike counts over :func:`rate_spans` and the interval around the middle step.

    Args:
        counts: (N, H, W) float spike counts, one per span. prev, nxt: (N, H, W) window positions of the last
            spike before the middle step (−1: none) and of the first at or after it (K: none).
        scale: (N,) brightness scales.
    Returns:
        float32 (N, C, H, W).
    """
    spans = rate_spans(window)
    rates = [cnt / (b - a) for cnt, (a, b) in zip(counts, spans, strict=True)]
    rates.insert(len(nested_lengths(window)), 1.0 / (nxt - prev).float())
    n, h, w = prev.shape
    s = scale.to(rates[0]).view(n, 1, 1)
    planes = [r / s for r in rates]
    planes.append(torch.log(s).expand(n, h, w) / math.log(10.0))
    return torch.stack(planes, dim=1)


def spike_features(window: Tensor, scale: Tensor) -> Tensor:
    """Brightness-normalised features of spike windows centred on their middle step.

    Args:
        window: (N, K, H, W) 0/1 spikes (any dtype), K odd; step ``K // 2`` is the reconstructed one.
        scale: (N,) brightness scales (see :func:`brightness_scale`; give the whole frame's when tiling).
    Returns:
        float32 (N, C, H, W), ``C = feature_count(K)``.
    """
    x = window.float()
    n, k, h, w = x.shape
    c = k // 2
    csum = torch.cat([x.new_zeros(n, 1, h, w), x.cumsum(dim=1)], dim=1)  # csum[j] = spikes in steps < j
    counts = [csum[:, b] - csum[:, a] for a, b in rate_spans(k)]
    steps = torch.arange(k, dtype=x.dtype, device=x.device).view(1, k, 1, 1)
    prev = (x[:, :c] * (steps[:, :c] + 1)).amax(dim=1) - 1 if c > 0 else x.new_full((n, h, w), -1.0)
    nxt = k - (x[:, c:] * (k - steps[:, c:])).amax(dim=1)
    return stack_features(k, counts, prev, nxt, scale)


class RunningFeatures:
    """:func:`spike_features` of consecutive windows of one stream, each rate channel a running count.

    ``feats(steps)`` takes the K step indices of a window (into ``frames``); when they are the previous
    window's shifted by one (the next frame, also with windows mirrored at the stream's ends), every count is
    updated with the step that enters and the one that leaves its span, otherwise recounted. The interval
    channel scans the window once in uint8. Counts are exact integers, so the features equal
    :func:`spike_features` of the same window. Nothing is read back to the host: on CUDA the frames of a
    stream queue up without a synchronisation each.
    """

    def __init__(self, frames: Tensor, window: int) -> None:
        """``frames``: (T, H, W) uint8 0/1 spikes (e.g. ``torch.from_numpy`` of a memory map), on any device
        (the counts and features are made there)."""
        self.frames, self.k = frames, window
        self.spans = rate_spans(window)
        self.steps: np.ndarray | None = None
        self.counts: list[Tensor] = []

    def _count(self, steps: np.ndarray) -> None:
        f = self.frames
        if self.steps is not None and np.array_equal(steps[:-1], self.steps[1:]):
            for cnt, (a, b) in zip(self.counts, self.spans, strict=True):
                cnt.add_(f[steps[b - 1]]).sub_(f[self.steps[a]])
        else:
            self.counts = []
            for a, b in self.spans:
                cnt = torch.zeros(f.shape[1:], dtype=torch.float32, device=f.device)
                for j in steps[a:b]:
                    cnt.add_(f[j])
                self.counts.append(cnt)
        self.steps = steps

    def __call__(self, steps: np.ndarray) -> tuple[Tensor, Tensor]:
        """Features and brightness scale of the window of ``steps`` (K indices into ``frames``).

        Returns:
            float32 (1, C, H, W) features and (1,) float32 scale (the whole window's, as in ``frame_scale``).
        """
        if len(steps) != self.k:
            raise ValueError(f"a window has {self.k} steps, found {len(steps)}")
        self._count(np.asarray(steps))
        k, c, f = self.k, self.k // 2, self.frames
        last = torch.zeros(f.shape[1:], dtype=torch.uint8, device=f.device)
        for j in range(c):  # 1 + position of the last spike before the middle step
            torch.maximum(last, f[steps[j]] * (j + 1), out=last)
        first = torch.zeros_like(last)
        for j in range(c, k):  # K − position of the first spike at or after it
            torch.maximum(first, f[steps[j]] * (k - j), out=first)
        total = self.counts[len(nested_lengths(k)) - 1].sum(dtype=torch.float64)  # stays on the device
        scale = (total / (k * last.numel())).clamp_min(MIN_SCALE).to(torch.float32).reshape(1)
        prev, nxt = last.to(torch.int32) - 1, k - first.to(torch.int32)
        return stack_features(k, [cnt[None] for cnt in self.counts], prev[None], nxt[None], scale), scale

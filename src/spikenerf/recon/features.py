"""Input features of the learned reconstructor, computed from a spike window of K steps centred on a step.

All features are firing *rates* (spikes per step, so intensity / φ) divided by a per-image brightness scale
``s`` (the image mean of the full-window rate): the network sees brightness-normalised inputs and its output
is multiplied back by ``s`` (see :mod:`spikenerf.recon.net`). Channels, in order:

* nested TFP windows centred on the step, lengths :data:`NESTED` (clipped to K), then K itself;
* the TFI rate ``1 / Δ`` of the inter-spike interval containing the step, found inside the window
  (a missing spike before/after counts as one at the window edge, so a silent pixel gives ``1 / (K + 1)``);
* :data:`CHUNKS` consecutive sub-window rates covering the window in time order (motion cues);
* ``log s`` as a constant plane (the absolute light level sets the noise level).
"""

from __future__ import annotations

import itertools
import math

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


def feature_count(window: int) -> int:
    """Channels of :func:`spike_features` for a window of K steps."""
    return len(nested_lengths(window)) + 1 + min(CHUNKS, window) + 1


def brightness_scale(window: Tensor) -> Tensor:
    """Per-image scale ``s``: the mean full-window firing rate, at least :data:`MIN_SCALE`.

    Args:
        window: (N, K, H, W) 0/1 spikes.
    Returns:
        (N,) float32.
    """
    return window.float().mean(dim=(1, 2, 3)).clamp_min(MIN_SCALE)


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
    feats = []
    for length in nested_lengths(k):
        half = length // 2
        feats.append((csum[:, c + half + 1] - csum[:, c - half]) / length)
    steps = torch.arange(k, dtype=x.dtype, device=x.device).view(1, k, 1, 1)
    prev = (x[:, :c] * (steps[:, :c] + 1)).amax(dim=1) - 1 if c > 0 else x.new_full((n, h, w), -1.0)
    nxt = k - (x[:, c:] * (k - steps[:, c:])).amax(dim=1)
    feats.append(1.0 / (nxt - prev))
    bounds = [round(i * k / min(CHUNKS, k)) for i in range(min(CHUNKS, k) + 1)]
    for a, b in itertools.pairwise(bounds):
        feats.append((csum[:, b] - csum[:, a]) / (b - a))
    s = scale.to(x).view(n, 1, 1)
    planes = [f / s for f in feats]
    planes.append(torch.log(s).expand(n, h, w) / math.log(10.0))
    return torch.stack(planes, dim=1)

"""Integrate-and-fire spike camera model (numpy or torch)."""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import torch

Array = TypeVar("Array", np.ndarray, torch.Tensor)


def fire(accumulator: Array, intensity: Array, threshold: float | Array = 1.0) -> tuple[Array, Array]:
    """One readout step of the ideal integrate-and-fire pixel.

    ``A ← A + I``; a spike fires where ``A ≥ φ`` and then ``φ`` is subtracted (the remainder is kept).
    At most one spike per pixel per step.

    Args:
        accumulator: (..., H, W) accumulated intensity before the step.
        intensity: (..., H, W) intensity integrated over the step (linear, 1.0 = white for one step).
        threshold: φ, a scalar or an array broadcastable to the accumulator.
    Returns:
        spikes: bool, same shape; accumulator: the new accumulator.
    """
    acc = accumulator + intensity
    spikes = acc >= threshold
    if isinstance(acc, torch.Tensor):
        acc = acc - spikes.to(acc.dtype) * threshold
    else:
        acc = acc - spikes.astype(acc.dtype) * threshold
    return spikes, acc

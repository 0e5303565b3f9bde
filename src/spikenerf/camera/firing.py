"""The integrate-and-fire rule of one spike camera pixel, numpy or torch: :func:`fire` (also run inside
training, by the spiking renderer and the losses) and :func:`fire_`, the same rule in place on the camera's
float32 buffers (:class:`~spikenerf.camera.model.SpikeCamera`)."""

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
        spikes: bool, same shape; accumulator: the new accumulator, in the dtype that ``accumulator +
        intensity`` promotes to (numpy's or torch's rules: a float32 accumulator with a float64 intensity
        array gives float64; pass both as float32 to stay in float32, as the camera does,
        :class:`~spikenerf.camera.model.SpikeCamera`). No input check: this is the rule itself, also run
        inside training (see :meth:`~spikenerf.camera.model.SpikeCamera.step`).
    """
    acc = accumulator + intensity
    spikes = acc >= threshold
    if isinstance(acc, torch.Tensor):
        acc = acc - spikes.to(acc.dtype) * threshold
    else:
        acc = acc - spikes.astype(acc.dtype) * threshold
    return spikes, acc


def fire_(
    accumulator: Array, intensity: Array, threshold: float | Array, spikes: Array, scratch: Array
) -> Array:
    """In-place :func:`fire` on float32 buffers: the same rule and bit-identical results, no allocation.

    No autograd: tensors must not require grad (the camera detaches its input).

    Args:
        accumulator: (..., H, W) float32, updated in place.
        intensity: broadcastable to the accumulator.
        threshold: φ as a float32-representable float, or a float32 array of the accumulator's shape.
        spikes: bool buffer of the accumulator's shape, overwritten with this step's spikes.
        scratch: float32 buffer of the accumulator's shape, overwritten.
    Returns:
        ``spikes``.
    """
    if isinstance(accumulator, torch.Tensor) and accumulator.device.type != "cpu":
        accumulator.add_(intensity)
        torch.ge(accumulator, threshold, out=spikes)
        accumulator.sub_(torch.mul(spikes, threshold, out=scratch))
    else:  # numpy, or CPU tensors through zero-copy numpy views (torch's CPU bool kernels are slower)
        accumulator, intensity, threshold, scratch, out = (
            x.numpy() if isinstance(x, torch.Tensor) else x
            for x in (accumulator, intensity, threshold, scratch, spikes)
        )
        if not isinstance(threshold, np.ndarray):
            threshold = np.float32(threshold)  # keeps the loops in float32
        np.add(accumulator, intensity, out=accumulator)
        np.greater_equal(accumulator, threshold, out=out)
        np.copyto(scratch, out)  # 1.0 / 0.0; much faster than a masked subtract (where=spikes)
        if isinstance(threshold, np.ndarray) or threshold != 1:
            np.multiply(scratch, threshold, out=scratch)
        np.subtract(accumulator, scratch, out=accumulator)
    return spikes

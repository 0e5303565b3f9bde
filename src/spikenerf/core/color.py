"""Colour conventions: linear radiance, luminance, and sRGB encoding for display (numpy or torch)."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from spikenerf.core.errors import InputError, is_integer, is_number, nonempty

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", np.ndarray, "torch.Tensor")


def is_tensor(x: Any) -> bool:
    """Whether ``x`` is a torch tensor, without importing torch (a tensor implies torch is loaded, and
    numpy-only callers stay fast to start)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


#: Rec. 601 luma weights applied to *linear* RGB, the design's gray convention.
GRAY_WEIGHTS = (0.299, 0.587, 0.114)


def rgb_to_gray(rgb: Array, channel_axis: int = 0) -> Array:
    """Linear RGB to linear gray, 0.299R + 0.587G + 0.114B.

    Args:
        rgb: (..., 3, ...) with the colour axis at ``channel_axis``.
    Returns:
        The same shape with the colour axis removed.
    Raises:
        InputError: ``rgb`` not an array or tensor, ``channel_axis`` not one of its axes, or the colour axis
            without 3 entries.
    """
    if not hasattr(rgb, "shape") or not hasattr(rgb, "ndim"):
        raise InputError(
            f"rgb must be a numpy array or torch tensor, found {type(rgb).__name__}", param="rgb"
        )
    if not is_integer(channel_axis) or not -rgb.ndim <= channel_axis < rgb.ndim:
        raise InputError(
            f"channel_axis must be an axis of rgb's shape {tuple(rgb.shape)}, found {channel_axis!r}",
            param="channel_axis",
        )
    if rgb.shape[channel_axis] != 3:
        raise InputError(
            f"rgb must have 3 colour channels on axis {channel_axis}, found shape {tuple(rgb.shape)}",
            param="rgb",
        )
    r, g, b = (
        rgb.select(channel_axis, i) if is_tensor(rgb) else np.take(rgb, i, channel_axis) for i in range(3)
    )
    return GRAY_WEIGHTS[0] * r + GRAY_WEIGHTS[1] * g + GRAY_WEIGHTS[2] * b


def srgb_encode(linear: Array) -> Array:
    """Linear [0, 1] to sRGB-encoded [0, 1] display values (IEC 61966-2-1); input is clipped to [0, 1]."""
    if is_tensor(linear):
        x = linear.clamp(0.0, 1.0)
        return sys.modules["torch"].where(
            x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(1e-12) ** (1 / 2.4) - 0.055
        )
    x = np.asarray(linear)
    if not (np.issubdtype(x.dtype, np.number) or x.dtype == bool):  # (a string, None: numpy's ufunc error)
        found = f"{type(linear).__name__} of {x.dtype}"
        raise InputError(f"linear must be numbers (an array or a tensor), found {found}", param="linear")
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 1e-12) ** (1 / 2.4) - 0.055)


def srgb_slope(linear: Array, floor: float = 1 / 255) -> Array:
    """The slope ``d srgb_encode / d linear`` at ``linear`` clamped to ``[floor, 1]`` (numpy or torch, no
    gradient of its own): how much a linear error of each value moves its display value. It falls from 12.92
    at ``linear ≤ 0.0031308`` to 0.44 at white; the floor keeps near-black values at a finite slope (11.1
    at 1/255, the default), the cap at 1 keeps values above white at white's.

    Args:
        linear: (...) linear values. floor: the least value the slope is taken at, in (0, 1].
    Returns:
        (...) the slopes, > 0, of ``linear``'s shape (and dtype, where floating).
    Raises:
        InputError: ``floor`` not a number in (0, 1].
    """
    if not (is_number(floor) and 0 < floor <= 1):
        raise InputError(f"floor must be a number in (0, 1], found {floor!r}", param="floor")
    if is_tensor(linear):
        torch_ = sys.modules["torch"]
        x = linear.detach().clamp(float(floor), 1.0)
        return torch_.where(x <= 0.0031308, torch_.full_like(x, 12.92), (1.055 / 2.4) * x ** (1 / 2.4 - 1))
    x = np.clip(linear, floor, 1.0)
    return np.where(x <= 0.0031308, 12.92, (1.055 / 2.4) * x ** (1 / 2.4 - 1))


def srgb_mse(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared difference () of the sRGB display values of two linear tensors of one shape (each clipped
    to [0, 1] by :func:`srgb_encode`), in float32 (float64 where either is): what every PSNR of a
    training step reports.

    Raises:
        InputError: ``target`` not of ``pred``'s shape (an (N, 1) against (N,) broadcast to (N, N)), or
            ``pred`` empty (the mean of nothing is NaN; a shape check, no host sync).
    """
    if tuple(target.shape) != tuple(pred.shape):
        raise InputError(
            f"target must have the shape of pred, {tuple(pred.shape)}, found {tuple(target.shape)}",
            param="target",
        )
    nonempty(pred, "pred")
    torch_ = sys.modules["torch"]  # float64 stays float64 (a gradcheck's); the rest is taken in float32
    wide = torch_.float64 if torch_.float64 in (pred.dtype, target.dtype) else torch_.float32
    return ((srgb_encode(pred.to(wide)) - srgb_encode(target.to(wide))) ** 2).mean()


def display_uint8(display: np.ndarray) -> np.ndarray:
    """Display values (any shape, e.g. sRGB-encoded) → uint8 0…255, clipped to [0, 1] and rounded."""
    return np.round(np.clip(display, 0.0, 1.0) * 255.0).astype(np.uint8)


def srgb_decode(encoded: Array) -> Array:
    """sRGB-encoded [0, 1] to linear [0, 1] (the inverse of :func:`srgb_encode`)."""
    if is_tensor(encoded):
        x = encoded.clamp(0.0, 1.0)
        return sys.modules["torch"].where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    x = np.clip(encoded, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)

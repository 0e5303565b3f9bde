"""PSNR, the one implementation: ``10·log10(range² / MSE)`` in dB (used by train, eval and pipelines)."""

from __future__ import annotations

import math
import numbers
from typing import TYPE_CHECKING, overload

import numpy as np

from spikenerf.core.errors import InputError, is_finite

if TYPE_CHECKING:
    from torch import Tensor


@overload
def mse_to_psnr(mse: float, data_range: float = 1.0) -> float: ...
@overload
def mse_to_psnr(mse: Tensor, data_range: float = 1.0) -> Tensor: ...
@overload
def mse_to_psnr(mse: np.ndarray, data_range: float = 1.0) -> np.ndarray: ...
def mse_to_psnr(mse: float | Tensor | np.ndarray, data_range: float = 1.0) -> float | Tensor | np.ndarray:
    """PSNR in dB of a mean squared error on values in [0, ``data_range``]; +inf for MSE 0.

    Args:
        mse: a real number (numpy scalars included), or a tensor or numpy array of any shape (elementwise,
            computed in float64). A negative or NaN MSE gives NaN either way.
        data_range: the largest value, a finite number > 0.
    Returns:
        a float for a number, else a float64 tensor (array) of the same shape.
    Raises:
        InputError: ``data_range`` not a finite number > 0 (a negative one gave the PSNR of its magnitude,
            0 a "math domain error").
    """
    if not (is_finite(data_range) and data_range > 0):
        raise InputError(f"data_range must be a finite number > 0, found {data_range!r}", param="data_range")
    if isinstance(mse, np.ndarray):
        with np.errstate(divide="ignore", invalid="ignore"):
            return 10.0 * np.log10(data_range**2 / mse.astype(np.float64))
    if isinstance(mse, numbers.Real):
        mse = float(mse)
        if not mse >= 0:  # negative or NaN: no PSNR
            return math.nan
        return math.inf if mse == 0 else 10.0 * math.log10(data_range**2 / mse)
    # as a difference of logs: at MSE 0 the gradient is −inf (10·log10(range²/MSE) gave NaN: 0 · inf)
    return 20.0 * math.log10(data_range) - 10.0 * mse.double().log10()

"""PSNR, the one implementation: ``10·log10(range² / MSE)`` in dB (used by train, eval and pipelines)."""

from __future__ import annotations

import math
import numbers
from typing import TYPE_CHECKING, overload

if TYPE_CHECKING:
    from torch import Tensor


@overload
def mse_to_psnr(mse: float, data_range: float = 1.0) -> float: ...
@overload
def mse_to_psnr(mse: Tensor, data_range: float = 1.0) -> Tensor: ...
def mse_to_psnr(mse: float | Tensor, data_range: float = 1.0) -> float | Tensor:
    """PSNR in dB of a mean squared error on values in [0, ``data_range``]; +inf for MSE 0.

    Args:
        mse: a real number (numpy scalars included), or a tensor of any shape (elementwise, computed in
            float64). A negative or NaN MSE gives NaN either way.
    Returns:
        a float for a number, else a float64 tensor of the same shape.
    """
    if isinstance(mse, numbers.Real):
        mse = float(mse)
        if not mse >= 0:  # negative or NaN: no PSNR
            return math.nan
        return math.inf if mse == 0 else 10.0 * math.log10(data_range**2 / mse)
    return 10.0 * (data_range**2 / mse.double()).log10()

"""The ``bayer`` colour mode's colour filter array (RGGB) and the mosaic a Bayer camera sees through it."""

from __future__ import annotations

import numpy as np
import torch

from spikenerf.camera.firing import Array
from spikenerf.core.errors import InputError

#: The colour filter array of the ``bayer`` mode: (0,0)=R, (0,1)=G, (1,0)=G, (1,1)=B.
BAYER_PATTERN = "RGGB"


def bayer_channel_index(height: int, width: int) -> np.ndarray:
    """The RGGB colour filter array: int64 (H, W), 0 = R, 1 = G, 2 = B; (0,0)=R, (0,1)=G, (1,0)=G, (1,1)=B."""
    index = np.ones((height, width), dtype=np.int64)
    index[0::2, 0::2] = 0
    index[1::2, 1::2] = 2
    return index


def bayer_mosaic(rgb: Array) -> Array:
    """Sample (..., 3, H, W) RGB through the RGGB filter array: (..., H, W), same type and dtype."""
    if rgb.ndim < 3 or rgb.shape[-3] != 3:
        raise InputError(f"bayer_mosaic needs an RGB array of shape (..., 3, H, W), got {tuple(rgb.shape)}")
    out = (
        torch.empty_like(rgb[..., 0, :, :])
        if isinstance(rgb, torch.Tensor)
        else np.empty_like(rgb[..., 0, :, :])
    )
    out[..., 0::2, 0::2] = rgb[..., 0, 0::2, 0::2]
    out[..., 0::2, 1::2] = rgb[..., 1, 0::2, 1::2]
    out[..., 1::2, 0::2] = rgb[..., 1, 1::2, 0::2]
    out[..., 1::2, 1::2] = rgb[..., 2, 1::2, 1::2]
    return out

"""Optional mixed precision for the training step (``--amp bf16|fp16``; off by default).

Autocast runs the decoder MLP and the other autocast-listed ops in the low-precision dtype; the grid
factors, the compositing (float64 running sums) and the optimiser stay in float32. ``fp16`` pairs with a
gradient scaler in the trainer; ``bf16`` needs none and also runs on a CPU.
"""

from __future__ import annotations

import contextlib

import torch

from spikenerf.train.settings import AMP_MODES as AMP_MODES  # (defined there, without torch)
from spikenerf.train.settings import AmpMode as AmpMode

_DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


def autocast(device: torch.device, mode: str) -> contextlib.AbstractContextManager:
    """The autocast context of ``mode`` ("none" | "bf16" | "fp16") on ``device``'s type (a no-op for none)."""
    if mode == "none":
        return contextlib.nullcontext()
    return torch.autocast(device.type, dtype=_DTYPES[mode])

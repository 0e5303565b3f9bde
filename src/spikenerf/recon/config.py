"""The settings of ``recon-train``, without importing torch (the CLI's defaults; training:
:mod:`spikenerf.recon.training`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from spikenerf.core.errors import InputError


@dataclass(frozen=True)
class ReconTrainConfig:
    """Training settings: steps, batch of crops, crop side, Adam learning rate (cosine-decayed to 5 %),
    network width, seed, validation/checkpoint periods and the number of val samples scored."""

    iters: int = 4000
    batch: int = 16
    crop: int = 40
    lr: float = 2e-3
    width: int = 16
    seed: int = 0
    eval_every: int = 250
    ckpt_every: int = 100
    val_samples: int = 128

    def check(self) -> ReconTrainConfig:
        for name in ("iters", "batch", "crop", "width", "eval_every", "ckpt_every", "val_samples"):
            if getattr(self, name) < 1:
                raise InputError(f"{name} must be ≥ 1, found {getattr(self, name)}", param=name)
        if not 0 < self.lr < math.inf:
            raise InputError(f"lr must be finite and > 0, found {self.lr}", param="lr")
        return self

"""Training logs: loss terms, λ, learning rates, rays/s and PSNR, to ``curves.csv`` and, with
``log="tensorboard"``, to TensorBoard event files in ``RUN/tensorboard/`` (``tensorboard --logdir RUN``);
the run's warning lines on stderr (:func:`warn`).

Per-step values stay on the training device as running sums (:class:`RunningMeans`); they are read, with
one device synchronisation, only every ``log_every`` steps and at each evaluation.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from spikenerf.core.color import srgb_encode
from spikenerf.core.errors import InputError, check_choice
from spikenerf.train.settings import LOG_KINDS
from spikenerf.train.settings import LogKind as LogKind  # (defined there, without torch)

#: sub-folder of the run folder that holds the event files
TENSORBOARD_DIR = "tensorboard"


class RunningMeans:
    """Means of named scalar tensors over the steps since the last :meth:`read`, summed on their device."""

    def __init__(self) -> None:
        self.sums: dict[str, Tensor] = {}
        self.counts: dict[str, int] = {}

    def add(self, values: dict[str, Tensor]) -> None:
        """Add one step's values (0-d tensors; detached here, no synchronisation)."""
        for name, value in values.items():
            value = value.detach().float()
            self.sums[name] = self.sums[name] + value if name in self.sums else value.clone()
            self.counts[name] = self.counts.get(name, 0) + 1

    def read(self) -> dict[str, float]:
        """The means since the last read (one transfer to the host), then start over."""
        if not self.sums:
            return {}
        names = list(self.sums)
        totals = torch.stack([self.sums[n] for n in names]).cpu().tolist()
        means = {n: t / self.counts[n] for n, t in zip(names, totals, strict=True)}
        self.sums, self.counts = {}, {}
        return means


class TensorBoardLog:
    """Scalars and images for TensorBoard (``torch.utils.tensorboard``; needs the ``tensorboard`` package)."""

    def __init__(self, out: str | Path, start: int = 0) -> None:
        """``start``: the iteration a resumed run continues from; its later events (written before the
        interruption, and about to be written again) are purged, so no step appears twice."""
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError as err:
            raise InputError(
                "log: tensorboard needs the tensorboard package (pip install 'spikenerf[tensorboard]')"
            ) from err
        purge = start + 1 if start > 0 else None
        self.writer = SummaryWriter(log_dir=str(Path(out) / TENSORBOARD_DIR), purge_step=purge)

    def scalars(self, iteration: int, values: dict[str, float]) -> None:
        """One scalar per tag (``loss/recon``, ``psnr/test``, ...); non-finite values are skipped."""
        for tag, value in values.items():
            if math.isfinite(value):
                self.writer.add_scalar(tag, value, iteration)
        self.writer.flush()

    def images(self, iteration: int, pairs: list[tuple[Tensor, Tensor]]) -> None:
        """Test renders beside their ground truth: pairs of linear (H, W, C) images, C = 1 or 3."""
        for i, (pred, target) in enumerate(pairs):
            side = torch.cat([pred.float().cpu(), target.float().cpu()], dim=1).expand(-1, -1, 3)
            image = np.asarray(srgb_encode(side.numpy().astype(np.float64)), np.float32)
            self.writer.add_image(f"test/view{i}", image, iteration, dataformats="HWC")
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


def open_log(kind: str, out: str | Path, start: int = 0) -> TensorBoardLog | None:
    """The logger of ``kind`` (``none`` → None); ``start``: see :class:`TensorBoardLog`."""
    check_choice(kind, LOG_KINDS, "log")
    return TensorBoardLog(out, start) if kind == "tensorboard" else None


def step_scalars(
    means: dict[str, float], lam: float, optimizer: torch.optim.Optimizer, rays_per_second: float
) -> dict[str, Any]:
    """TensorBoard tags of a logging step: ``loss/<term>``, ``lambda``, ``lr/<group>``, ``rays_per_s``."""
    out: dict[str, Any] = {f"loss/{k}": v for k, v in means.items() if k != "srgb_mse"}
    out["lambda"] = lam
    for i, group in enumerate(optimizer.param_groups):
        out[f"lr/{group.get('name', i)}"] = float(group["lr"])
    out["rays_per_s"] = rays_per_second
    return out


def tell(message: str) -> None:
    """One note on stderr (``spikenerf: ...``): what a command does, not a warning."""
    print(f"spikenerf: {message}", file=sys.stderr)


def warn(message: str) -> None:
    """One warning line on stderr (``spikenerf: warning: ...``)."""
    print(f"spikenerf: warning: {message}", file=sys.stderr)

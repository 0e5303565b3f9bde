"""The image baselines: ``nerf-gt`` (the oracle on sharp renders) and the three methods on blur views
(``nerf-blur``, ``nerf-blur-aware``, ``nerf-bad``)."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from spikenerf.core.errors import InputError
from spikenerf.data.dataset import SpikeDataset
from spikenerf.data.targets import ImageTargets, blur_targets, gt_targets
from spikenerf.train.exposure_poses import ExposureLearner
from spikenerf.train.methods.base import Config, TrainMethod, TrainState
from spikenerf.train.pose_refine import PoseLearner


class NerfGT(TrainMethod):
    """The oracle: NeRF on the sharp ground-truth renders."""

    name, views = "nerf-gt", "gt"

    def image_targets(self, dataset: SpikeDataset, stream: np.ndarray | None) -> ImageTargets:
        return gt_targets(dataset, self.config.color, self.name)


class NerfBlur(TrainMethod):
    """NeRF on the conventional camera's blur views, each at its mid-exposure pose."""

    name, views = "nerf-blur", "blur"

    def image_targets(self, dataset: SpikeDataset, stream: np.ndarray | None) -> ImageTargets:
        return blur_targets(dataset, self.config.color, None, self.name)


class NerfBlurAware(NerfBlur):
    """A deblurring NeRF given the true trajectory: each blur view is compared with the mean of renders at
    ``targets.blur_samples`` poses spread over its exposure."""

    name, reads = "nerf-blur-aware", ("targets.blur_samples",)

    def poses_per_view(self) -> int:
        return self.config.targets.blur_samples

    def settings(self) -> list[str]:
        return [f"{self.poses_per_view()} renders across each exposure"]

    def image_targets(self, dataset: SpikeDataset, stream: np.ndarray | None) -> ImageTargets:
        return blur_targets(dataset, self.config.color, self.poses_per_view(), self.name)


class NerfBAD(NerfBlur):
    """BAD-NeRF-like: a deblurring NeRF that learns each blur view's exposure start and end pose (from its
    given pose, train/exposure_poses.py) and compares the mean of ``targets.blur_samples`` renders
    interpolated between them with the blurred image; it reads no trajectory."""

    name, learns_poses = "nerf-bad", True
    reads = ("targets.blur_samples", "exposure.")

    @classmethod
    def check(cls, config: Config) -> None:
        if config.targets.blur_samples < 2:
            raise InputError(
                f"targets.blur_samples must be ≥ 2 for nerf-bad (a start and an end pose), "
                f"found {config.targets.blur_samples}",
                param="targets.blur_samples",
            )
        if config.poses.refine:
            raise InputError(
                "poses.refine: nerf-bad learns each exposure's own start and end pose; turn refinement off",
                param="poses.refine",
            )

    def __init__(self, config: Config) -> None:
        super().__init__(config)
        self.exposures: ExposureLearner | None = None

    def poses_per_view(self) -> int:
        return self.config.targets.blur_samples

    def settings(self) -> list[str]:
        return [f"{self.poses_per_view()} renders between each exposure's learned start and end poses"]

    def learner(self, device: torch.device) -> PoseLearner | None:
        t, c = self.targets, self.config
        assert t is not None, "build_targets first"
        self.exposures = ExposureLearner(
            c.exposure, t.poses[:, 0], t.steps, self.poses_per_view(), c.iters, c.seed + 2, device
        )
        return self.exposures

    def image_poses(self, state: TrainState, index: Tensor) -> Tensor:
        assert self.exposures is not None, "learner first"
        return self.exposures.poses(index).reshape(-1, 4, 4)

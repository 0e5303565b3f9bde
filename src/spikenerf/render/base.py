"""The model interface the trainer, ``render`` and ``eval`` use: a field plus its ray sampler."""

from __future__ import annotations

import dataclasses
from typing import Any

import torch
from torch import Tensor, nn

from spikenerf.fields.base import Field
from spikenerf.render.volume import RenderOutput


class RadianceModel(nn.Module):
    """Base of the renderable models (``build_model`` makes them).

    Attributes:
        kind: "grid" | "mlp". channels: 1 (gray) or 3 (rgb). field: the radiance field module.
    The scene box (2, 3) is a buffer of the field, so it moves with ``.to(device)`` and is in the state.
    """

    kind: str = ""

    def __init__(self, field: Field) -> None:
        super().__init__()
        self.field = field

    @property
    def channels(self) -> int:
        return int(self.field.channels)

    @property
    def config(self) -> Any:
        return self.field.config

    @property
    def scene_box(self) -> Tensor:
        """The field's world bounds (2, 3): ``[min, max]``."""
        return self.field.scene_box

    @property
    def device(self) -> torch.device:
        return self.field.scene_box.device

    def forward(
        self, origins: Tensor, dirs: Tensor, near: Tensor, far: Tensor, perturb: bool
    ) -> RenderOutput:
        """:meth:`render_rays`: origins (N, 3), unit dirs (N, 3), near/far (N,) → per-ray output."""
        return self.render_rays(origins, dirs, near, far, perturb)

    def render_rays(
        self, origins: Tensor, dirs: Tensor, near: Tensor, far: Tensor, perturb: bool = False
    ) -> RenderOutput:
        """Render N rays: origins (N, 3), unit dirs (N, 3), near/far (N,) world distances.

        ``perturb`` draws random sample positions (training); otherwise samples are deterministic.
        """
        raise NotImplementedError

    def on_step(self, step: int, optimizer: torch.optim.Optimizer | None = None) -> bool:
        """Call after every optimiser step with the number of completed steps (1, 2, …).

        Runs the model's schedules (grid: coarse-to-fine upsampling, occupancy updates). Returns True when
        parameter tensors were replaced: then rebuild the optimiser from :meth:`param_groups` (its moments
        are reset, as in TensoRF). Idempotent for a repeated ``step``, so it is safe after a resume.
        """
        return False

    def param_groups(self, base_lr: float | None = None) -> list[dict]:
        """Adam parameter groups with their learning rates and a ``name`` ("grid" | "network").

        ``base_lr=None`` uses the config's rates; otherwise the network rate is ``base_lr`` and the grid rate
        keeps its ratio to it.
        """
        return self.field.param_groups(base_lr)

    def regularization(self, step: int | None = None) -> Tensor:
        """A scalar () prior to add to the loss at optimiser step ``step`` (already weighted; zero unless
        the config enables one; :meth:`spikenerf.fields.base.Field.regularization`)."""
        return self.field.regularization(step)

    def hparams(self) -> dict[str, Any]:
        """Everything ``build_model`` needs to rebuild this model (store it beside the checkpoint)."""
        return {
            "kind": self.kind,
            "channels": self.channels,
            "scene_box": self.scene_box.detach().cpu().tolist(),
            "config": dataclasses.asdict(self.config),
        }

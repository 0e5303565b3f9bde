"""The base of the radiance fields: a scene box, the box normalisation, output channels and Adam groups.

Compare nerfstudio's ``fields/base_field.py``: a field maps world points and view directions to density and
colour; what every field shares lives here, what differs (the encoding, the network) in its subclass.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from spikenerf.core.errors import InputError

#: points a call of :meth:`Field.density_lattice`'s default evaluates at once
LATTICE_CHUNK = 1 << 16


def checked_box(scene_box: Tensor | Any) -> Tensor:
    """``scene_box`` as a (2, 3) float32 tensor of ``[min, max]`` corners; InputError naming it unless it
    has that shape (a (3, 2) box of [min, max] per axis would reshape to other corners), is finite and has
    max > min on every axis (an inverted box renders nothing)."""
    box = torch.as_tensor(scene_box, dtype=torch.float32)
    if tuple(box.shape) != (2, 3):
        raise InputError(
            f"scene_box must be (2, 3) [min, max] corners, found shape {tuple(box.shape)}", param="scene_box"
        )
    if not (bool(torch.isfinite(box).all()) and bool((box[1] > box[0]).all())):
        raise InputError(
            f"scene_box must be finite with max > min on every axis, found {box.tolist()}", param="scene_box"
        )
    return box.clone()


class Field(nn.Module):
    """A radiance field over an axis-aligned scene box.

    Args:
        channels: 1 (gray) or 3 (rgb) colour channels.
        scene_box: (2, 3) world bounds ``[min, max]``; stored as the buffer ``scene_box`` (so it moves with
            ``.to(device)`` and is in the state dict).
        config: the field's frozen hyper-parameter dataclass, kept as ``config``.
    Colour is linear radiance in [0, 1]; density is per world unit.
    """

    scene_box: Tensor

    def __init__(self, channels: int, scene_box: Tensor, config: Any) -> None:
        super().__init__()
        self.config = config
        self.channels = channels
        self.register_buffer("scene_box", checked_box(scene_box))

    def normalize(self, xyz: Tensor) -> Tensor:
        """World points (..., 3) → box-normalised [−1, 1]³ (..., 3)."""
        lo, hi = self.scene_box[0], self.scene_box[1]
        return (xyz - lo) * (2.0 / (hi - lo)) - 1.0

    def denormalize(self, xyz_norm: Tensor) -> Tensor:
        """Box-normalised points (..., 3) → world (..., 3)."""
        lo, hi = self.scene_box[0], self.scene_box[1]
        return lo + (xyz_norm + 1.0) * (0.5 * (hi - lo))

    def forward(self, xyz: Tensor, dirs: Tensor) -> tuple[Tensor, Tensor]:
        """World points (M, 3), unit dirs (M, 3) → density (M,) per world unit, colour (M, C)."""
        raise NotImplementedError

    @torch.no_grad()
    def density_lattice(self, coords: Tensor) -> Tensor:
        """Density per world unit (G, G, G) at every point of the lattice ``coords``³ ((G,) normalised
        coordinates in [−1, 1], index order x, y, z), without gradients. Here :meth:`forward` on
        :data:`LATTICE_CHUNK` points at a time (the density does not depend on the view direction, so any
        direction serves); a field may compute it faster (the grid field: by separable interpolation)."""
        g = coords.shape[0]
        axes = torch.meshgrid(coords, coords, coords, indexing="ij")
        points = self.denormalize(torch.stack(axes, dim=-1).reshape(-1, 3))
        dirs = torch.zeros_like(points[:LATTICE_CHUNK])
        dirs[:, 2] = -1.0
        parts = [
            self(points[i : i + LATTICE_CHUNK], dirs[: len(points[i : i + LATTICE_CHUNK])])[0]
            for i in range(0, len(points), LATTICE_CHUNK)
        ]
        return torch.cat(parts).reshape(g, g, g)

    def prepare(self) -> None:
        """Build what the field's first forward would otherwise build (a fused kernel), so that training
        times only its steps; nothing unless the field needs it. Call after moving it to its device."""

    def regularization(self, step: int | None = None) -> Tensor:
        """A scalar () prior to add to the loss at optimiser step ``step`` (None: not in training; already
        weighted); zero unless the field defines one."""
        return self.scene_box.new_zeros(())

    def param_groups(self, base_lr: float | None = None) -> list[dict]:
        """Adam groups, each with ``params``, ``lr`` and a ``name`` ("grid" | "network").

        The default is one "network" group of all parameters at ``base_lr`` (default ``config.lr``).
        """
        return [{"params": list(self.parameters()), "lr": base_lr or self.config.lr, "name": "network"}]

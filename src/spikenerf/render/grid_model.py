"""Ray marching of the grid field: fixed steps, occupancy skipping, colour only where weights matter."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from spikenerf.data.rays import ray_box_bounds
from spikenerf.fields.grid import GridField
from spikenerf.render.base import RadianceModel
from spikenerf.render.volume import RenderOutput, composite, weights_from_density


class GridModel(RadianceModel):
    """Renders a :class:`~spikenerf.fields.grid.GridField`.

    Samples lie in intervals of the field's ``step_size`` starting at ``near``. With ``use_occupancy`` the
    rays are first shortened to the box around occupied cells (snapped to the same step lattice, so the
    samples kept are exactly those of the full march) and density is evaluated only in occupied cells;
    colour is decoded only where the compositing weight exceeds ``config.weight_threshold``. Skipped samples
    count as zero density: only the near-empty haze of culled cells is lost.
    """

    kind = "grid"
    field: GridField

    def __init__(self, field: GridField) -> None:
        super().__init__(field)
        self.use_occupancy = True

    def on_step(self, step: int, optimizer: torch.optim.Optimizer | None = None) -> bool:
        return self.field.on_step(step)

    def _shorten(
        self, origins: Tensor, dirs: Tensor, near: Tensor, far: Tensor, step: float
    ) -> tuple[Tensor, Tensor]:
        """near/far narrowed to the occupied box, ``near`` moved by whole steps only."""
        box = self.field.denormalize(self.field.occupancy.bounds)
        enter, leave = ray_box_bounds(origins, dirs, box, min_near=0.0)
        skip = torch.floor((enter - near) / step).clamp_min(0.0)
        lo = near + skip * step
        hi = torch.minimum(far, leave)
        return lo, torch.maximum(hi, lo)

    def render_rays(
        self, origins: Tensor, dirs: Tensor, near: Tensor, far: Tensor, perturb: bool = False
    ) -> RenderOutput:
        field, cfg = self.field, self.field.config
        n, step = origins.shape[0], field.step_size
        if self.use_occupancy:
            near, far = self._shorten(origins, dirs, near, far, step)
        span = float((far - near).max()) if n else 0.0
        s = max(1, min(cfg.max_samples, math.ceil(span / step)))
        t_start = near[:, None] + step * torch.arange(s, device=near.device, dtype=near.dtype)
        deltas = (far[:, None] - t_start).clamp(0.0, step)
        t = t_start + (torch.rand_like(t_start) if perturb else 0.5) * deltas

        flat = (deltas.reshape(-1) > 0).nonzero().squeeze(1)
        o_n = field.normalize(origins)
        d_n = dirs * (2.0 / (field.scene_box[1] - field.scene_box[0]))
        xn = self._points(o_n, d_n, t, flat, s)
        if self.use_occupancy:
            keep = field.occupancy.lookup(xn)
            flat, xn = flat[keep], xn[keep]
        sigma = t.new_zeros(n * s)
        if len(flat):
            sigma = sigma.index_copy(0, flat, field.density_norm(xn))
        weights = weights_from_density(sigma.view(n, s), deltas)

        app = (weights.detach().reshape(-1) > cfg.weight_threshold).nonzero().squeeze(1)
        colors = t.new_zeros(n * s, field.channels)
        if len(app):
            rgb = field.color_norm(self._points(o_n, d_n, t, app, s), dirs[app // s])
            colors = colors.index_copy(0, app, rgb)
        color, depth, opacity = composite(weights, colors.view(n, s, -1), t)
        return RenderOutput(color, depth, opacity, weights=weights, num_samples=len(flat))

    @staticmethod
    def _points(origins: Tensor, dirs: Tensor, t: Tensor, flat: Tensor, s: int) -> Tensor:
        """Points (M, 3) of the flat sample indices ``flat`` into (N, S) samples along the given rays."""
        ray = flat // s
        return torch.addcmul(origins[ray], t.reshape(-1)[flat, None], dirs[ray])

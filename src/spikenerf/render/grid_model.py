"""Ray marching of the grid field: fixed steps, occupancy skipping, colour only where weights matter."""

from __future__ import annotations

import torch
from torch import Tensor

from spikenerf.data.rays import ray_box_bounds
from spikenerf.fields.grid import GridField
from spikenerf.render.base import RadianceModel
from spikenerf.render.volume import RenderOutput, packed_composite, packed_weights


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

    @torch.no_grad()
    def _march(
        self, o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, step: float
    ) -> tuple[Tensor, Tensor]:
        """Packed sample slots inside ``[near, far)`` and (with ``use_occupancy``) in occupied cells.

        Returns ray (M,) and step number k (M,) of each kept slot, int64, ray after ray: slot k of a ray
        covers ``[near + k·step, min(near + (k+1)·step, far))``. No padding: the work is the total number of
        slots, not rays × the longest ray. The occupancy test uses the slot's midpoint.
        """
        counts = torch.floor((far - near) / step).long().add_(1).clamp_(0, self.field.config.max_samples)
        counts = torch.where(far > near, counts, torch.zeros_like(counts))
        total = int(counts.sum())
        ray = torch.repeat_interleave(
            torch.arange(len(counts), device=near.device), counts, output_size=total
        )
        first = torch.cumsum(counts, dim=0) - counts
        k = torch.arange(total, device=near.device) - first[ray]
        t_start = near[ray] + step * k
        inside = t_start < far[ray]
        if self.use_occupancy:
            t_mid = t_start + 0.5 * (far[ray] - t_start).clamp(max=step)
            inside &= self.field.occupancy.lookup(torch.addcmul(o_n[ray], t_mid[:, None], d_n[ray]))
        return ray[inside], k[inside]

    def render_rays(
        self, origins: Tensor, dirs: Tensor, near: Tensor, far: Tensor, perturb: bool = False
    ) -> RenderOutput:
        field, cfg = self.field, self.field.config
        n, step = origins.shape[0], field.step_size
        if self.use_occupancy:
            near, far = self._shorten(origins, dirs, near, far, step)
        o_n = field.normalize(origins)
        d_n = dirs * (2.0 / (field.scene_box[1] - field.scene_box[0]))
        ray, k = self._march(o_n, d_n, near, far, step)
        t_start = near[ray] + step * k
        deltas = (far[ray] - t_start).clamp(0.0, step)
        t = t_start + (torch.rand_like(t_start) if perturb else 0.5) * deltas
        xn = torch.addcmul(o_n[ray], t[:, None], d_n[ray])
        sigma = field.density_norm(xn) if len(ray) else t.new_zeros(0)
        weights = packed_weights(sigma, deltas, ray, n)
        app = (weights.detach() > cfg.weight_threshold).nonzero().squeeze(1)
        rgb = field.color_norm(xn[app], dirs[ray[app]]) if len(app) else t.new_zeros(0, field.channels)
        color, depth, opacity = packed_composite(weights, ray, n, t, rgb, app)
        return RenderOutput(color, depth, opacity, num_samples=len(ray))

"""NeRF's two-pass rendering: stratified coarse samples, then inverse-CDF fine samples."""

from __future__ import annotations

import torch
from torch import Tensor

from spikenerf.fields.mlp import MLPField
from spikenerf.render.base import RadianceModel
from spikenerf.render.volume import (
    RenderOutput,
    composite,
    deltas_from_samples,
    sample_pdf,
    stratified_samples,
    weights_from_density,
)


class MLPModel(RadianceModel):
    """Renders an :class:`~spikenerf.fields.mlp.MLPField` the way NeRF does.

    The coarse network sees ``n_coarse`` stratified samples; the fine network sees those plus ``n_fine``
    samples drawn from the coarse weights. ``color`` is the fine pass; ``coarse_color`` is returned for the
    coarse loss term (NeRF trains both with the same target).
    """

    kind = "mlp"
    field: MLPField

    def _pass(
        self, origins: Tensor, dirs: Tensor, t: Tensor, far: Tensor, fine: bool, perturb: bool
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        n, s = t.shape
        pts = origins[:, None] + t[..., None] * dirs[:, None]
        noise = self.field.config.raw_noise_std if perturb else 0.0
        view = dirs[:, None].expand(n, s, 3).reshape(-1, 3)
        sigma, rgb = self.field.query(pts.reshape(-1, 3), view, fine=fine, noise_std=noise)
        weights = weights_from_density(sigma.view(n, s), deltas_from_samples(t, far))
        color, depth, opacity = composite(weights, rgb.view(n, s, -1), t)
        return color, depth, opacity, weights

    def render_rays(
        self, origins: Tensor, dirs: Tensor, near: Tensor, far: Tensor, perturb: bool = False
    ) -> RenderOutput:
        cfg = self.field.config
        t_c, edges = stratified_samples(near, far, cfg.n_coarse, perturb)
        color_c, depth, opacity, weights = self._pass(origins, dirs, t_c, far, False, perturb)
        if cfg.n_fine <= 0:
            return RenderOutput(color_c, depth, opacity, weights=weights, num_samples=t_c.numel())
        t_f = sample_pdf(edges, weights.detach(), cfg.n_fine, perturb)
        t_all, _ = torch.sort(torch.cat([t_c, t_f], dim=-1), dim=-1)
        color, depth, opacity, weights = self._pass(origins, dirs, t_all, far, True, perturb)
        return RenderOutput(
            color,
            depth,
            opacity,
            weights=weights,
            coarse_color=color_c,
            num_samples=t_c.numel() + t_all.numel(),
        )

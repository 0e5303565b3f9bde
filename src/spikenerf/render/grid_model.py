"""Ray marching of the grid field: fixed steps, occupancy skipping, colour only where weights matter."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from spikenerf.data.rays import ray_box_bounds
from spikenerf.fields.grid import GridField
from spikenerf.render import march_cpu, march_triton, volume_triton
from spikenerf.render.base import RadianceModel
from spikenerf.render.volume import (
    RenderOutput,
    early_stop_mask,
    packed_composite,
    packed_weights,
    ray_offsets,
)

#: slots the static march lays out for each slot of the ``static_samples`` budget (most are empty space)
MARCH_SLOTS = 4


class GridModel(RadianceModel):
    """Renders a :class:`~spikenerf.fields.grid.GridField`.

    Samples lie in intervals of the field's ``step_size`` starting at ``near``. With ``use_occupancy`` the
    rays are first shortened to the box around occupied cells (snapped to the same step lattice, so the
    samples kept are exactly those of the full march) and density is evaluated only in occupied cells;
    colour is decoded only where the compositing weight exceeds ``config.weight_threshold``. Skipped samples
    count as zero density: only the near-empty haze of culled cells is lost.

    With the field's ``static_samples`` N > 0 the same samples lie in a fixed budget of N × rays slots
    (:meth:`_march_static` over ``MARCH_SLOTS`` times as many, then :func:`compact_slots`): no
    data-dependent shape and no host sync, for CUDA graphs and ``torch.compile(fullgraph=True)``; samples
    beyond the budget are cut (``RenderOutput.dropped_samples``).
    The budget serves the training renders only: a render without gradients (``eval``, ``render``, the test
    views during training) takes the packed path, which cuts nothing.
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

    def _counts(self, near: Tensor, far: Tensor, step: float) -> Tensor:
        """Sample slots (N,) int64 of each ray: the steps starting in ``[near, far)``, ≤ ``max_samples``."""
        counts = torch.floor((far - near) / step).long().add_(1).clamp_(0, self.field.config.max_samples)
        return torch.where(far > near, counts, torch.zeros_like(counts))

    def _kept(
        self, o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, step: float, ray: Tensor, k: Tensor
    ) -> Tensor:
        """Which slots (M,) bool of rays ``ray`` (M,), steps ``k`` (M,) start before ``far`` and (with
        ``use_occupancy``) have their midpoint in an occupied cell."""
        t_start = near.index_select(0, ray) + step * k
        far_at = far.index_select(0, ray)
        inside = t_start < far_at
        if self.use_occupancy:
            t_mid = t_start + 0.5 * (far_at - t_start).clamp(max=step)
            # a product, then a sum (not addcmul, which may fuse them): the rounding of march_triton's
            # kernels, which keep the same steps
            mid = o_n.index_select(0, ray) + t_mid[:, None] * d_n.index_select(0, ray)
            inside &= self.field.occupancy.lookup(mid)
        return inside

    @torch.no_grad()
    def _march(
        self, o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, step: float
    ) -> tuple[Tensor, Tensor]:
        """Packed sample slots inside ``[near, far)`` and (with ``use_occupancy``) in occupied cells.

        Returns ray (M,) and step number k (M,) of each kept slot, int64, ray after ray: slot k of a ray
        covers ``[near + k·step, min(near + (k+1)·step, far))``. No padding: the work is the total number of
        slots, not rays × the longest ray. The occupancy test uses the slot's midpoint. On a CPU the fused
        kernel's loop (``march_cpu.py``) keeps the same slots without laying out the candidates.
        """
        counts = self._counts(near, far, step)
        if self.marched(o_n):  # the kept steps only, tested where they are made
            grid = self._grid()
            kept = march_triton.kept_counts(o_n, d_n, near, far, counts, grid, step)
            ray, k, _ = march_triton.write(o_n, d_n, near, far, counts, grid, step, kept, int(kept.sum()))
            return ray, k
        if march_cpu.applies(o_n, d_n, near, far):
            return march_cpu.march(o_n, d_n, near, far, counts, self._grid(), step)
        total = int(counts.sum())
        ray = torch.repeat_interleave(
            torch.arange(len(counts), device=near.device), counts, output_size=total
        )
        first = torch.cumsum(counts, dim=0) - counts
        k = torch.arange(total, device=near.device) - first.index_select(0, ray)
        inside = self._kept(o_n, d_n, near, far, step, ray, k)
        return ray[inside], k[inside]

    @torch.no_grad()
    def _march_static(
        self, o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, step: float, budget: int
    ) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """The slots of :meth:`_march` laid out in a fixed ``budget`` B of slots: no compaction, no host sync.

        The rays' steps lie ray after ray, unkept ones included (a ``repeat_interleave`` of each ray's
        step count, cut to add up to B: no data-dependent shape), so the rays and steps are those of the
        packed march, in its order. When the rays need more than B slots, the march is cut at the end of
        the budget: the ray there loses its tail and the later rays get no slot. The slots left after every
        ray's last one take ray N − 1 and are never kept (:func:`compact_slots` lays out its own spare slots).
        Returns ray (B,) and ray_at (B,) in [0, N) (the same here; :func:`compact_slots` takes both), step
        number k (B,) int64, keep (B,) bool (the slots the packed march keeps) and dropped () int64: the
        slots cut off.
        """
        n = len(near)
        counts = self._counts(near, far, step)
        ends = torch.cumsum(counts, dim=0)
        starts = ends - counts
        laid = (ends.clamp(max=budget) - starts).clamp_min(0)  # each ray's steps in the budget
        rest = (budget - ends[-1]).clamp_min(0)[None]  # and the slots after them: B in all
        index = torch.arange(n + 1, device=near.device)
        ray = torch.repeat_interleave(index, torch.cat([laid, rest]), output_size=budget)
        used = ray < n
        ray = ray.clamp_(max=n - 1)
        k = torch.arange(budget, device=near.device) - starts.index_select(0, ray)
        keep = used & self._kept(o_n, d_n, near, far, step, ray, k)
        return ray, ray, k, keep, (ends[-1] - budget).clamp_min(0)

    @torch.no_grad()
    def _march_fused(
        self, o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, step: float, budget: int
    ) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """:func:`compact_slots` of :meth:`_march_static` in one pass of the Triton march kernels (``march``
        "triton"): the same five outputs for ``budget`` slots, except that every step of every ray is
        tested (not ``MARCH_SLOTS`` × budget of them), so ``dropped`` is exact."""
        counts, grid = self._counts(near, far, step), self._grid()
        kept = march_triton.kept_counts(o_n, d_n, near, far, counts, grid, step)
        ray, k, total = march_triton.write(o_n, d_n, near, far, counts, grid, step, kept, budget)
        return fill_spare(ray, ray, k, total, total.new_zeros(()), len(near), budget)

    def _grid(self) -> Tensor | None:
        return self.field.occupancy.grid if self.use_occupancy else None

    @staticmethod
    def _points(
        o_n: Tensor,
        d_n: Tensor,
        near: Tensor,
        far: Tensor,
        step: float,
        ray: Tensor,
        k: Tensor,
        perturb: bool,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Distances t (M,), interval lengths (M,) and normalised points (M, 3) of slots ``ray``, ``k`` (M,):
        the slot's centre, or a uniform draw in it with ``perturb``."""
        t_start = near.index_select(0, ray) + step * k
        deltas = (far.index_select(0, ray) - t_start).clamp(0.0, step)
        t = t_start + (torch.rand_like(t_start) if perturb else 0.5) * deltas
        return t, deltas, torch.addcmul(o_n.index_select(0, ray), t[:, None], d_n.index_select(0, ray))

    def render_rays(
        self, origins: Tensor, dirs: Tensor, near: Tensor, far: Tensor, perturb: bool = False
    ) -> RenderOutput:
        field, cfg = self.field, self.field.config
        n, step = origins.shape[0], field.step_size
        if self.use_occupancy:
            near, far = self._shorten(origins, dirs, near, far, step)
        o_n = field.normalize(origins)
        d_n = dirs * (2.0 / (field.scene_box[1] - field.scene_box[0]))
        if cfg.static_samples and n and torch.is_grad_enabled():  # images, metrics: every sample
            return self._render_static(o_n, d_n, dirs, near, far, step, perturb)
        fused = self.fused(o_n)
        ray, k = self._march(o_n, d_n, near, far, step)
        t, deltas, xn = self._points(o_n, d_n, near, far, step, ray, k, perturb)
        offsets = ray_offsets(ray, n)
        stopping = bool(cfg.early_stop and len(ray) and torch.is_grad_enabled())
        if stopping:  # the density looked up only up to each ray's stop where the CPU kernel applies
            # (a threshold outside (0, 1): every sample, and early_stop_mask refuses it below)
            limit = -math.log(cfg.early_stop) if 0.0 < cfg.early_stop < 1.0 else math.inf
            sigma = field.density_until(xn, offsets, deltas, limit)
        else:
            sigma = field.density_norm(xn) if len(ray) else t.new_zeros(0)
        if stopping:  # on σ, so its gradient is exactly 0
            stop = early_stop_mask(sigma, deltas, ray, n, cfg.early_stop, offsets, fused)
            sigma = torch.where(stop, sigma, 0.0)
        weights = packed_weights(sigma, deltas, ray, n, offsets, fused)
        app = (weights.detach() > cfg.weight_threshold).nonzero().squeeze(1)
        if len(app):
            rgb = field.color_norm(xn.index_select(0, app), dirs, ray.index_select(0, app))
        else:
            rgb = t.new_zeros(0, field.channels)
        color, depth, opacity = packed_composite(weights, ray, n, t, rgb, app, offsets=offsets, fused=fused)
        return RenderOutput(color, depth, opacity, num_samples=len(ray))

    def fused(self, points: Tensor) -> bool:
        """Whether this render sums along its rays with the Triton kernels (``composite`` "triton" where
        they run on ``points``' device; elsewhere, e.g. ``eval`` on a CPU, the torch sums)."""
        return self.field.config.composite == "triton" and volume_triton.applies(points)

    def marched(self, points: Tensor) -> bool:
        """Whether this render marches with the Triton kernels (``march`` "triton" where they run on
        ``points``' device; elsewhere the torch march)."""
        return self.field.config.march == "triton" and volume_triton.applies(points)

    def _render_static(
        self, o_n: Tensor, d_n: Tensor, dirs: Tensor, near: Tensor, far: Tensor, step: float, perturb: bool
    ) -> RenderOutput:
        """:meth:`render_rays` in ``static_samples`` × N slots, for normalised origins and directions (N, 3),
        unit ``dirs`` (N, 3), near/far (N,): every shape is fixed by N.

        The march lays out ``MARCH_SLOTS`` × that many slots (:meth:`_march_static`: cheap, points and an
        occupancy lookup), and :func:`compact_slots` moves the kept ones (inside the ray, in occupied
        cells) into the budget, where the field is evaluated. Unkept and spare slots get zero density (so
        zero weight); colour is counted where the weight exceeds
        ``weight_threshold``, so the result is the packed path's when all samples fit. With ``early_stop``
        the slots behind each ray's early stop count as empty; with ``static_visible`` V they are found by
        a density pass without gradient and the others moved into V × N slots (:func:`compact_slots`
        again), where density, colour and the backward run. Colour is decoded in every slot, or with
        ``static_colors`` C > 0 in the C × N slots of largest weight only (:func:`colour_slots`).
        """
        field, cfg, n = self.field, self.field.config, o_n.shape[0]
        fused = self.fused(o_n)
        budget = n * cfg.static_samples
        if self.marched(o_n):
            ray, ray_at, k, keep, dropped = self._march_fused(o_n, d_n, near, far, step, budget)
        else:
            marched = self._march_static(o_n, d_n, near, far, step, MARCH_SLOTS * budget)
            ray, ray_at, k, keep, dropped = compact_slots(*marched, n, budget)
        t, deltas, xn = self._points(o_n, d_n, near, far, step, ray_at, k, perturb)
        if cfg.static_visible and cfg.early_stop:  # a no-grad pass finds where each ray stops
            with torch.no_grad():
                sigma = torch.where(keep, field.density_norm(xn), 0.0)
                offsets = ray_offsets(ray, 2 * n)
                keep = keep & early_stop_mask(sigma, deltas, ray, 2 * n, cfg.early_stop, offsets, fused)
            budget = n * cfg.static_visible
            source, filled, _ = slot_sources(keep, budget)
            ray, ray_at, k, keep, dropped = compact_slots(ray, ray_at, k, keep, dropped, n, budget)
            # the kept slots keep the points the stop was found at; the spare ones get distinct new points
            t_new, d_new, x_new = self._points(o_n, d_n, near, far, step, ray_at, k, perturb)
            t = torch.where(filled, t.index_select(0, source), t_new)
            deltas = torch.where(filled, deltas.index_select(0, source), d_new)
            xn = torch.where(filled[:, None], xn.index_select(0, source), x_new)
            sigma = torch.where(keep, field.density_norm(xn), 0.0)
            offsets = ray_offsets(ray, 2 * n)
        else:
            sigma = torch.where(keep, field.density_norm(xn), 0.0)
            offsets = ray_offsets(ray, 2 * n)
            if cfg.early_stop:
                stop = early_stop_mask(sigma, deltas, ray, 2 * n, cfg.early_stop, offsets, fused)
                sigma = torch.where(stop, sigma, 0.0)
        weights = packed_weights(sigma, deltas, ray, 2 * n, offsets, fused)
        shown = weights.detach() > cfg.weight_threshold
        lost = None
        if cfg.static_colors and n * cfg.static_colors < budget:
            slots, lost = colour_slots(weights.detach(), shown, n * cfg.static_colors)
            at = ray_at.index_select(0, slots)
            picked = field.color_norm(xn.index_select(0, slots), dirs.index_select(0, at))
            picked = picked * shown.index_select(0, slots)[:, None]
            rgb = picked.new_zeros(budget, picked.shape[1]).index_put((slots,), picked)
        else:
            rgb = torch.where(shown[:, None], field.color_norm(xn, dirs.index_select(0, ray_at)), 0.0)
        color, depth, opacity = packed_composite(
            weights, ray, 2 * n, t, rgb, None, offsets=offsets, fused=fused
        )
        return RenderOutput(color[:n], depth[:n], opacity[:n], num_samples=budget, dropped_samples=dropped,
                            dropped_colors=lost)  # fmt: skip


def compact_slots(
    ray: Tensor, ray_at: Tensor, k: Tensor, keep: Tensor, dropped: Tensor, n: int, budget: int
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """The kept slots of a static march moved, in order, into ``budget`` B slots: fixed shapes, no host sync.

    Takes :meth:`GridModel._march_static`'s ray, ray_at, k, keep (M,) and dropped () for N rays; returns the
    same five for B slots. Slot i holds the (i+1)-th kept slot of the march (a ``searchsorted`` over the
    running count of kept slots), so each ray's kept samples stay in order and the rays in theirs. Kept
    slots beyond B are cut and added to ``dropped``. The U slots left after the last kept one are spare
    (:func:`fill_spare`): spread evenly over N empty rays N … 2N − 1 (in order; composite over 2N rays and
    keep the first N) at distinct points (ray j mod N, step j div N for the j-th of them), ``keep`` False.
    Were they all one ray at one point, the backward's scatters (``before[ray]`` in :func:`packed_weights`,
    the grid lookups) would pile up on one address, serialised on a GPU.
    """
    source, _, total = slot_sources(keep, budget)
    # no lambda over ``source``: torch 2.4's Dynamo fails to inline that closure (an AssertionError)
    ray, ray_at, k = ray.index_select(0, source), ray_at.index_select(0, source), k.index_select(0, source)
    return fill_spare(ray, ray_at, k, total, dropped, n, budget)


def fill_spare(
    ray: Tensor, ray_at: Tensor, k: Tensor, total: Tensor, dropped: Tensor, n: int, budget: int
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """:func:`compact_slots`' result from ray, ray_at, k (B,) of the kept slots, valid in the first
    min(B, total) slots, and ``total`` () int64 kept slots in all: the later slots made spare (rays N … 2N − 1
    evenly, distinct points, keep False) and the kept slots past B added to ``dropped``."""
    slot = torch.arange(budget, device=ray.device)
    filled = slot < total
    spare = (slot - total).clamp_min(0)
    spare_ray = n + spare * n // (budget - total).clamp_min(1)
    return (
        torch.where(filled, ray, spare_ray),
        torch.where(filled, ray_at, spare % n),
        torch.where(filled, k, spare // n),
        filled,
        dropped + (total - budget).clamp_min(0),
    )


def slot_sources(keep: Tensor, budget: int) -> tuple[Tensor, Tensor, Tensor]:
    """Where each of ``budget`` B slots of :func:`compact_slots` comes from: source (B,) int64, the index of
    the (i+1)-th True of ``keep`` (M,) bool (clamped to M − 1 past the last one), filled (B,) bool (slot i
    has a source) and () int64, the number of True in ``keep``."""
    seen = torch.cumsum(keep, dim=0)
    total = seen[-1]
    slot = torch.arange(budget, device=keep.device)
    return torch.searchsorted(seen, slot, right=True).clamp_(max=len(keep) - 1), slot < total, total


def colour_slots(weights: Tensor, shown: Tensor, count: int) -> tuple[Tensor, Tensor]:
    """The ``count`` slots (count,) int64 of largest ``weights`` (B,) among the ``shown`` (B,) bool ones
    (unshown slots fill the rest), and () int64: the shown slots left out. Fixed shapes, no host sync."""
    score = torch.where(shown, weights, -1.0)
    slots = torch.topk(score, count, sorted=False).indices
    return slots, (shown.sum() - shown.index_select(0, slots).sum()).clamp_min(0)

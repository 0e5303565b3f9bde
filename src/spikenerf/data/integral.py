"""Spike-count targets over arbitrary windows, and unbiased per-step pose samples inside them.

A spike camera pixel that fired ``N`` times over the steps ``a … b − 1`` saw a mean intensity (over those
``L = b − a`` steps, each at its own pose) between ``φ(N − 1)/L`` and ``φ(N + 1)/L``
(docs/spike-integral.md). So the prefix counts ``C_t = Σ_{k<t} s_k`` of the stream are targets for *every*
window at once: the window ``[a, b)`` has the mean ``φ (C_b − C_a) / L``. :class:`CountTargets` holds
them; :class:`WindowTargetSampler` draws windows of the chosen lengths inside the stream (or outside its
held-out bands), and :func:`stratified_steps` draws S steps of a window (one uniform step in each of S
equal parts), whose mean render is an unbiased estimate of the window's mean render.

:meth:`CountTargets.align` moves a window onto spikes: from the step after one spike of a pixel to the
step of a later one, the pixel saw ``n φ`` of light to within one step's light (the accumulator's residue
after each reset), so the mean ``n φ / L'`` is exact to ``± I / L'`` — an error proportional to the pixel's
brightness, where a fixed window's count is only exact to ``± φ / L`` whatever the brightness.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from spikenerf.camera.layout import to_channels_last
from spikenerf.core.errors import InputError
from spikenerf.data.samplers import SeededSampler
from spikenerf.scenes.projection import project_points
from spikenerf.scenes.trajectory import Intrinsics

#: :attr:`CountTargets.phase` counts a spike's light in 1/256
PHASE_SCALE = 256


@dataclass
class CountTargets:
    """Prefix spike counts and per-step poses of a recorded stream.

    Attributes:
        counts: (T + 1, H, W, C) int16 (int32 past 32767 steps) ``C_t``, the spikes of steps ``0 … t − 1``.
        poses: (T, 4, 4) float32 camera-to-world of each step.
        threshold: φ of the camera.
        phase: None, or (T + 1, H, W, C) uint8: the interpolated fraction of a spike's light already gathered
            before step t, in 1/256 (:func:`count_phases`); ``window_mean`` then reads ``C_t + phase_t/256``.
        usable: None (every step), or (T,) bool: the steps that :meth:`track_mean` and :meth:`still_mean`
            may read (a run's held-out bands excluded, ``data.holdout.Holdout.band``).
    """

    counts: Tensor
    poses: Tensor
    threshold: float
    phase: Tensor | None = None
    usable: Tensor | None = None

    @property
    def steps(self) -> int:
        """T, the recorded steps."""
        return int(self.counts.shape[0]) - 1

    def on(self, device: torch.device | str) -> CountTargets:
        """A copy whose counts and poses live on ``device`` (the training GPU), gathered there."""
        phase = None if self.phase is None else self.phase.to(device)
        usable = None if self.usable is None else self.usable.to(device)
        return CountTargets(self.counts.to(device), self.poses.to(device), self.threshold, phase, usable)

    @property
    def nbytes(self) -> int:
        """Bytes of the counts and phases (what a device copy holds, besides the poses)."""
        return self.counts.nbytes + (0 if self.phase is None else self.phase.nbytes)

    def window_mean(self, start: Tensor, end: Tensor, pixels: Tensor) -> Tensor:
        """Mean intensity ``φ (C_end − C_start) / (end − start)`` of each window, (B, C) float32, on the
        counts' device; with :attr:`phase`, each count plus its interpolated fraction.

        Args:
            start, end: (B,) int64 window bounds, ``0 ≤ start < end ≤ T``. pixels: (B, 2) int64 ``(x, y)``.
        """
        device = self.counts.device
        start, end, pixels = start.to(device), end.to(device), pixels.to(device)
        x, y = pixels[:, 0], pixels[:, 1]
        n = (self.counts[end, y, x].int() - self.counts[start, y, x].int()).float()
        if self.phase is not None:
            n = n + (self.phase[end, y, x].float() - self.phase[start, y, x].float()) / PHASE_SCALE
        return self.threshold * n / (end - start).float()[:, None]

    def track_steps(self, steps: Tensor, half: int) -> tuple[Tensor, Tensor]:
        """The steps ``steps − half … steps + half`` (B, L) int64, clamped into the stream, and (B, L) bool:
        inside the stream and :attr:`usable`."""
        device, total = self.counts.device, self.steps
        j = steps.to(device)[:, None] + torch.arange(-half, half + 1, device=device)[None]
        valid = (j >= 0) & (j < total)
        j = j.clamp(0, total - 1)
        if self.usable is not None:
            valid &= self.usable.to(device)[j]
        return j, valid

    def _mean_along(self, j: Tensor, x: Tensor, y: Tensor, valid: Tensor) -> Tensor:
        """``φ/L' Σ s_j(x_j, y_j)`` (B, C) over the L' ``valid`` of the (B, L) steps ``j`` and pixels."""
        spikes = (self.counts[j + 1, y, x].int() - self.counts[j, y, x].int()).float() * valid[..., None]
        return self.threshold * spikes.sum(dim=1) / valid.sum(dim=1).clamp_min(1)[:, None].float()

    def track_mean(
        self, points: Tensor, steps: Tensor, half: int, intrinsics: Intrinsics, poses: Tensor | None = None
    ) -> Tensor:
        """Mean spike intensity (B, C) float32 along the image tracks of world ``points`` (B, 3): over the
        steps ``steps − half … steps + half`` of ``steps`` (B,) int64, the spike of each step read at the
        pixel the point projects to in that step's pose (OpenGL axes), ``φ/L' Σ_j s_j(pixel_j)`` over the
        L' steps inside the stream (and :attr:`usable`) whose pixel is inside the image. On the counts'
        device; no host sync. A one-step track (``half`` 0) of a point on pixel p's ray at step k is
        ``window_mean(k, k + 1, p)``. ``poses``: (B, 2·half + 1, 4, 4) the poses of the steps
        :meth:`track_steps` gives (a refined trajectory's, so that the track follows the poses the point
        was rendered from); None: :attr:`poses`.
        """
        j, valid = self.track_steps(steps, half)
        if poses is None:
            poses = self.poses.to(j.device)[j]
        elif tuple(poses.shape) != (*j.shape, 4, 4):
            raise InputError(
                f"poses must be (B, 2·half + 1, 4, 4) = {(*j.shape, 4, 4)}, found {tuple(poses.shape)}",
                param="poses",
            )
        u, v, depth = project_points(
            poses.to(j.device, torch.float32), points.to(j.device, torch.float32)[:, None], intrinsics
        )
        x, y = torch.floor(u).long(), torch.floor(v).long()
        valid &= (depth > 1e-6) & (x >= 0) & (x < intrinsics.width) & (y >= 0) & (y < intrinsics.height)
        x, y = x.clamp(0, intrinsics.width - 1), y.clamp(0, intrinsics.height - 1)
        return self._mean_along(j, x, y, valid)

    def still_mean(self, pixels: Tensor, steps: Tensor, half: int) -> Tensor:
        """:meth:`track_mean` of a track that stays at ``pixels`` (B, 2) int64 ``(x, y)``: the pixel's own
        mean spike intensity (B, C) over the same steps; without :attr:`usable`, ``window_mean`` of the
        window ``[steps − half, steps + half + 1)`` clipped to the stream."""
        j, valid = self.track_steps(steps, half)
        pixels = pixels.to(j.device)
        x, y = pixels[:, :1].expand_as(j), pixels[:, 1:].expand_as(j)
        return self._mean_along(j, x, y, valid)

    def align(
        self, start: Tensor, end: Tensor, pixels: Tensor, generator: torch.Generator, longest: int
    ) -> tuple[Tensor, Tensor]:
        """Spike-aligned windows: each window ``[start, end)`` of length L becomes ``[t_j + 1, t_{j+n} + 1)``,
        from the step after the first spike ``j`` of one channel (drawn at random) at or after ``start`` to
        the step of spike ``j + n``, with ``n = max(1, round(L · rate))`` of that pixel's mean rate, so that
        bright pixels keep windows of about L steps and dark ones get longer ones. A window keeps its place
        where the stream has too few spikes after ``start`` or the aligned one would exceed ``longest``.

        Args:
            start, end: (B,) int64 windows. pixels: (B, 2) int64 ``(x, y)``. generator: draws the channel.
            longest: the longest aligned window allowed, in steps.
        Returns:
            start, end (B,) int64 on the counts' device; ``window_mean`` of an aligned window's channel is
            ``n φ / L'``.
        """
        device, total = self.counts.device, self.steps
        channel = torch.randint(0, self.counts.shape[-1], (len(start),), generator=generator).to(device)
        start, end, pixels = start.to(device), end.to(device), pixels.to(device)
        column = self.counts[:, pixels[:, 1], pixels[:, 0], channel].T.contiguous().long()  # (B, T + 1)
        rate = column[:, -1].double() / total
        n = torch.clamp(torch.round((end - start).double() * rate), min=1).long()
        # the (1-based) index of the first spike at or after each start
        first = column.gather(1, start[:, None])[:, 0] + 1
        ok = first + n <= column[:, -1]
        wanted = torch.stack([first, torch.where(ok, first + n, first)], dim=1)
        at = torch.searchsorted(column, wanted) - 1  # the step of each wanted spike
        new_start, new_end = at[:, 0] + 1, at[:, 1] + 1
        ok &= new_end - new_start <= longest
        return torch.where(ok, new_start, start), torch.where(ok, new_end, end)


def count_phases(counts: Tensor, max_span: int = 0) -> Tensor:
    """Interpolated spike phases of prefix counts ``C`` (T + 1, H, W, C): (T + 1, H, W, C) uint8.

    The step after a pixel's spike is an *anchor*: its accumulator has just been reset, so the light
    gathered since the stream began is ``n φ`` there to within one step's light (``n = C_t``, up to the
    unknown start value, which cancels in a window). Between anchors ``u < v`` the light is taken to grow
    linearly, so step ``t`` holds the fraction ``(t − u) / (v − u)`` of the next spike's ``φ``; it is
    stored rounded to 1/256 (:data:`PHASE_SCALE`). Steps before a pixel's first anchor or after its last
    get 0, the plain count. A window's mean ``φ (C_b + f_b − C_a − f_a) / L`` is then exact to within one
    step's light over L (plus the rounding) where the light is steady between the spikes, instead of
    ``± φ / L``; where it is not, the error stays below ``2 φ / L`` (each end is off by less than ``φ``: the
    interpolated and the true accumulator both rise from 0 to ``φ`` between two anchors). With
    ``max_span`` > 0 only anchors at most that many steps apart are interpolated between (elsewhere 0, the
    plain count): a long span spreads a window's light over the image motion of the whole span.
    """
    steps = counts.shape[0]
    shape = counts.shape[1:]
    # last anchor at or before t (−1: none yet); kept for the backward pass
    last = torch.empty((steps, *shape), dtype=torch.int16 if steps <= 32767 else torch.int32)
    running = torch.full(shape, -1, dtype=torch.int32)
    for t in range(steps):
        if t > 0:
            running = torch.where(counts[t] != counts[t - 1], torch.tensor(t, dtype=torch.int32), running)
        last[t] = running.to(last.dtype)
    phase = torch.zeros((steps, *shape), dtype=torch.uint8)
    following = torch.full(shape, -1, dtype=torch.int32)  # first anchor after t (−1: none)
    for t in range(steps - 1, -1, -1):
        before = last[t].int()
        span = (following - before).clamp_min(1)
        inside = (before >= 0) & (following > 0) & ((span <= max_span) | (max_span <= 0))
        span = span.float()
        frac = torch.round((t - before).float() / span * PHASE_SCALE).clamp_max(PHASE_SCALE - 1)
        phase[t] = torch.where(inside, frac, 0.0).to(torch.uint8)
        if t > 0:
            following = torch.where(counts[t] != counts[t - 1], torch.tensor(t, dtype=torch.int32), following)
    return phase


def count_targets(
    stream: np.ndarray, poses: np.ndarray, threshold: float, interpolate: bool = False, max_span: int = 0
) -> CountTargets:
    """:class:`CountTargets` of a (T, H, W) gray or (T, 3, H, W) rgb 0/1 stream and its (T, 4, 4) poses;
    ``interpolate``: with :func:`count_phases` (between spikes at most ``max_span`` steps apart; 0: any).

    Raises:
        InputError: the poses do not match the stream's steps (names ``poses``).
    """
    spikes = to_channels_last(np.asarray(stream))
    if len(poses) != spikes.shape[0]:
        raise InputError(f"poses: {len(poses)} poses for a stream of {spikes.shape[0]} steps", param="poses")
    dtype = torch.int16 if spikes.shape[0] <= torch.iinfo(torch.int16).max else torch.int32
    counts = torch.zeros((spikes.shape[0] + 1, *spikes.shape[1:]), dtype=dtype)
    running = torch.zeros(spikes.shape[1:], dtype=torch.int32)
    for t in range(spikes.shape[0]):  # one step at a time: no (T, H, W, C) int32 temporary
        running += torch.as_tensor(np.asarray(spikes[t], dtype=np.uint8))
        counts[t + 1] = running.to(dtype)
    phase = count_phases(counts, max_span) if interpolate else None
    poses_t = torch.as_tensor(np.asarray(poses), dtype=torch.float32)
    return CountTargets(counts, poses_t, float(threshold), phase)


def stratified_steps(start: Tensor, end: Tensor, samples: int, generator: torch.Generator) -> Tensor:
    """S steps of each window ``[start, end)``: one uniform step in each of S equal parts of it.

    Together the S parts draw a uniform position in the window's [0, 1) span, so each step is expected
    S / L times among the S draws, whatever S and L: the mean of the S renders is an exactly unbiased
    estimate of the window's mean render.

    Args:
        start, end: (B,) int64 window bounds. samples: S ≥ 1. generator: seeded generator.
    Returns:
        (B, S) int64 steps, ascending within each row.
    """
    if samples < 1:
        raise InputError(f"samples must be ≥ 1, found {samples}", param="samples")
    length = (end - start).double()[:, None]
    u = torch.rand((len(start), samples), generator=generator, dtype=torch.float64)
    frac = (torch.arange(samples, dtype=torch.float64) + u) / samples
    offset = torch.minimum(torch.floor(frac * length), length - 1).long()
    return start[:, None] + offset


class WindowTargetSampler(SeededSampler):
    """Seeded, resumable draws of (window, pixel, steps) for the spike-integral targets.

    Each target draws a length from ``lengths`` uniformly, then its first step uniformly among the allowed
    starts of that length (every ``0 … T − L``, or those whose window overlaps no held-out band), a pixel
    uniformly, and S stratified steps per estimate (:func:`stratified_steps`), G estimates each.

    Args:
        steps: T. height, width: image size. lengths: window lengths, each in ``1 … T``.
        samples: S steps per estimate. groups: G independent estimates per window. seed: generator seed.
        starts: length -> (N,) int64 allowed first steps (None: all).
        aligner: moves the drawn windows onto spikes (:meth:`CountTargets.align` with its ``longest``
            bound), called with (start, end, pixels, generator) before the steps are drawn; None: fixed.
    """

    def __init__(
        self,
        steps: int,
        height: int,
        width: int,
        lengths: tuple[int, ...] | list[int],
        samples: int,
        groups: int = 1,
        seed: int = 0,
        starts: dict[int, Tensor] | None = None,
        aligner: Callable[..., tuple[Tensor, Tensor]] | None = None,
    ) -> None:
        if not lengths or any(not 1 <= n <= steps for n in lengths):
            raise InputError(
                f"lengths: every window length must be between 1 and the {steps} recorded steps, found "
                f"{list(lengths)}",
                param="lengths",
            )
        if samples < 1 or groups < 1:
            raise InputError(f"samples and groups must be ≥ 1, found {samples}, {groups}", param="samples")
        self.steps, self.height, self.width = steps, height, width
        self.lengths = torch.as_tensor(list(lengths), dtype=torch.int64)
        self.samples, self.groups = samples, groups
        tables = [torch.arange(steps - n + 1) if starts is None else starts[n] for n in lengths]
        if any(len(t) == 0 for t in tables):
            raise InputError(f"no window of lengths {list(lengths)} to train on among the {steps} steps")
        self.counts = torch.as_tensor([len(t) for t in tables], dtype=torch.float64)
        self.table = torch.zeros((len(tables), max(len(t) for t in tables)), dtype=torch.int64)
        for i, t in enumerate(tables):
            self.table[i, : len(t)] = t
        super().__init__(seed)
        self.aligner = aligner

    def sample(self, windows: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """``windows`` targets → start, end (B,) int64; pixels (B, 2) int64 ``(x, y)``; steps (B, G·S)
        int64 (G groups of S stratified steps, group-major)."""
        g = self.generator
        which = torch.randint(0, len(self.lengths), (windows,), generator=g)
        u = torch.rand(windows, generator=g, dtype=torch.float64)
        pick = torch.minimum(torch.floor(u * self.counts[which]).long(), self.counts[which].long() - 1)
        start = self.table[which, pick]
        end = start + self.lengths[which]
        flat = torch.randint(0, self.height * self.width, (windows,), generator=g)
        pixels = torch.stack([flat % self.width, flat // self.width], dim=-1)
        if self.aligner is not None:
            start, end = (x.cpu() for x in self.aligner(start, end, pixels, g))
        parts = [stratified_steps(start, end, self.samples, g) for _ in range(self.groups)]
        return start, end, pixels, torch.cat(parts, dim=1)

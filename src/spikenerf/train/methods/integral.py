"""``spike-integral`` (ours, train's default): windows of spike counts against the mean of renders at each
step's own pose (docs/spike-integral.md), and its window and track defaults."""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import numpy as np
import torch
from torch import Tensor

from spikenerf.core.color import srgb_mse
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import SpikeDataset
from spikenerf.data.holdout import check_reach, checked
from spikenerf.data.integral import CountTargets, WindowTargetSampler, count_targets
from spikenerf.data.rays import pixel_rays
from spikenerf.data.targets import load_stream, stream_targets
from spikenerf.scenes.projection import image_motion
from spikenerf.train.losses import window_mean_loss
from spikenerf.train.methods.base import Config, StepLosses, Term, TrainMethod, TrainState
from spikenerf.train.pose_refine import PoseLearner
from spikenerf.train.sensor_response import SensorLearner
from spikenerf.train.settings import (
    INTEGRAL_SAMPLES,
    INTEGRAL_SHORTEST,
    INTEGRAL_SPAN_PX,
    INTEGRAL_WINDOW,
    INTEGRAL_WINDOWS,
    TRACK_HALF,
)

#: a spike-aligned window (``integral.align``) spans at most this many times the longest window length
ALIGN_LONGEST = 8


def default_window(motion: float, samples: int = 1) -> int:
    """spike-integral's window length when none is given: :data:`INTEGRAL_WINDOW` steps, shortened so that
    the image moves at most :data:`INTEGRAL_SPAN_PX` pixels in it, to no fewer than
    :data:`INTEGRAL_SHORTEST` steps nor fewer than ``samples`` (the renders a window needs).

    Args:
        motion: pixels the image moves a step (``scenes.projection.image_motion``); NaN or ≤ 0: unknown,
            the longest window.
        samples: ``integral.samples``, the renders drawn in each window (the window is never shorter).
    """
    length = INTEGRAL_WINDOW
    if math.isfinite(motion) and motion > 0:
        length = min(INTEGRAL_WINDOW, max(INTEGRAL_SHORTEST, math.floor(INTEGRAL_SPAN_PX / motion)))
    return max(length, samples)


def default_track(motion: float, samples: int = 1, groups: int = 1) -> int:
    """spike-integral's ``integral.track`` when none is given: :data:`TRACK_HALF` where the image moves so
    fast that :func:`default_window` is shorter than :data:`INTEGRAL_WINDOW` (over
    ``INTEGRAL_SPAN_PX / INTEGRAL_WINDOW`` pixels a step: 0.3), else 0; also 0 with more than one render a
    window (``samples``, ``groups``), which tracks do not support."""
    shortened = default_window(motion) < INTEGRAL_WINDOW
    return TRACK_HALF if shortened and samples == 1 and groups == 1 else 0


class SpikeIntegral(TrainMethod):
    """Spike-integral (ours, not in the paper): every target is a window's spike-count mean ``φ N / L``, read
    from the stream's prefix counts for any window, and compared with the mean of renders at steps drawn
    inside that window, each at its own pose (``integral`` config; docs/spike-integral.md). No
    reconstruction and no mask: a window without spikes has target 0."""

    name, uses_stream = "spike-integral", True
    #: targets.recon: only "tfp" (checked); targets.window_poses: eval's TFP keyframes (its window_poses())
    reads = ("targets.recon", "targets.window_poses", "integral.")
    scores_with = ("targets.window_poses",)  # eval's renders per TFP keyframe; its windows have their own
    default_batch = INTEGRAL_WINDOWS * INTEGRAL_SAMPLES
    learner_key = "sensor_response"  # integral.pixel_gain's map

    @classmethod
    def check(cls, config: Config) -> None:
        rays = config.integral.samples * config.integral.groups
        if config.rays_per_step() < rays:
            raise InputError(
                f"batch: {config.rays_per_step()} rays a step cannot render one window of {rays} steps "
                "(integral.samples × integral.groups)",
                param=("batch", "integral.samples"),
            )
        if config.targets.recon != "tfp":
            raise InputError(
                f"targets.recon {config.targets.recon!r}: spike-integral reads spike counts, not "
                "reconstructed images (use nerf-recon or spike-nerf for reconstruction targets)",
                param="targets.recon",
            )

    def settings(self) -> list[str]:
        c = self.config.integral
        lengths = "from the dataset" if c.lengths is None else "/".join(map(str, c.lengths)) + " steps"
        out = [f"windows {lengths}, {c.samples} render{'s' if c.samples > 1 else ''} each"]
        if c.track is None:
            out.append("track from the dataset")
        elif c.track:
            late = " (after the run's end)" if c.track_after >= self.config.iters else ""
            out.append(f"track windows of {2 * c.track + 1} steps from iteration {c.track_after}{late}")
        else:
            out.append("no track")
        if c.prior != "none":
            out.append(f"prior {c.prior} (weight {c.prior_weight:g})")
        if c.pixel_gain:
            rate = f"L2 weight {c.pixel_gain_weight:g}, rate {c.pixel_gain_lr:g}"
            out.append(f"learned per-pixel response ({rate})")
        out += [text for on, text in (
            (c.groups > 1, f"{c.groups} estimates a window (product form)"), (c.band, "noise band"),
            (c.weight == "srgb", "errors weighted by the sRGB slope"),
            (c.align, "spike-aligned windows"),
            (c.interpolate, f"interpolated counts (span {c.interpolate_span or 'any'})"),
        ) if on]  # fmt: skip
        return out

    @classmethod
    def for_dataset(cls, config: Config, dataset: SpikeDataset) -> Config:
        """The window length and the track, where none is given: :func:`default_window` and
        :func:`default_track` of the dataset's image motion."""
        c = config.integral
        if c.lengths is not None and c.track is not None:
            return config
        motion = image_motion(dataset.trajectory.poses, dataset.intrinsics, dataset.scene_box)
        integral = dataclasses.replace(
            c,
            lengths=[default_window(motion, c.samples)] if c.lengths is None else c.lengths,
            track=default_track(motion, c.samples, c.groups) if c.track is None else c.track,
        )
        return dataclasses.replace(config, integral=integral)

    def __init__(self, config: Config) -> None:
        super().__init__(config)
        self.counts: CountTargets | None = None
        self.step_numbers = torch.zeros(0, dtype=torch.int64)
        self.sensor: SensorLearner | None = None  # integral.pixel_gain's map (:meth:`learner`)
        self.sensor_shape = (0, 0)  # the sensor's (H, W), set by build_targets

    def poses_per_view(self) -> int:
        return self.config.integral.samples * self.config.integral.groups

    @property
    def uses_learned(self) -> bool:
        return self.config.integral.prior == "learned"

    def guard(self) -> int:
        """e, the check's reach, alone (the learned prior's image targets need :func:`guard_radius`'s
        a + e): a count window that overlaps a band is never drawn and a track skips the bands' steps, so
        no spike training reads lies within e of a check step (interpolated phases and aligned windows,
        which read past a window, are refused with the hold-out)."""
        if self.uses_learned:
            return super().guard()
        t = self.config.targets
        return check_reach(t.window, t.mask_n, self.config.spike.window)

    def build_targets(self, dataset: SpikeDataset) -> None:
        stream = load_stream(dataset, self.config.color)
        if self.uses_learned:  # the image prior: the learned reconstruction of every step, at its pose
            t = self.config.targets
            self.targets = stream_targets(dataset, self.config.color, "learned", t.window, False, t.mask_n,
                                          stream, 1)  # fmt: skip
        c = self.config.integral
        self.counts = count_targets(
            stream, dataset.trajectory.poses, dataset.threshold, c.interpolate, c.interpolate_span
        )
        self.step_numbers = torch.as_tensor(np.asarray(dataset.trajectory.steps))  # what the refiner takes
        self.sensor_shape = (dataset.intrinsics.height, dataset.intrinsics.width)
        longest = max(self.config.integral.lengths)
        if longest > self.counts.steps:
            raise InputError(
                f"integral.lengths: a {longest}-step window exceeds the {self.counts.steps} recorded steps",
                param="integral.lengths",
            )

    def make_samplers(self, height: int, width: int) -> dict[str, Any]:
        assert self.counts is not None, "build_targets first"
        c = self.config.integral
        starts = None
        if self.holdout is not None:
            starts = {n: self.holdout.window_starts(n) for n in set(c.lengths)}
            for n, allowed in starts.items():
                checked(self.holdout, len(allowed), f"{n}-step window")
        if c.interpolate and self.holdout is not None:
            raise InputError(
                "integral.interpolate: a phase reads the spikes around its step, held-out ones too: it "
                "cannot train with holdout",
                param=("integral.interpolate", "holdout"),
            )
        if c.track and self.holdout is not None:  # tracks skip the held-out bands' spikes
            usable = torch.as_tensor(~self.holdout.band())
            self.counts = dataclasses.replace(self.counts, usable=usable.to(self.counts.counts.device))
        aligner = None
        if c.align:
            if self.holdout is not None:
                raise InputError(
                    "integral.align: spike-aligned windows can reach into held-out steps: it cannot train "
                    "with holdout",
                    param=("integral.align", "holdout"),
                )
            aligner = functools.partial(self.counts.align, longest=ALIGN_LONGEST * max(c.lengths))
        sampler = WindowTargetSampler(self.counts.steps, height, width, c.lengths, c.samples, c.groups,
                                      self.config.seed, starts, aligner)  # fmt: skip
        samplers: dict[str, Any] = {"windows": sampler}
        if self.uses_learned:  # the prior's pixels: their own seeded stream
            samplers["rays"] = self.ray_sampler(height, width, self.config.seed + 2)
        return samplers

    def learner(self, device: torch.device) -> PoseLearner | None:
        """With ``integral.pixel_gain``: the per-pixel response map (C, H, W) and its own optimiser
        (:class:`SensorLearner`); None without it."""
        c = self.config.integral
        if not c.pixel_gain:
            return None
        assert self.sensor_shape[0] > 0, "build_targets first"
        height, width = self.sensor_shape
        self.sensor = SensorLearner(self.channels, height, width, c.pixel_gain_lr, self.config.iters, device)
        return self.sensor

    def draw(self, state: TrainState) -> tuple[Tensor, ...]:
        """The step's windows: start, end (B,), pixels (B, 2) and steps (B, G·S), drawn on the host
        (:class:`WindowTargetSampler`; ``integral.align`` reads the counts, a sync where a GPU keeps them)."""
        per = self.config.integral.samples * self.config.integral.groups
        return state.samplers["windows"].sample(max(1, state.config.rays_per_step() // per))

    def step_losses(self, state: TrainState, iteration: int, drawn: tuple[Tensor, ...]) -> StepLosses:
        integral = self.integral_term(state, drawn, iteration)
        terms = {"recon": integral.loss, "reg": state.model.regularization(iteration)}
        step = StepLosses(terms, integral.srgb_mse, integral.rays, dropped=integral.dropped)
        if self.sensor is not None:  # the map's L2 prior (its mean is held at 0 by construction)
            terms["sensor"] = self.sensor.response.penalty()
            step.weights["sensor"] = self.config.integral.pixel_gain_weight
        return step

    def losses(self, state: TrainState, iteration: int) -> StepLosses:
        step = super().losses(state, iteration)
        c = self.config.integral
        if self.uses_learned:
            prior = self.recon_term(state, c.prior_rays, views=1)
            step.terms["prior"], step.weights["prior"] = prior.loss, self.prior_weight(iteration)
            step.rays += prior.rays
        return step

    def prior_weight(self, iteration: int) -> float:
        """The learned prior's weight at ``iteration`` (``integral.prior_weight``, falling linearly to 0 at
        the last iteration with ``integral.prior_decay``)."""
        c = self.config.integral
        if not c.prior_decay:
            return c.prior_weight
        return c.prior_weight * max(0.0, 1.0 - iteration / max(1, self.config.iters - 1))

    def integral_term(
        self, state: TrainState, drawn: tuple[Tensor, ...] | None = None, iteration: int | None = None
    ) -> Term:
        """The window-mean loss of one batch (``drawn`` by :meth:`draw`; None: draw it); the :class:`Term`'s
        sRGB MSE is that of the window mean estimates. With ``integral.track`` from iteration
        ``integral.track_after`` on: :meth:`track_term`."""
        counts, c = self.counts, self.config.integral
        assert counts is not None, "build_targets first"
        per = c.samples * c.groups
        start, end, pixels, steps = self.draw(state) if drawn is None else drawn
        if c.track and iteration is not None and iteration >= c.track_after:
            return self.track_term(state, pixels, steps[:, 0])
        target = counts.window_mean(start, end, pixels).to(state.device)
        band = (counts.threshold / (end - start).float())[:, None].to(state.device) if c.band else None
        poses = counts.poses[steps.reshape(-1).to(counts.poses.device)].to(state.device)
        if state.pose_refine is not None:
            poses = state.pose_refine(poses, self.step_numbers[steps.reshape(-1)])
        out = state.render_rays(poses, pixels.repeat_interleave(per, dim=0))
        shape = (-1, c.groups, c.samples, self.channels)
        means = self.sensed(out.color.view(shape), pixels.to(state.device), counts.threshold)
        loss = window_mean_loss(means, target, band, c.weight)
        if out.coarse_color is not None:
            loss = loss + window_mean_loss(
                self.sensed(out.coarse_color.view(shape), pixels.to(state.device), counts.threshold),
                target,
                band,
                c.weight,
            )
        with torch.no_grad():
            mse = srgb_mse(means.mean(dim=1), target)
        return Term(loss, mse, poses.shape[0], out.dropped_samples)

    def sensed(self, colors: Tensor, pixels: Tensor, threshold: float) -> Tensor:
        """Window means (B, G, C) the counting pixels would report for the renders ``colors`` (B, G, S, C)
        at ``pixels`` (B, 2): their mean over the S samples, unchanged without ``integral.pixel_gain``. With
        it, each render is scaled by its pixel's learned response and clipped at φ (``threshold``), the
        most a pixel reports in a step (one spike), before the mean: a pixel of response above 1 that sees
        white fires every step, and its count says only that its light reached φ. The camera keeps the
        charge over φ in the pixel's accumulator, which fires it once the light drops (brighter counts
        after a saturated stretch); the cut does not model that, nor does it apply to the track terms."""
        if self.sensor is None:
            return colors.mean(dim=2)
        gain = self.sensor.response.factor(pixels)[:, None, None]  # (B, 1, 1, C)
        return (colors * gain).clamp(max=threshold).mean(dim=2)

    def track_term(self, state: TrainState, pixels: Tensor, steps: Tensor) -> Term:
        """The loss of one render per target, at pixels (B, 2) of steps (B,), against the spike counts along
        the image track of the rendered point (its depth detached; :meth:`CountTargets.track_mean` over
        ``2 · integral.track + 1`` steps): a long window without the image motion's blur."""
        counts, c = self.counts, self.config.integral
        assert counts is not None, "build_targets first"
        poses = counts.poses[steps.to(counts.poses.device)].to(state.device)
        if state.pose_refine is not None:
            poses = state.pose_refine(poses, self.step_numbers[steps])
        pixels = pixels.to(state.device)
        out = state.render_rays(poses, pixels)
        with torch.no_grad():
            origins, dirs = pixel_rays(poses, state.dataset.intrinsics, pixels)
            points = origins + out.depth.detach()[:, None] * dirs
            track = None  # the recorded poses; refined ones where the run refines them, as rendered
            if state.pose_refine is not None:  # (the track's steps on the host: the refiner reads them there)
                j = steps.cpu()[:, None] + torch.arange(-c.track, c.track + 1)[None]
                flat = j.clamp(0, counts.steps - 1).reshape(-1)
                poses_j = counts.poses[flat.to(counts.poses.device)].to(state.device)
                track = state.pose_refine(poses_j, self.step_numbers[flat]).view(*j.shape, 4, 4)
            k = state.dataset.intrinsics
            target = counts.track_mean(points, steps, c.track, k, track).to(state.device)
            # a ray that hits nothing (depth 0: no density at all) has no point to track: its pixel's own
            # spikes over the same steps (it read the camera's centre, mostly 0, before). A ray through
            # faint density keeps its track from its depth (Σ wᵢ tᵢ / Σ wᵢ): counting it as background
            # below opacity 0.5 lost 0.7 dB at 400×400 (docs/spike-integral.md)
            own = counts.still_mean(pixels, steps, c.track).to(state.device)
            target = torch.where(out.depth.detach()[:, None] > 0, target, own)
        loss = window_mean_loss(out.color[:, None], target, None, c.weight)
        if out.coarse_color is not None:
            loss = loss + window_mean_loss(out.coarse_color[:, None], target, None, c.weight)
        with torch.no_grad():
            mse = srgb_mse(out.color, target)
        return Term(loss, mse, poses.shape[0], out.dropped_samples)

"""``nerf-recon`` (NeRF on the reconstructions of every step) and ``spike-nerf`` (the paper: masked
reconstructions plus the spike loss)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from spikenerf.camera.reconstruct import WINDOWLESS
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import SpikeDataset
from spikenerf.data.holdout import checked
from spikenerf.data.samplers import WindowSampler
from spikenerf.data.targets import ImageTargets, build_spike_targets, load_stream, stream_targets
from spikenerf.render.spiking import render_spike_window
from spikenerf.train.losses import paper_spike_loss, spike_interval_loss, spike_weight
from spikenerf.train.methods.base import StepLosses, TrainMethod, TrainState


class NerfRecon(TrainMethod):
    """NeRF on the reconstructions Î_k (TFP, TFI or learned) of every step, unmasked."""

    name, uses_stream = "nerf-recon", True
    reads = ("targets.recon", "targets.window_poses")
    trains_with = ("targets.window",)

    def poses_per_view(self) -> int:
        return self.config.window_poses()

    def settings(self) -> list[str]:
        t = self.config.targets
        window = "" if t.recon in WINDOWLESS else f", window {t.window}"  # (TFI, TFSTP have none)
        poses = self.poses_per_view()
        aware = f", each the mean of {poses} renders across its window" if poses > 1 else ""
        return [f"targets {t.recon}{window}{aware}"]

    def image_targets(self, dataset: SpikeDataset, stream: np.ndarray | None) -> ImageTargets:
        """``M_k ⊙ Î_k`` or ``Î_k`` at every step; with a hold-out, a TFI or TFSTP ``Î`` of the stream cut at
        the bands' edges (each stretch its own stream: no trained step's image reads a banded spike)."""
        t, held = self.config.targets, self.holdout
        cuts = held.cuts() if held is not None and held.cut else None
        return stream_targets(dataset, self.config.color, t.recon, t.window, self.uses_mask, t.mask_n,
                              stream, self.config.window_poses(), cuts)  # fmt: skip


class SpikeNeRF(NerfRecon):
    """Spike-NeRF: masked targets ``M_k ⊙ Î_k`` plus ``λ(it) · L_spike`` (both can be switched off)."""

    name, has_spike_loss = "spike-nerf", True
    reads = (*NerfRecon.reads, "targets.mask", "spike.")
    trains_with = ("targets.window", "spike.window")

    @property
    def uses_mask(self) -> bool:
        return self.config.targets.masked()

    def ablations(self) -> list[str]:
        off = (("no mask", self.uses_mask), ("no spike loss", self.uses_spike_loss))
        return [name for name, on in off if not on]

    def settings(self) -> list[str]:
        c = self.config
        out = super().settings()
        if self.uses_mask:
            out.append(f"masks: a spike in steps k-{c.targets.mask_n}..k+{c.targets.mask_n}")
        if self.uses_spike_loss:
            kind = "interval (differentiable)" if c.spike.kind == "interval" else "the paper's (no gradient)"
            out.append(
                f"spike loss {kind}, λ {c.spike.lam:g}, windows of {c.spike.window} steps × "
                f"{c.spike.pixels} pixels"
            )
        return out

    def build_targets(self, dataset: SpikeDataset) -> None:
        stream = load_stream(dataset, self.config.color)
        self.targets = self.image_targets(dataset, stream)
        if self.uses_spike_loss:
            window = self.config.spike.window
            if window > len(dataset.trajectory):
                raise InputError(
                    f"spike window {window} exceeds the {len(dataset.trajectory)} recorded steps"
                )
            self.spikes = build_spike_targets(dataset, self.config.color, stream)

    def make_samplers(self, height: int, width: int) -> dict[str, Any]:
        samplers = super().make_samplers(height, width)
        if self.spikes is not None:
            s = self.config.spike
            steps, starts = self.spikes.spikes.shape[0], None
            if self.holdout is not None:
                starts = self.holdout.window_starts(s.window)
                checked(self.holdout, len(starts), f"{s.window}-step spike window")
            seed = self.config.seed + 1
            samplers["windows"] = WindowSampler(steps, height, width, s.window, seed, s.order, starts=starts)
        return samplers

    def lam(self, iteration: int) -> float:
        s = self.config.spike
        return spike_weight(iteration, s.lam, *s.schedule(self.config.iters)) if self.uses_spike_loss else 0.0

    def losses(self, state: TrainState, iteration: int) -> StepLosses:
        lam = self.lam(iteration)
        drawn = self.draw(state)
        spike = lam > 0 and iteration % self.config.spike.every == 0
        if spike:
            drawn = (*drawn, *self.draw_window(state))
        step = self.step_losses(state, iteration, drawn)
        if spike:  # the weight stays out of the compiled step (a changing float would recompile it)
            step.weights["spike"] = lam
        return step

    @property
    def step_variants(self) -> int:
        return 2 if self.uses_spike_loss else 1  # steps with and without a spike window

    def draw_window(self, state: TrainState) -> tuple[Tensor, Tensor, Tensor]:
        """The spike term's draws, on the host (the window sampler's generator; the paper's random start
        accumulators from the global one): the window's L steps (L,) int64, its P pixels (P, 2) and their
        start accumulators (P, C), uniform in [0, φ) for the paper's loss, else 0."""
        s, spikes = self.config.spike, self.spikes
        assert spikes is not None, "build_targets first"
        start, pixels = state.samplers["windows"].sample(s.pixels)
        shape = (s.pixels, self.channels)
        a0 = torch.rand(shape) * spikes.threshold if s.kind == "paper" else torch.zeros(shape)
        return torch.arange(start, start + s.window), pixels, a0

    def step_losses(self, state: TrainState, iteration: int, drawn: tuple[Tensor, ...]) -> StepLosses:
        """:meth:`TrainMethod.step_losses` of the rays ``drawn[:2]``, and with the window's draws of
        :meth:`draw_window` after them the spike term too (a second graph when compiled: no host sync)."""
        step = super().step_losses(state, iteration, drawn[:2])
        if len(drawn) > 2:
            step.terms["spike"], rays = self.spike_term(state, *drawn[2:])
            step.rays += rays
        return step

    def spike_term(self, state: TrainState, steps: Tensor, pixels: Tensor, a0: Tensor) -> tuple[Tensor, int]:
        """Spike loss of the window of L consecutive ``steps`` (L,) for pixels (P, 2) from start accumulators
        ``a0`` (P, C) (:meth:`draw_window`) → (loss, rays rendered)."""
        s, spikes, ds = self.config.spike, self.spikes, state.dataset
        assert spikes is not None
        poses = spikes.poses.index_select(0, steps.to(spikes.poses.device))
        if state.pose_refine is not None:
            poses = state.pose_refine.window(poses, steps)
        a0 = a0.to(state.device)
        window = render_spike_window(state.model, poses, ds.intrinsics, pixels, a0, spikes.threshold,
                                     ds.near, ds.far, perturb=True)  # fmt: skip
        recorded = spikes.window(steps, pixels).to(state.device)
        if s.kind == "paper":
            loss = paper_spike_loss(window.intensity, recorded, spikes.threshold, a0, s.paper_warmup)
        else:
            loss = spike_interval_loss(window.intensity, recorded, spikes.threshold, s.pairs)  # type: ignore[arg-type]
        return loss, s.window * s.pixels

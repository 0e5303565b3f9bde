"""Training methods: one :class:`TrainMethod` per ``--method``; each builds its targets and returns its named
loss terms, and the trainer sums them (compare nerfstudio's ``Model.get_loss_dict``).

Every method renders ``batch`` random rays against its image targets (``recon``, linear MSE; images posed
at S > 1 poses are rendered at each and averaged first) and adds the field's prior (``reg``). Spike-NeRF adds,
once its λ(it) > 0, one window of L consecutive steps for P pixels (``spike``, weighted by λ). The terms keep
these names in ``curves.csv`` and TensorBoard (``loss/recon``, ``loss/spike``, ``loss/reg``).

=================  ==============================================  ==================================
method             targets (``spikenerf.data.targets``)             loss terms
=================  ==============================================  ==================================
nerf-gt            sharp GT renders (``gt_targets``)               recon, reg
nerf-blur          blur views at mid-exposure (``blur_targets``)   recon, reg
nerf-blur-aware    blur views at ``blur_samples`` exposure poses   recon (exposure-averaged), reg
nerf-bad           blur views at learned exposure start/end poses  recon (exposure-averaged), reg
nerf-recon         Î_k at every step (``stream_targets``)          recon, reg
spike-nerf         M_k ⊙ Î_k at every step + the recorded stream   recon, reg, λ(it) · spike
spike-integral     spike counts of L-step windows (``integral``)   recon (S steps per window), reg
=================  ==============================================  ==================================

With ``targets.window_poses`` S > 1 (the default for TFP targets: 4), nerf-recon and spike-nerf render each
TFP target at S poses spread over its window and average them (window-aware targets; S = 1 is the paper's).

**One registry.** A method is its class: its ``name`` (the ``--method`` value, one of the
``spikenerf.data.targets.Method`` Literal), its facts (``views``, ``uses_stream``, ``has_spike_loss``,
``default_batch``, ``learns_poses``) and its own config rules (:meth:`TrainMethod.check`, which
``TrainConfig.validate`` calls), listed once in :data:`METHOD_CLASSES`; ``TrainConfig``, the CLI's
``--method`` choices, :func:`make_method` and the benchmark read that table. Adding a method is a class
here, its entry in :data:`METHOD_CLASSES` and its name in the ``Method`` Literal (docs/architecture.md).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple, Protocol

import numpy as np
import torch
from torch import Tensor

from spikenerf.core.color import srgb_mse
from spikenerf.core.errors import InputError, check_choice
from spikenerf.data.dataset import SpikeDataset
from spikenerf.data.holdout import Holdout, checked, guard_radius, make_holdout
from spikenerf.data.integral import CountTargets, WindowTargetSampler, count_targets
from spikenerf.data.rays import pixel_rays
from spikenerf.data.samplers import RaySampler, WindowSampler
from spikenerf.data.targets import (
    ImageTargets,
    SpikeTargets,
    blur_targets,
    build_spike_targets,
    gt_targets,
    load_stream,
    stream_targets,
)
from spikenerf.render.base import RadianceModel
from spikenerf.render.spiking import render_spike_window
from spikenerf.render.volume import RenderOutput
from spikenerf.scenes.trajectory import image_motion
from spikenerf.train.exposure_poses import ExposureLearner
from spikenerf.train.losses import (
    paper_spike_loss,
    recon_loss,
    spike_interval_loss,
    spike_weight,
    window_mean_loss,
)
from spikenerf.train.pose_refine import PoseLearner, PoseRefinement
from spikenerf.train.settings import (
    DEFAULT_BATCH as DEFAULT_BATCH,
)
from spikenerf.train.settings import (
    GPU_BATCH_SCALE as GPU_BATCH_SCALE,
)
from spikenerf.train.settings import (
    INTEGRAL_SAMPLES as INTEGRAL_SAMPLES,
)
from spikenerf.train.settings import (
    INTEGRAL_SHORTEST as INTEGRAL_SHORTEST,
)
from spikenerf.train.settings import (
    INTEGRAL_SPAN_PX as INTEGRAL_SPAN_PX,
)
from spikenerf.train.settings import (
    INTEGRAL_WINDOW as INTEGRAL_WINDOW,
)
from spikenerf.train.settings import (
    INTEGRAL_WINDOWS as INTEGRAL_WINDOWS,
)
from spikenerf.train.settings import (
    TRACK_HALF as TRACK_HALF,
)

#: a :class:`spikenerf.train.config.TrainConfig` (not imported: config.py reads :data:`METHOD_CLASSES`)
Config = Any

#: config keys that only some methods read (a key ending in "." stands for its section): each method lists
#: those it reads in :attr:`TrainMethod.reads`, and :func:`unused_keys` names the others (``train`` warns of
#: a given one). ``spike.window`` and ``targets.mask_n`` are not among them: every method's hold-out guard
#: band reads them; nor, in :data:`SHARED_KEYS`, ``targets.recon``, the target of eval's no-reference checks.
METHOD_KEYS = (
    "targets.recon",
    "targets.mask",
    "targets.window_poses",
    "targets.blur_samples",
    "spike.",
    "integral.",
    "exposure.",
)
SHARED_KEYS = ("spike.window", "targets.recon")
#: the window lengths every run records for eval's no-reference checks and the hold-out guard band, and that
#: only some methods also train with (:attr:`TrainMethod.trains_with`)
WINDOW_KEYS = ("targets.window", "spike.window")

#: a spike-aligned window (``integral.align``) spans at most this many times the longest window length
ALIGN_LONGEST = 8


def default_window(motion: float, samples: int = 1) -> int:
    """spike-integral's window length when none is given: :data:`INTEGRAL_WINDOW` steps, shortened so that
    the image moves at most :data:`INTEGRAL_SPAN_PX` pixels in it, to no fewer than
    :data:`INTEGRAL_SHORTEST` steps nor fewer than ``samples`` (the renders a window needs).

    Args:
        motion: pixels the image moves a step (``scenes.trajectory.image_motion``); NaN or ≤ 0: unknown,
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


class TrainState(Protocol):
    """What a method reads from the trainer during a step."""

    config: Config
    dataset: SpikeDataset
    model: RadianceModel
    device: torch.device
    samplers: dict[str, Any]
    pose_refine: PoseRefinement | None  # learnable pose corrections (--refine-poses) or None

    def render_rays(self, poses: Tensor, pixels: Tensor, perturb: bool = True) -> RenderOutput: ...


@dataclass
class StepLosses:
    """One step's named loss terms (in summation order), their weights and statistics.

    Attributes:
        terms: name -> 0-d loss tensor, unweighted (what ``curves.csv`` averages).
        weights: name -> weight this step (λ(it) for ``spike``); a term without one is added as it is.
        srgb_mse: 0-d MSE of the sRGB-encoded batch (the train PSNR; no gradient, stays on the device).
        rays: rays rendered this step.
        dropped: 0-d int64 on the device: the sample slots that the grid's ``static_samples`` budget cut
            from this step's target renders (``RenderOutput.dropped_samples``); None with the packed render.
    """

    terms: dict[str, Tensor]
    srgb_mse: Tensor
    rays: int
    weights: dict[str, float] = field(default_factory=dict)
    dropped: Tensor | None = None

    def total(self) -> Tensor:
        """The loss to minimise: the sum of the weighted terms."""
        total: Tensor | None = None
        for name, term in self.terms.items():
            weighted = self.weights[name] * term if name in self.weights else term
            total = weighted if total is None else total + weighted
        assert total is not None
        return total


class Term(NamedTuple):
    """One rendered loss term of a step (:meth:`TrainMethod.recon_of`, :meth:`SpikeIntegral.integral_term`).

    Attributes:
        loss: 0-d loss tensor.
        srgb_mse: 0-d MSE of the sRGB-encoded batch (the train PSNR; no gradient, stays on the device).
        rays: rays rendered.
        dropped: the render's ``dropped_samples`` (0-d int64; None with the packed render).
    """

    loss: Tensor
    srgb_mse: Tensor
    rays: int
    dropped: Tensor | None


class TrainMethod:
    """A training method: its targets, its λ schedule and its named loss terms.

    Attributes:
        name: the ``--method`` value. views: what its targets are posed on and the benchmark counts in
            "trained on": ``steps`` (every spike step), ``gt`` (the GT renders) or ``blur`` (the blur views).
        uses_stream: its targets are made from the recorded spike stream; its images are sharp, of a TFP
            window (``TrainConfig.window_poses``: the resolved ``targets.window_poses`` applies to it).
        has_spike_loss: it adds the spike loss (unless ``spike.enabled`` switches it off).
        default_batch: rays per step when ``batch`` is not given (``TrainConfig.rays_per_step``).
        learns_poses: it learns its views' poses itself (pose refinement stays off by default).
        reads: the :data:`METHOD_KEYS` it reads (:func:`unused_keys`).
        trains_with: the :data:`WINDOW_KEYS` that shape its training (:func:`check_only_keys`); the others
            set only eval's no-reference checks and the hold-out guard band.
    """

    name: ClassVar[str]
    views: ClassVar[str] = "steps"
    uses_stream: ClassVar[bool] = False
    has_spike_loss: ClassVar[bool] = False
    default_batch: ClassVar[int] = DEFAULT_BATCH
    learns_poses: ClassVar[bool] = False
    reads: ClassVar[tuple[str, ...]] = ()
    trains_with: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def check(cls, config: Config) -> None:
        """InputError (naming the config key) on settings this method cannot train with; the last rule of
        ``TrainConfig.validate``, after the generic ones."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.channels = 1 if config.color == "gray" else 3
        self.targets: ImageTargets | None = None
        self.spikes: SpikeTargets | None = None
        self.holdout: Holdout | None = None
        self.stream_steps = np.zeros(0, dtype=np.int64)

    # ---------------------------------------------------------------------------------------------- facts
    @property
    def uses_learned(self) -> bool:
        """Its targets include the learned reconstructions of the stream (built on the training device and
        cached in the run folder)."""
        return self.uses_stream and self.config.targets.recon == "learned"

    @property
    def uses_mask(self) -> bool:
        """Its image targets are multiplied by the spike masks."""
        return False

    @property
    def uses_spike_loss(self) -> bool:
        """It adds the spike loss (:attr:`has_spike_loss`, and ``spike.enabled``)."""
        return self.has_spike_loss and self.config.spike.enabled

    def poses_per_view(self) -> int:
        """Poses rendered and averaged for each target image (S of :class:`ImageTargets`)."""
        return 1

    def describe(self) -> str:
        """``spike-nerf (no mask)``: the name and the parts the config switched off."""
        off = self.ablations()
        return self.name + (f" ({', '.join(off)})" if off else "")

    def ablations(self) -> list[str]:
        """The parts of the method the config switched off (``no mask``, ``no spike loss``)."""
        return []

    def settings(self) -> list[str]:
        """The method's key settings as ``info`` and ``train`` print them (``targets tfp, window 41``), from
        a run's recorded config, whose dataset-dependent defaults :meth:`for_dataset` filled in."""
        return []

    # ---------------------------------------------------------------------------------------------- setup
    def image_targets(self, dataset: SpikeDataset, stream: np.ndarray | None) -> ImageTargets:
        """The reconstruction-loss targets (``stream``: the recorded stream when :attr:`uses_stream`)."""
        raise NotImplementedError

    def build_targets(self, dataset: SpikeDataset) -> None:
        """Build :attr:`targets` (and the spike targets of a method with a spike loss)."""
        stream = load_stream(dataset, self.config.color) if self.uses_stream else None
        self.targets = self.image_targets(dataset, stream)

    @classmethod
    def for_dataset(cls, config: Config, dataset: SpikeDataset) -> Config:
        """``config`` with the defaults that depend on the dataset filled in (none here; a run records
        them in its ``config.yaml``)."""
        return config

    def hold_out(self, dataset: SpikeDataset) -> Holdout | None:
        """Decide the held-out check steps (``config.holdout``; None: trains on every step), which
        :meth:`make_samplers` then never draws."""
        c = self.config
        t, r = c.targets, c.holdout_radius
        radius = guard_radius(t.window, t.mask_n, c.spike.window) if r is None else r
        self.holdout = make_holdout(dataset, c.holdout, c.holdout_steps, radius)
        self.stream_steps = np.asarray(dataset.trajectory.steps)
        return self.holdout

    def make_samplers(self, height: int, width: int) -> dict[str, Any]:
        """The seeded samplers of its steps, by name (their states are checkpointed under these names)."""
        return {"rays": self.ray_sampler(height, width, self.config.seed)}

    def ray_sampler(self, height: int, width: int, seed: int) -> RaySampler:
        """Random rays over the image targets, held-out steps excluded."""
        assert self.targets is not None, "build_targets first"
        images = None
        if self.holdout is not None:
            images = self.holdout.image_indices(self.targets.steps, self.stream_steps)
            checked(self.holdout, len(images), "image target")
        return RaySampler(len(self.targets), height, width, seed, images)

    def learner(self, device: torch.device) -> PoseLearner | None:
        """Pose parameters the method learns with its own optimiser (None: none); call after
        :meth:`build_targets`. The trainer steps and checkpoints it under ``exposure_poses``."""
        return None

    # ---------------------------------------------------------------------------------------------- steps
    def lam(self, iteration: int) -> float:
        """λ of the spike loss at ``iteration`` (0 for a method without one)."""
        return 0.0

    def losses(self, state: TrainState, iteration: int) -> StepLosses:
        """The loss terms of one step: ``recon`` and ``reg`` (subclasses add theirs); :meth:`draw` on the
        host, then :meth:`step_losses`."""
        return self.step_losses(state, iteration, self.draw(state))

    @property
    def step_variants(self) -> int:
        """How many kinds of step :meth:`step_losses` takes (each its own compiled graph)."""
        return 1

    def draw(self, state: TrainState) -> tuple[Tensor, ...]:
        """The step's random draws for :meth:`step_losses`, made on the host by the samplers' own generators
        (no device value is read): the rays' image indices (B,) and pixels (B, 2)."""
        return self.draw_rays(state)

    def step_losses(self, state: TrainState, iteration: int, drawn: tuple[Tensor, ...]) -> StepLosses:
        """The device part of :meth:`losses` for the draws ``drawn`` of :meth:`draw`: with a grid field's
        ``static_samples`` it traces as one graph, with no host sync (tests/test_step_graph.py)."""
        recon = self.recon_of(state, *drawn)
        terms = {"recon": recon.loss, "reg": state.model.regularization(iteration)}
        return StepLosses(terms, recon.srgb_mse, recon.rays, dropped=recon.dropped)

    def draw_rays(
        self, state: TrainState, rays: int | None = None, views: int | None = None
    ) -> tuple[Tensor, Tensor]:
        """Image indices (B,) and pixels (B, 2) of ``rays`` (None: the step's) rays rendered at ``views``
        poses per target (None: :meth:`poses_per_view`): B = rays // views targets."""
        views = self.poses_per_view() if views is None else views
        rays = state.config.rays_per_step() if rays is None else rays
        return state.samplers["rays"].sample(max(1, rays // views))

    def recon_term(self, state: TrainState, rays: int | None = None, views: int | None = None) -> Term:
        """Reconstruction loss of one random batch of ``rays`` (None: the step's), ``views`` poses per target
        (None: :meth:`poses_per_view`); the :class:`Term`'s tensors stay on the device (no sync)."""
        return self.recon_of(state, *self.draw_rays(state, rays, views), views)

    def recon_of(self, state: TrainState, index: Tensor, pixels: Tensor, views: int | None = None) -> Term:
        """:meth:`recon_term` of the drawn targets ``index`` (B,) at ``pixels`` (B, 2)."""
        targets = self.targets
        assert targets is not None, "build_targets first"
        views, channels = self.poses_per_view() if views is None else views, self.channels
        target = targets.gather(index, pixels).to(state.device)
        poses = self.image_poses(state, index)  # (B·S, 4, 4), S poses averaged per ray
        out = state.render_rays(poses, pixels.repeat_interleave(views, dim=0))
        color = out.color.view(-1, views, channels).mean(dim=1)
        loss = recon_loss(color, target)
        if out.coarse_color is not None:
            loss = loss + recon_loss(out.coarse_color.view(-1, views, channels).mean(dim=1), target)
        with torch.no_grad():
            mse = srgb_mse(color, target)
        return Term(loss, mse, poses.shape[0], out.dropped_samples)

    def image_poses(self, state: TrainState, index: Tensor) -> Tensor:
        """Poses (B·S, 4, 4) of image targets ``index`` (B,): their S poses each, refined when
        ``--refine-poses`` is on."""
        assert self.targets is not None, "build_targets first"
        poses = self.targets.poses[index].reshape(-1, 4, 4)
        if state.pose_refine is not None:
            poses = state.pose_refine.images(self.targets, index, poses)
        return poses


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


class NerfRecon(TrainMethod):
    """NeRF on the reconstructions Î_k (TFP, TFI or learned) of every step, unmasked."""

    name, uses_stream = "nerf-recon", True
    reads = ("targets.recon", "targets.window_poses")
    trains_with = ("targets.window",)

    def poses_per_view(self) -> int:
        return self.config.window_poses()

    def settings(self) -> list[str]:
        t = self.config.targets
        window = "" if t.recon == "tfi" else f", window {t.window}"  # (TFI has none)
        poses = self.poses_per_view()
        aware = f", each the mean of {poses} renders across its window" if poses > 1 else ""
        return [f"targets {t.recon}{window}{aware}"]

    def image_targets(self, dataset: SpikeDataset, stream: np.ndarray | None) -> ImageTargets:
        t = self.config.targets
        return stream_targets(dataset, self.config.color, t.recon, t.window, self.uses_mask, t.mask_n,
                              stream, self.config.window_poses())  # fmt: skip


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


class SpikeIntegral(TrainMethod):
    """Spike-integral (ours, not in the paper): every target is a window's spike-count mean ``φ N / L``, read
    from the stream's prefix counts for any window, and compared with the mean of renders at steps drawn
    inside that window, each at its own pose (``integral`` config; docs/spike-integral.md). No
    reconstruction and no mask: a window without spikes has target 0."""

    name, uses_stream = "spike-integral", True
    #: targets.recon: only "tfp" (checked); targets.window_poses: eval's TFP keyframes (its window_poses())
    reads = ("targets.recon", "targets.window_poses", "integral.")
    default_batch = INTEGRAL_WINDOWS * INTEGRAL_SAMPLES

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
        out += [text for on, text in (
            (c.groups > 1, f"{c.groups} estimates a window (product form)"), (c.band, "noise band"),
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

    def poses_per_view(self) -> int:
        return self.config.integral.samples * self.config.integral.groups

    @property
    def uses_learned(self) -> bool:
        return self.config.integral.prior == "learned"

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

    def draw(self, state: TrainState) -> tuple[Tensor, ...]:
        """The step's windows: start, end (B,), pixels (B, 2) and steps (B, G·S), drawn on the host
        (:class:`WindowTargetSampler`; ``integral.align`` reads the counts, a sync where a GPU keeps them)."""
        per = self.config.integral.samples * self.config.integral.groups
        return state.samplers["windows"].sample(max(1, state.config.rays_per_step() // per))

    def step_losses(self, state: TrainState, iteration: int, drawn: tuple[Tensor, ...]) -> StepLosses:
        integral = self.integral_term(state, drawn, iteration)
        terms = {"recon": integral.loss, "reg": state.model.regularization(iteration)}
        return StepLosses(terms, integral.srgb_mse, integral.rays, dropped=integral.dropped)

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
        means = out.color.view(shape).mean(dim=2)
        loss = window_mean_loss(means, target, band)
        if out.coarse_color is not None:
            loss = loss + window_mean_loss(out.coarse_color.view(shape).mean(dim=2), target, band)
        with torch.no_grad():
            mse = srgb_mse(means.mean(dim=1), target)
        return Term(loss, mse, poses.shape[0], out.dropped_samples)

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
            target = counts.track_mean(points, steps, c.track, state.dataset.intrinsics).to(state.device)
            # a ray that hits nothing (depth 0: the white background) has no point to track: its pixel's
            # own spikes over the same steps (it read the camera's centre, mostly 0, before)
            own = counts.still_mean(pixels, steps, c.track).to(state.device)
            target = torch.where(out.depth.detach()[:, None] > 0, target, own)
        loss = window_mean_loss(out.color[:, None], target, None)
        if out.coarse_color is not None:
            loss = loss + window_mean_loss(out.coarse_color[:, None], target, None)
        with torch.no_grad():
            mse = srgb_mse(out.color, target)
        return Term(loss, mse, poses.shape[0], out.dropped_samples)


#: ``--method`` -> its class: the one table of training methods, in the order of the ``Method`` Literal of
#: ``spikenerf.data.targets`` (its names; tests/test_methods.py checks that each has exactly one entry)
METHOD_CLASSES: dict[str, type[TrainMethod]] = {
    cls.name: cls for cls in (SpikeIntegral, SpikeNeRF, NerfRecon, NerfBlur, NerfBlurAware, NerfBAD, NerfGT)
}


def method_class(name: str) -> type[TrainMethod]:
    """The :class:`TrainMethod` class of ``name`` (InputError naming ``method`` for an unknown one)."""
    check_choice(name, METHOD_CLASSES, "method")
    return METHOD_CLASSES[name]


def unused_keys(method: str, keys: Iterable[str]) -> list[str]:
    """The config ``keys`` (dotted, e.g. ``spike.lam``) that ``method`` does not read: those of
    :data:`METHOD_KEYS` outside its :attr:`TrainMethod.reads`, in the given order."""

    def among(key: str, patterns: Iterable[str]) -> bool:
        return any(key == p or (p.endswith(".") and key.startswith(p)) for p in patterns)

    reads = method_class(method).reads
    return [k for k in keys if among(k, METHOD_KEYS) and not among(k, (*reads, *SHARED_KEYS))]


def check_only_keys(method: str, keys: Iterable[str]) -> list[str]:
    """The keys among ``keys`` that do not change how ``method`` trains, in the given order: the
    :data:`WINDOW_KEYS` it does not train with (they still set eval's no-reference checks and the hold-out
    guard band), and ``targets.recon`` where it does not read it (it still sets the reconstruction that
    eval's no-reference checks compare renders with)."""
    cls = method_class(method)
    return [
        k
        for k in keys
        if (k in WINDOW_KEYS and k not in cls.trains_with) or (k == "targets.recon" and k not in cls.reads)
    ]


def make_method(config: Config) -> TrainMethod:
    """The :class:`TrainMethod` of ``config.method`` (InputError for an unknown one)."""
    return method_class(config.method)(config)

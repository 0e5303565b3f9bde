"""The base of every training method: :class:`TrainMethod` (its targets, samplers and loss terms), the
step's :class:`StepLosses` and the config keys that only some methods read."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple, Protocol

import numpy as np
import torch
from torch import Tensor

from spikenerf.core.color import srgb_mse
from spikenerf.data.dataset import SpikeDataset
from spikenerf.data.holdout import Holdout, check_reach, checked, guard_radius, make_holdout
from spikenerf.data.samplers import RaySampler
from spikenerf.data.targets import ImageTargets, SpikeTargets, load_stream
from spikenerf.render.base import RadianceModel
from spikenerf.render.volume import RenderOutput
from spikenerf.train.losses import recon_loss
from spikenerf.train.pose_refine import PoseLearner, PoseRefinement
from spikenerf.train.settings import DEFAULT_BATCH

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
        scores_with: keys of :attr:`reads` that set only how ``eval`` scores its renders, not its training
            (:func:`check_only_keys`; spike-integral's ``targets.window_poses``).
        learner_key: the checkpoint key of its :meth:`learner`'s state.
    """

    name: ClassVar[str]
    views: ClassVar[str] = "steps"
    uses_stream: ClassVar[bool] = False
    has_spike_loss: ClassVar[bool] = False
    default_batch: ClassVar[int] = DEFAULT_BATCH
    learns_poses: ClassVar[bool] = False
    reads: ClassVar[tuple[str, ...]] = ()
    trains_with: ClassVar[tuple[str, ...]] = ()
    scores_with: ClassVar[tuple[str, ...]] = ()
    learner_key: ClassVar[str] = "exposure_poses"

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

    def guard(self) -> int:
        """The default guard band half-width r (``holdout_radius`` None): :func:`guard_radius`, the reach
        of an image target plus the check's."""
        t = self.config.targets
        return guard_radius(t.window, t.mask_n, self.config.spike.window)

    def hold_out(
        self, dataset: SpikeDataset, whole: bool = False, began: int | None = None
    ) -> Holdout | None:
        """Decide the held-out check steps (``config.holdout``; None: trains on every step), which
        :meth:`make_samplers` then never draws; call before :meth:`build_targets` (TFI and TFSTP targets
        are cut at the bands' edges, ``Holdout.cuts``, unless ``whole``: a resumed run that began with
        targets of the whole stream). The band half-width is ``holdout_radius``, else ``began`` (a resumed
        run's recorded one), else :meth:`guard`."""
        c = self.config
        t, r = c.targets, c.holdout_radius
        radius = r if r is not None else began if began is not None else self.guard()
        reach = check_reach(t.window, t.mask_n, c.spike.window)
        self.holdout = make_holdout(dataset, c.holdout, c.holdout_steps, radius, t.recon, reach, whole)
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
        """Parameters the method learns with their own optimiser (None: none; nerf-bad's exposure poses,
        spike-integral's sensor response); call after :meth:`build_targets`. The trainer steps it, and
        checkpoints it under :attr:`learner_key`."""
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

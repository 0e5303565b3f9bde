"""Typed training configs (saved to ``RUN/config.yaml``); what each method does with them is its class in
:mod:`spikenerf.train.methods`.

The dataclasses are the one typed source: each choice is a ``Literal`` owned by the module that implements
it (``method``: the registered methods), each range a ``BOUNDS`` entry, and ``spikenerf.core.config``
validates any value (a YAML file, ``--set key.sub=value``) against them, as it does the field configs; the
rules that join several keys are in :meth:`TrainConfig.validate` and the method's own ``check``. The
ablation flags only ever switch parts off.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal

from spikenerf.camera.reconstruct import DEFAULT_WINDOW, check_window
from spikenerf.core.config import Bound, check_config, choices, from_mapping, plain_scalars
from spikenerf.core.device import check_device_name
from spikenerf.core.errors import InputError
from spikenerf.data.choices import Method, TrainColor, WindowOrder
from spikenerf.data.reconstruction import TargetRecon
from spikenerf.fields.choices import FieldKind
from spikenerf.train.settings import (
    DEFAULT_BATCH,
    GPU_BATCH_SCALE,
    INTEGRAL_SAMPLES,
    INTEGRAL_WINDOW,
    SPIKE_LOSS_KINDS,
    AmpMode,
    ExposurePoseConfig,
    LogKind,
    LossWeight,
    PairMode,
    PoseRefineConfig,
    SpikeLossKind,
)

if TYPE_CHECKING:
    from spikenerf.train.methods import TrainMethod

#: spike-integral's optional image prior (``integral.prior``)
IntegralPrior = Literal["none", "learned"]

__all__ = [
    "DEFAULT_BATCH",
    "INTEGRAL_SAMPLES",
    "INTEGRAL_WINDOW",
    "SPIKE_LOSS_KINDS",
    "IntegralConfig",
    "SpikeLossConfig",
    "TargetConfig",
    "TrainConfig",
]


def _method_names() -> list[str]:
    """The registered methods (``spikenerf.train.methods.METHOD_CLASSES``; imported when a config is
    checked, not when this module is: ``train --help`` imports no torch)."""
    from spikenerf.train.methods import METHOD_CLASSES

    return list(METHOD_CLASSES)


#: the default poses per TFP target (window-aware targets; docs/method.md, Targets)
WINDOW_POSES = 4


@dataclass
class TargetConfig:
    """Reconstruction targets.

    Attributes:
        recon: tfp | tfi | tfstp | learned (image reconstruction of the stream). window: TFP window, frames
            (odd).
        mask: multiply by the spike masks (spike-nerf); None: on with the paper's targets (one pose per
            target), off with window-aware ones, where they gained nothing (docs/spike-integral.md, masks).
            :meth:`masked` resolves it. mask_n: mask half window n (2n+1 frames, paper: 5).
        blur_samples: poses per exposure averaged by nerf-blur-aware and nerf-bad (its virtual frames).
        window_poses: poses per TFP target of nerf-recon and spike-nerf, spread over its window and
            averaged (1: the target's own step, the paper's; S > 1: window-aware targets, recon tfp only;
            None: :data:`WINDOW_POSES` with tfp, 1 otherwise). :meth:`poses_per_target` resolves it.
    """

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "mask_n": Bound(least=1), "blur_samples": Bound(least=1), "window_poses": Bound(least=1),
    }  # fmt: skip

    recon: TargetRecon = "tfp"
    window: int = DEFAULT_WINDOW
    mask: bool | None = None
    mask_n: int = 5
    blur_samples: int = 8
    window_poses: int | None = None

    def poses_per_target(self) -> int:
        """``window_poses`` resolved: :data:`WINDOW_POSES` for TFP targets when unset, else 1."""
        if self.window_poses is None:
            return WINDOW_POSES if self.recon == "tfp" else 1
        return self.window_poses

    def masked(self) -> bool:
        """``mask`` resolved: when unset, on for one pose per target (the paper's), off for window-aware
        targets."""
        return self.mask if self.mask is not None else self.poses_per_target() == 1


@dataclass
class IntegralConfig:
    """spike-integral: each target is a window's spike-count mean ``φ N / L``, compared with the mean of
    renders at steps drawn inside the window at their own poses (docs/spike-integral.md).

    Attributes:
        lengths: window lengths L in steps; each target draws one uniformly. None (the default): one
            length from the dataset, ``INTEGRAL_WINDOW`` steps shortened to span at most
            ``INTEGRAL_SPAN_PX`` pixels of image motion (``train.methods.default_window``), recorded
            resolved in the run's config.yaml.
        samples: S steps rendered per estimate of a window's mean render (stratified over the window).
        groups: G independent estimates per window: 1 squared error; ≥ 2 the unbiased product form.
        band: count errors within the interval ``± φ / L`` of a noise-free pixel as 0.
        weight: ``linear`` (the default): every ray's squared error alike, in linear intensity; ``srgb``:
            each weighted by the squared sRGB slope at its detached render, normalised to mean 1, as test
            PSNR weighs it (``train.losses.srgb_weights``; the windows' terms and the tracks').
        align: move each window onto spikes of its pixel (``CountTargets.align``: exact to the pixel's own
            light, not to ``± φ / L``), up to ``ALIGN_LONGEST`` times the longest length; needs holdout off.
        interpolate: add to each count the fraction of the next spike's light gathered by then, taken
            linearly between the pixel's spikes (``data.integral.count_phases``): sub-count targets;
            needs holdout off. interpolate_span: interpolate only between spikes at most this many steps
            apart (0: any), plain counts elsewhere; needs ``interpolate``.
        track: h > 0: from iteration ``track_after`` on, compare each render with the spike counts along the
            image track of its point over the 2h + 1 steps around its step (``CountTargets.track_mean``; the
            field's depth, detached), not with its own pixel's window; 0: off. Needs ``samples`` and
            ``groups`` 1; skips held-out steps. None (the default): ``TRACK_HALF`` where the image motion
            shortens the default window, else 0 (``train.methods.default_track``), recorded resolved.
            track_after: iterations of plain windows first.
        prior: ``learned``: add a reconstruction term on the shipped network's reconstructions of every step
            (``targets.window``), at each step's pose, weighted ``prior_weight``, over ``prior_rays`` rays a
            step; ``none`` (the default): the window means alone. prior_decay: the weight falls linearly
            from ``prior_weight`` at the first iteration to 0 at the last (the counts alone finish the run).
        pixel_gain: learn a response factor per sensor pixel (its gain over its threshold; fixed-pattern
            noise) that scales each render of a window, cut at φ (one spike a step), before the window
            mean; not the track terms nor eval's renders (``train.sensor_response``; docs/camera.md); off by
            default. pixel_gain_weight: weight of its L2
            term ``mean(m²)`` on the centred log-responses m. pixel_gain_lr: its Adam rate.
    """

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "samples": Bound(least=1), "groups": Bound(least=1), "prior_weight": Bound(least=0),
        "prior_rays": Bound(least=1), "interpolate_span": Bound(least=0), "track": Bound(least=0),
        "track_after": Bound(least=0), "pixel_gain_weight": Bound(least=0), "pixel_gain_lr": Bound(above=0),
    }  # fmt: skip

    lengths: list[int] | None = None
    samples: int = INTEGRAL_SAMPLES
    groups: int = 1
    band: bool = False
    weight: LossWeight = "linear"
    align: bool = False
    interpolate: bool = False
    interpolate_span: int = 0
    track: int | None = None
    track_after: int = 400
    prior: IntegralPrior = "none"
    prior_weight: float = 1.0
    prior_rays: int = 256
    prior_decay: bool = False
    pixel_gain: bool = False
    pixel_gain_weight: float = 0.001
    pixel_gain_lr: float = 0.005

    def check(self) -> None:
        """InputError (naming ``integral.KEY``) on an empty or non-positive ``lengths``, ``samples`` < 1,
        ``groups`` < 1, more ``samples`` than the shortest window holds, or ``interpolate_span`` without
        ``interpolate``."""
        check_config(self, "integral.")
        if self.track and (self.samples != 1 or self.groups != 1):
            raise InputError(
                f"integral.track renders one step per target: set integral.samples and integral.groups to 1 "
                f"(found {self.samples} and {self.groups})",
                param=("integral.track", "integral.samples"),
            )
        if self.interpolate_span and not self.interpolate:
            raise InputError(
                "integral.interpolate_span needs integral.interpolate=true", param="integral.interpolate_span"
            )
        if self.lengths is None:  # chosen from the dataset (at least ``samples`` steps)
            return
        if not self.lengths or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1
                                       for n in self.lengths):  # fmt: skip
            raise InputError(
                f"integral.lengths must be a list of window lengths ≥ 1, found {self.lengths!r}",
                param="integral.lengths",
            )
        if self.samples > min(self.lengths):
            raise InputError(
                f"integral.samples: {self.samples} steps per window do not fit in a "
                f"{min(self.lengths)}-step window (integral.lengths)",
                param=("integral.samples", "integral.lengths"),
            )


@dataclass
class SpikeLossConfig:
    """The spike loss ``λ(it) · L_spike``.

    Attributes:
        enabled: use the spike loss (spike-nerf only). kind: ``interval`` (differentiable integral constraint)
            or ``paper`` (the paper's non-differentiable spike comparison, for comparison: no gradient).
        lam: λ after the ramp. warmup_iters: iterations with λ = 0 (no spike windows rendered).
        ramp_iters: linear ramp of λ from 0 to ``lam``. Both default (None) to a fifth of the run
        (1000 each for the default 5000 iterations), see :meth:`schedule`.
        window: L consecutive steps per window.
        pixels: pixels per window (each renders L rays). pairs: ``all`` sub-windows or the whole ``window``.
        order: ``sequential`` windows along the stream (the paper's deterministic choice) or ``random``.
        every: render a spike window every this many iterations. paper_warmup: steps the paper loss discards.
    """

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "lam": Bound(least=0), "warmup_iters": Bound(least=0), "ramp_iters": Bound(least=0),
        "window": Bound(least=1), "pixels": Bound(least=1), "every": Bound(least=1),
        "paper_warmup": Bound(least=0),
    }  # fmt: skip

    enabled: bool = True
    kind: SpikeLossKind = "interval"
    lam: float = 1.0
    warmup_iters: int | None = None
    ramp_iters: int | None = None
    window: int = 16
    pixels: int = 32
    pairs: PairMode = "all"
    order: WindowOrder = "sequential"
    every: int = 1
    paper_warmup: int = 4

    def schedule(self, iters: int) -> tuple[int, int]:
        """(warm-up, ramp) iterations for a run of ``iters``: the given values, else ``iters // 5`` each."""
        default = iters // 5
        return (
            default if self.warmup_iters is None else self.warmup_iters,
            default if self.ramp_iters is None else self.ramp_iters,
        )


@dataclass
class TrainConfig:
    """One training run.

    Attributes:
        dataset: dataset folder. method: spike-integral (the default) | spike-nerf | nerf-recon | nerf-blur |
            nerf-blur-aware | nerf-bad | nerf-gt.
        color: gray | rgb. field: grid | mlp. iters: optimiser steps.
        batch: rays per step (reconstruction; None: :meth:`rays_per_step`'s default for the method and
            device).
        lr: base learning rate (None = the field's own); the grid keeps its grid/network ratio.
        lr_final_ratio: exponential decay to this fraction of the rate at ``iters`` (None = the field's).
        seed: seeds the initialisation, the samplers and the jitter. device: auto | cpu | cuda[:N] | mps.
        eval_every: iterations between test-view evaluations (0 = only at the end). eval_views: views used.
        ckpt_every: iterations between checkpoints (always one at the end).
        log: ``none`` or ``tensorboard`` (event files in ``RUN/tensorboard/``; curves.csv is always written).
        log_every: iterations between reads of the loss terms (progress bar, TensorBoard scalars): the
            per-step values are summed on the device and read only then.
        amp: mixed precision of the training step, none | bf16 | fp16 (see ``train/amp.py``).
        compile: ``torch.compile`` the field's per-sample functions (``fields/compiled.py``), or with the
            grid's ``static_samples`` the device part of each step as one graph (``train/compiled_step.py``);
            falls back to eager with a warning when compilation fails.
        compile_optimizer: ``torch.compile`` the Adam update (``train/compiled_optim.py``); not with
            ``amp`` fp16 (its gradient scaler steps the optimiser itself).
        field_config: overrides of the field's config (GridFieldConfig / MLPFieldConfig fields).
        poses: pose refinement (``--refine-poses``, train/pose_refine.py).
        exposure: the learned exposure start and end poses of nerf-bad (train/exposure_poses.py).
        holdout: hold the check steps of ``eval``'s no-reference checks out of training (None: on for
            imported datasets, off for simulated ones; ``spikenerf.data.holdout``).
        holdout_steps: check steps (evenly spaced) on a dataset without imported test keyframes.
        holdout_radius: guard band half-width r in steps around each check step (None: the method's
            ``guard()``: ``data.holdout.guard_radius`` of the TFP window, mask n and spike window, or for
            spike-integral without image targets the check's reach alone; a resumed run keeps its own).
    """

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "iters": Bound(least=1), "batch": Bound(least=1), "lr": Bound(above=0),
        "lr_final_ratio": Bound(above=0, most=1), "eval_every": Bound(least=0), "eval_views": Bound(least=0),
        "ckpt_every": Bound(least=1),
        "log_every": Bound(least=1), "holdout_steps": Bound(least=1), "holdout_radius": Bound(least=0),
    }  # fmt: skip

    dataset: str = ""
    #: the ``Method`` Literal for typing; a value is checked against the registered methods
    method: Method = dataclasses.field(default="spike-integral", metadata=choices(_method_names))
    color: TrainColor = "gray"
    field: FieldKind = "grid"
    iters: int = 5000
    batch: int | None = None
    lr: float | None = None
    lr_final_ratio: float | None = None
    seed: int = 0
    device: str = "auto"
    eval_every: int = 250
    eval_views: int = 3
    ckpt_every: int = 500
    log: LogKind = "none"
    log_every: int = 25
    amp: AmpMode = "none"
    compile: bool = False
    compile_optimizer: bool = False
    holdout: bool | None = None
    holdout_steps: int = 8
    holdout_radius: int | None = None
    targets: TargetConfig = dataclasses.field(default_factory=TargetConfig)
    spike: SpikeLossConfig = dataclasses.field(default_factory=SpikeLossConfig)
    integral: IntegralConfig = dataclasses.field(default_factory=IntegralConfig)
    poses: PoseRefineConfig = dataclasses.field(default_factory=PoseRefineConfig)
    exposure: ExposurePoseConfig = dataclasses.field(default_factory=ExposurePoseConfig)
    field_config: dict[str, Any] = dataclasses.field(default_factory=dict)

    def validate(self) -> TrainConfig:
        """Raise :class:`InputError` on an unknown choice or an out-of-range number; returns self (its numpy
        scalars made Python numbers first)."""
        plain_scalars(self)
        check_config(self)  # types, finite floats and every BOUNDS, naming the key
        check_device_name(self.device)
        check_window(self.targets.window, "targets.window")
        if self.window_poses() > 1 and self.targets.recon != "tfp":  # (only the stream methods read both)
            raise InputError(
                f"targets.window_poses > 1 models the TFP window; targets.recon {self.targets.recon!r} "
                "has none (use tfp)",
                param=("targets.window_poses", "targets.recon"),
            )
        if self.compile_optimizer and self.amp == "fp16":
            raise InputError(
                "compile_optimizer does not work with amp fp16, whose gradient scaler steps the optimiser "
                "itself (use bf16 or none)",
                param=("compile_optimizer", "amp"),
            )
        self.poses.check()
        self.exposure.check()
        self.integral.check()
        self.method_class().check(self)  # the method's own rules (spike-integral's, nerf-bad's, ...)
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def window_poses(self) -> int:
        """Poses per TFP image this run's renders are averaged over (its targets, and ``eval``'s TFP
        keyframes and no-reference checks): the resolved ``targets.window_poses`` for the stream methods
        (nerf-recon, spike-nerf) and for spike-integral, which renders sharp images as window-aware runs do;
        1 for the others."""
        from spikenerf.train.methods import METHOD_CLASSES  # (torch: only where a method's facts are read)

        cls = METHOD_CLASSES.get(self.method)
        return self.targets.poses_per_target() if cls is not None and cls.uses_stream else 1

    def rays_per_step(self, device_type: str = "cpu") -> int:
        """``batch``, or where it is None the method's ``default_batch`` (spike-integral: 4096, 4096
        windows × 1 render; the others :data:`DEFAULT_BATCH`, 1024), :data:`GPU_BATCH_SCALE` times that on
        a ``cuda`` device."""
        if self.batch is not None:
            return self.batch
        from spikenerf.train.methods import METHOD_CLASSES

        cls = METHOD_CLASSES.get(self.method)
        rays = DEFAULT_BATCH if cls is None else cls.default_batch
        return rays * GPU_BATCH_SCALE if device_type == "cuda" else rays

    def method_class(self) -> type[TrainMethod]:
        """The registered class of ``method`` (``spikenerf.train.methods.METHOD_CLASSES``)."""
        from spikenerf.train.methods import method_class

        return method_class(self.method)

    def resolved(self, device_type: str = "cpu") -> TrainConfig:
        """A copy with the defaults that depend on other fields filled in (``targets.window_poses``: see
        :meth:`window_poses`; ``targets.mask``: :meth:`TargetConfig.masked` of those; ``batch``:
        :meth:`rays_per_step` on ``device_type``), as a new run records them in its ``config.yaml``."""
        targets = dataclasses.replace(self.targets, window_poses=self.window_poses())
        targets = dataclasses.replace(targets, mask=targets.masked())
        return dataclasses.replace(self, targets=targets, batch=self.rays_per_step(device_type))

    @classmethod
    def from_dict(cls, data: dict[str, Any], path: str | Path | None = None) -> TrainConfig:
        """Rebuild from :meth:`to_dict` output (e.g. ``config.yaml``); unknown keys and wrong types are an
        InputError (the ranges are :meth:`validate`'s)."""
        config = from_mapping(cls, data, "train config", path=path, sections=SECTIONS)
        check_config(config, path=path, bounds=False)
        return config


#: the sections of a TrainConfig mapping, built as their config classes
SECTIONS: dict[str, type] = {
    "targets": TargetConfig,
    "spike": SpikeLossConfig,
    "integral": IntegralConfig,
    "poses": PoseRefineConfig,
    "exposure": ExposurePoseConfig,
}

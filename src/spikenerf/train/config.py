"""Typed training configs (saved to ``RUN/config.yaml``); what each method does with them is its class in
:mod:`spikenerf.train.methods`.

The dataclasses are the one typed source: each choice is a ``Literal`` owned by the module that implements
it, and :func:`check_types` validates any value (a YAML file, ``--set key.sub=value``) against the
annotations. The ablation flags only ever switch parts off.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

import yaml

from spikenerf.camera.reconstruct import DEFAULT_WINDOW
from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError
from spikenerf.data.samplers import WindowOrder
from spikenerf.data.targets import STREAM_METHODS, Method, TargetRecon, TrainColor
from spikenerf.fields import FIELD_KINDS, FieldKind
from spikenerf.train.amp import AmpMode
from spikenerf.train.exposure_poses import ExposurePoseConfig
from spikenerf.train.logger import LogKind
from spikenerf.train.losses import SPIKE_LOSS_KINDS, PairMode, SpikeLossKind
from spikenerf.train.pose_refine import PoseRefineConfig

FIELDS = FIELD_KINDS
__all__ = ["FIELDS", "SPIKE_LOSS_KINDS", "IntegralConfig", "SpikeLossConfig", "TargetConfig", "TrainConfig"]


#: the default poses per TFP target (window-aware targets; docs/method.md, Targets)
WINDOW_POSES = 4
#: spike-integral's default window length and steps rendered per window (docs/method.md, Spike-integral)
INTEGRAL_WINDOW, INTEGRAL_SAMPLES = 11, 2
#: rays per step when ``batch`` is not given: 1024 targets, and for spike-integral 1024 windows of
#: ``INTEGRAL_SAMPLES`` renders each (the oracle's 1024 targets a step; docs/spike-integral.md, Batch)
DEFAULT_BATCH = 1024
METHOD_BATCH: dict[str, int] = {"spike-integral": DEFAULT_BATCH * INTEGRAL_SAMPLES}


@dataclass
class TargetConfig:
    """Reconstruction targets.

    Attributes:
        recon: tfp | tfi (image reconstruction of the stream). window: TFP window, frames (odd).
        mask: multiply by the spike masks (spike-nerf). mask_n: mask half window n (2n+1 frames, paper: 5).
        blur_samples: poses per exposure averaged by nerf-blur-aware and nerf-bad (its virtual frames).
        window_poses: poses per TFP target of nerf-recon and spike-nerf, spread over its window and
            averaged (1: the target's own step, the paper's; S > 1: window-aware targets, recon tfp only;
            None: :data:`WINDOW_POSES` with tfp, 1 otherwise). :meth:`poses_per_target` resolves it.
    """

    recon: TargetRecon = "tfp"
    window: int = DEFAULT_WINDOW
    mask: bool = True
    mask_n: int = 5
    blur_samples: int = 8
    window_poses: int | None = None

    def poses_per_target(self) -> int:
        """``window_poses`` resolved: :data:`WINDOW_POSES` for TFP targets when unset, else 1."""
        if self.window_poses is None:
            return WINDOW_POSES if self.recon == "tfp" else 1
        return self.window_poses


@dataclass
class IntegralConfig:
    """spike-integral: each target is a window's spike-count mean ``φ N / L``, compared with the mean of
    renders at steps drawn inside the window at their own poses (docs/spike-integral.md).

    Attributes:
        lengths: window lengths L in steps; each target draws one uniformly.
        samples: S steps rendered per estimate of a window's mean render (stratified over the window).
        groups: G independent estimates per window: 1 squared error; ≥ 2 the unbiased product form.
        band: count errors within the interval ``± φ / L`` of a noise-free pixel as 0.
    """

    lengths: list[int] = dataclasses.field(default_factory=lambda: [INTEGRAL_WINDOW])
    samples: int = INTEGRAL_SAMPLES
    groups: int = 1
    band: bool = False

    def check(self) -> None:
        """InputError (naming ``integral.KEY``) on an empty or non-positive ``lengths``, ``samples`` < 1 or
        ``groups`` < 1."""
        if not self.lengths or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1
                                       for n in self.lengths):  # fmt: skip
            raise InputError(
                f"integral.lengths must be a list of window lengths ≥ 1, found {self.lengths!r}",
                param="integral.lengths",
            )
        for name, value in (("integral.samples", self.samples), ("integral.groups", self.groups)):
            if value < 1:
                raise InputError(f"{name} must be ≥ 1, found {value}", param=name)
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
        batch: rays per step (reconstruction; None: :meth:`rays_per_step`'s default for the method).
        lr: base learning rate (None = the field's own); the grid keeps its grid/network ratio.
        lr_final_ratio: exponential decay to this fraction of the rate at ``iters`` (None = the field's).
        seed: seeds the initialisation, the samplers and the perturbations. device: auto | cpu | cuda.
        eval_every: iterations between test-view evaluations (0 = only at the end). eval_views: views used.
        ckpt_every: iterations between checkpoints (always one at the end).
        log: ``none`` or ``tensorboard`` (event files in ``RUN/tensorboard/``; curves.csv is always written).
        log_every: iterations between reads of the loss terms (progress bar, TensorBoard scalars): the
            per-step values are summed on the device and read only then.
        amp: mixed precision of the training step, none | bf16 | fp16 (see ``train/amp.py``).
        compile: ``torch.compile`` the field's per-sample functions (``fields/compiled.py``; falls back to
            eager with a warning when compilation fails).
        field_config: overrides of the field's config (GridFieldConfig / MLPFieldConfig fields).
        poses: pose refinement (``--refine-poses``, train/pose_refine.py).
        exposure: the learned exposure start and end poses of nerf-bad (train/exposure_poses.py).
        holdout: hold the check steps of ``eval``'s no-reference checks out of training (None: on for
            imported datasets, off for simulated ones; ``spikenerf.data.holdout``).
        holdout_steps: check steps (evenly spaced) on a dataset without imported test keyframes.
        holdout_radius: guard band half-width r in steps around each check step (None:
            ``data.holdout.guard_radius`` of the TFP window, mask n and spike window).
    """

    dataset: str = ""
    method: Method = "spike-integral"
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
        """Raise :class:`InputError` on an unknown choice or an out-of-range number; returns self."""
        check_types(self)
        positive = {  # errors name the config key; the CLI maps keys to its flags
            "iters": self.iters,
            "batch": self.rays_per_step(),
            "spike.window": self.spike.window,
            "spike.pixels": self.spike.pixels,
            "spike.every": self.spike.every,
            "eval_views": self.eval_views + 1,
            "ckpt_every": self.ckpt_every,
            "log_every": self.log_every,
            "targets.blur_samples": self.targets.blur_samples,
            "targets.window_poses": self.targets.poses_per_target(),
            "holdout_steps": self.holdout_steps,
        }
        for name, value in positive.items():
            if value < 1:
                raise InputError(f"{name} must be ≥ 1, found {value}", param=name)
        for name, value in (
            ("spike.warmup_iters", self.spike.warmup_iters),
            ("spike.ramp_iters", self.spike.ramp_iters),
            ("holdout_radius", self.holdout_radius),
        ):
            if value is not None and value < 0:
                raise InputError(f"{name} must be ≥ 0, found {value}", param=name)
        if self.lr is not None and not (math.isfinite(self.lr) and self.lr > 0):
            raise InputError(f"lr must be a finite number > 0, found {self.lr}", param="lr")
        if not (math.isfinite(self.spike.lam) and self.spike.lam >= 0) or self.eval_every < 0:
            raise InputError(
                f"spike.lam and eval_every must be ≥ 0, found {self.spike.lam}, {self.eval_every}",
                param=("spike.lam", "eval_every"),
            )
        ratio = self.lr_final_ratio
        if ratio is not None and not (math.isfinite(ratio) and 0 < ratio <= 1):
            raise InputError(
                f"lr_final_ratio must be a finite number in (0, 1], found {ratio}", param="lr_final_ratio"
            )
        if self.targets.mask_n < 1:
            raise InputError(
                f"targets.mask_n must be ≥ 1, found {self.targets.mask_n}", param="targets.mask_n"
            )
        if self.spike.paper_warmup < 0:
            raise InputError(
                f"spike.paper_warmup must be ≥ 0, found {self.spike.paper_warmup}", param="spike.paper_warmup"
            )
        if self.targets.window < 1 or self.targets.window % 2 == 0:
            raise InputError(
                f"targets.window must be an odd number of frames, found {self.targets.window}",
                param="targets.window",
            )
        if self.targets.poses_per_target() > 1 and self.targets.recon != "tfp":
            raise InputError(
                f"targets.window_poses > 1 models the TFP window; targets.recon {self.targets.recon!r} "
                "has none (use tfp)",
                param=("targets.window_poses", "targets.recon"),
            )
        self.poses.check()
        self.exposure.check()
        self.integral.check()
        rays = self.integral.samples * self.integral.groups
        if self.method == "spike-integral" and self.rays_per_step() < rays:
            raise InputError(
                f"batch: {self.rays_per_step()} rays a step cannot render one window of {rays} steps "
                "(integral.samples × integral.groups)",
                param=("batch", "integral.samples"),
            )
        if self.method == "spike-integral" and self.targets.recon != "tfp":
            raise InputError(
                f"targets.recon {self.targets.recon!r}: spike-integral reads spike counts, not reconstructed "
                "images (use nerf-recon or spike-nerf for reconstruction targets)",
                param="targets.recon",
            )
        if self.method == "nerf-bad" and self.targets.blur_samples < 2:
            raise InputError(
                f"targets.blur_samples must be ≥ 2 for nerf-bad (a start and an end pose), "
                f"found {self.targets.blur_samples}",
                param="targets.blur_samples",
            )
        if self.method == "nerf-bad" and self.poses.refine:
            raise InputError(
                "poses.refine: nerf-bad learns each exposure's own start and end pose; turn refinement off",
                param="poses.refine",
            )
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def window_poses(self) -> int:
        """Poses per TFP image this run's renders are averaged over (its targets, and ``eval``'s TFP
        keyframes and no-reference checks): the resolved ``targets.window_poses`` for the stream methods
        (nerf-recon, spike-nerf) and for spike-integral, which renders sharp images as window-aware runs do;
        1 for the others."""
        sharp = self.method in STREAM_METHODS or self.method == "spike-integral"
        return self.targets.poses_per_target() if sharp else 1

    def rays_per_step(self) -> int:
        """``batch``, or where it is None the method's default: :data:`METHOD_BATCH` (spike-integral: 2048,
        1024 windows × 2 renders), else :data:`DEFAULT_BATCH` (1024)."""
        return self.batch if self.batch is not None else METHOD_BATCH.get(self.method, DEFAULT_BATCH)

    def resolved(self) -> TrainConfig:
        """A copy with the defaults that depend on other fields filled in (``targets.window_poses``: see
        :meth:`window_poses`; ``batch``: :meth:`rays_per_step`), as a new run records them in its
        ``config.yaml``."""
        targets = dataclasses.replace(self.targets, window_poses=self.window_poses())
        return dataclasses.replace(self, targets=targets, batch=self.rays_per_step())

    @classmethod
    def from_dict(cls, data: dict[str, Any], path: str | Path | None = None) -> TrainConfig:
        """Rebuild from :meth:`to_dict` output (e.g. ``config.yaml``); unknown keys are an InputError."""
        return _from_dict(cls, data, path)


def check_types(config: Any, prefix: str = "", path: str | Path | None = None) -> None:
    """Check every field of a config dataclass (and its sections) against its annotation: ``Literal``
    choices, int, float, bool, str, ``X | None``, dict; an InputError names the key (``spike.kind``)."""
    hints = get_type_hints(type(config))
    for f in dataclasses.fields(config):
        value, name = getattr(config, f.name), f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            check_types(value, f"{name}.", path)
        elif not _matches(value, hints[f.name]):
            # no param=: a wrong type comes from a file or --set, where the user wrote the key itself
            raise InputError(f"{name} must be {_describe(hints[f.name])}, found {value!r}", path=path)


def _matches(value: Any, hint: Any) -> bool:
    origin = get_origin(hint)
    if origin is Literal:
        return value in get_args(hint)
    if origin in (Union, types.UnionType):
        return any(_matches(value, h) for h in get_args(hint))
    if hint is type(None):
        return value is None
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is int:  # 64 bits: torch and numpy overflow beyond
        return isinstance(value, int) and not isinstance(value, bool) and abs(value) < 2**63
    return isinstance(value, origin or hint)


def _coerce(value: Any, hint: Any) -> Any:
    """A string for a number-typed key read as a float (YAML 1.1 reads ``1e-3``, no dot, as a string);
    anything else unchanged (``--set dataset=1e3`` stays the string it is)."""
    if isinstance(value, str) and _matches(1.0, hint) and not _matches(value, hint):
        with contextlib.suppress(ValueError):
            return float(value)
    return value


def _describe(hint: Any) -> str:
    origin = get_origin(hint)
    if origin is Literal:
        return "one of " + ", ".join(map(str, get_args(hint)))
    if origin in (Union, types.UnionType):
        return " or ".join(_describe(h) for h in get_args(hint))
    names = {type(None): "null", float: "a number", int: "an integer", bool: "true or false", str: "a string"}
    return names.get(hint, f"a {getattr(origin or hint, '__name__', hint)}")


def apply_overrides(data: dict[str, Any], items: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """Apply ``KEY.SUB=VALUE`` overrides (values parsed as YAML) to a :meth:`TrainConfig.to_dict` mapping.

    ``KEY`` is any TrainConfig field, ``targets.X``/``spike.X`` their fields, ``field_config.X`` an entry of
    the field's config. Unknown keys are reported when the mapping is turned back into a config.
    """
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key or any(not part for part in key.split(".")):
            raise InputError(f"override expects KEY=VALUE (e.g. spike.lam=0.5), found {item!r}")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise InputError(f"override {key}: unreadable value {text!r} ({err})") from err
        *sections, leaf = key.split(".")
        node = data
        for i, section in enumerate(sections):
            if not isinstance(node.get(section), dict):
                where = ".".join(sections[: i + 1])
                raise InputError(
                    f"override {key}: {where!r} is not a section "
                    "(targets, spike, integral, poses, exposure, field_config)"
                )
            node = node[section]
        node[leaf] = value
    return data


def _from_dict(cls: type, data: Any, path: str | Path | None) -> Any:
    if not isinstance(data, dict):
        raise InputError(f"expected a mapping for {cls.__name__}, found {type(data).__name__}", path=path)
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise InputError(
            f"unknown {cls.__name__} keys {unknown}; expected some of {sorted(known)}", path=path
        )
    nested = {
        "targets": TargetConfig,
        "spike": SpikeLossConfig,
        "integral": IntegralConfig,
        "poses": PoseRefineConfig,
        "exposure": ExposurePoseConfig,
    }
    hints = get_type_hints(cls)
    values = {
        k: _from_dict(nested[k], v, path) if k in nested else _coerce(v, hints[k]) for k, v in data.items()
    }
    config = cls(**values)
    if cls is TrainConfig:
        check_types(config, path=path)
    return config


def save_config(config: TrainConfig, path: str | Path) -> None:
    """Write ``config.yaml`` atomically."""
    write_text_atomic(path, yaml.safe_dump(config.to_dict(), sort_keys=False))


#: the largest config file read (a config is a few kB; a larger file is surely not one)
MAX_CONFIG_BYTES = 1 << 20


def _read_config(path: str | Path) -> tuple[Path, Any]:
    """The parsed YAML of a config file (InputError when missing or malformed)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("missing run config (not a run folder written by `spikenerf train`?)", path=path)
    if path.stat().st_size > MAX_CONFIG_BYTES:
        raise InputError(f"is {path.stat().st_size} bytes, too large for a YAML config", path=path)
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = "\0"
    if "\0" in text:
        raise InputError("is a binary file, not a YAML config", path=path)
    try:
        return path, yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise InputError(f"malformed YAML ({err})", path=path) from err


def load_config(path: str | Path) -> TrainConfig:
    """Read ``config.yaml`` written by :func:`save_config` (or a ``--config`` file)."""
    path, data = _read_config(path)
    return TrainConfig.from_dict(data, path).validate()


def load_run_config(path: str | Path) -> TrainConfig:
    """A run folder's ``config.yaml`` as that run trained: :func:`load_config`, but a run written before
    ``targets.window_poses`` existed (its targets section lacks the key) trained with one pose per target,
    not today's default. (A run written since records the resolved count: :meth:`TrainConfig.resolved`.)"""
    path, data = _read_config(path)
    config = TrainConfig.from_dict(data, path).validate()
    if isinstance(data.get("targets"), dict) and "window_poses" not in data["targets"]:
        config.targets.window_poses = 1
    return config

"""Typed training configs (saved to ``RUN/config.yaml``) and the methods they select.

``TrainConfig.for_method`` applies a method's defaults; the ablation flags only ever switch parts off.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError
from spikenerf.data.targets import COLORS, METHODS, RECONS
from spikenerf.train.amp import AMP_MODES

FIELDS = ("grid", "mlp")
SPIKE_LOSS_KINDS = ("interval", "paper")


@dataclass
class TargetConfig:
    """Reconstruction targets.

    Attributes:
        recon: tfp | tfi (image reconstruction of the stream). window: TFP window, frames (odd).
        mask: multiply by the spike masks (spike-nerf). mask_n: mask half window n (2n+1 frames, paper: 5).
        blur_samples: poses per exposure averaged by nerf-blur-aware.
    """

    recon: str = "tfp"
    window: int = 41
    mask: bool = True
    mask_n: int = 5
    blur_samples: int = 8


@dataclass
class SpikeLossConfig:
    """The spike loss ``λ(it) · L_spike``.

    Attributes:
        enabled: use the spike loss (spike-nerf only). kind: ``interval`` (differentiable integral constraint)
            or ``paper`` (the paper's non-differentiable spike comparison, for comparison: no gradient).
        lam: λ after the ramp. warmup_iters: iterations with λ = 0 (no spike windows rendered).
        ramp_iters: linear ramp of λ from 0 to ``lam``. Both default (None) to a fifth of the run
        (300 each for the default 1500 iterations), see :meth:`schedule`.
        window: L consecutive steps per window.
        pixels: pixels per window (each renders L rays). pairs: ``all`` sub-windows or the whole ``window``.
        order: ``sequential`` windows along the stream (the paper's deterministic choice) or ``random``.
        every: render a spike window every this many iterations. paper_warmup: steps the paper loss discards.
    """

    enabled: bool = True
    kind: str = "interval"
    lam: float = 1.0
    warmup_iters: int | None = None
    ramp_iters: int | None = None
    window: int = 16
    pixels: int = 32
    pairs: str = "all"
    order: str = "sequential"
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
        dataset: dataset folder. method: spike-nerf | nerf-recon | nerf-blur | nerf-blur-aware | nerf-gt.
        color: gray | rgb. field: grid | mlp. iters: optimiser steps. batch: rays per step (reconstruction).
        lr: base learning rate (None = the field's own); the grid keeps its grid/network ratio.
        lr_final_ratio: exponential decay to this fraction of the rate at ``iters`` (None = the field's).
        seed: seeds the initialisation, the samplers and the perturbations. device: auto | cpu | cuda.
        eval_every: iterations between test-view evaluations (0 = only at the end). eval_views: views used.
        ckpt_every: iterations between checkpoints (always one at the end).
        amp: mixed precision of the training step, none | bf16 | fp16 (see ``train/amp.py``).
        field_config: overrides of the field's config (GridFieldConfig / MLPFieldConfig fields).
    """

    dataset: str = ""
    method: str = "spike-nerf"
    color: str = "gray"
    field: str = "grid"
    iters: int = 1500
    batch: int = 1024
    lr: float | None = None
    lr_final_ratio: float | None = None
    seed: int = 0
    device: str = "auto"
    eval_every: int = 250
    eval_views: int = 3
    ckpt_every: int = 500
    amp: str = "none"
    targets: TargetConfig = dataclasses.field(default_factory=TargetConfig)
    spike: SpikeLossConfig = dataclasses.field(default_factory=SpikeLossConfig)
    field_config: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def uses_spike_loss(self) -> bool:
        return self.method == "spike-nerf" and self.spike.enabled

    @property
    def uses_mask(self) -> bool:
        return self.method == "spike-nerf" and self.targets.mask

    def validate(self) -> TrainConfig:
        """Raise :class:`InputError` on an unknown choice or an out-of-range number; returns self."""
        choices = {
            "--method": (self.method, METHODS),
            "--color": (self.color, COLORS),
            "--field": (self.field, FIELDS),
            "--recon": (self.targets.recon, RECONS),
            "--spike-loss": (self.spike.kind, SPIKE_LOSS_KINDS),
            "spike.pairs": (self.spike.pairs, ("all", "window")),
            "spike.order": (self.spike.order, ("sequential", "random")),
            "--amp": (self.amp, AMP_MODES),
        }
        for name, (value, allowed) in choices.items():
            if value not in allowed:
                raise InputError(f"{name} must be one of {', '.join(allowed)}, found {value!r}")
        positive = {
            "--iters": self.iters,
            "--batch": self.batch,
            "spike.window": self.spike.window,
            "spike.pixels": self.spike.pixels,
            "spike.every": self.spike.every,
            "--eval-views": self.eval_views + 1,
            "--ckpt-every": self.ckpt_every,
            "blur_samples": self.targets.blur_samples,
        }
        for name, value in positive.items():
            if value < 1:
                raise InputError(f"{name} must be ≥ 1, found {value}")
        for name, value in (
            ("--spike-warmup", self.spike.warmup_iters),
            ("spike.ramp", self.spike.ramp_iters),
        ):
            if value is not None and value < 0:
                raise InputError(f"{name} must be ≥ 0, found {value}")
        if self.lr is not None and not self.lr > 0:
            raise InputError(f"--lr must be positive, found {self.lr}")
        if self.spike.lam < 0 or self.eval_every < 0:
            raise InputError(
                f"--lambda and --eval-every must be ≥ 0, found {self.spike.lam}, {self.eval_every}"
            )
        if self.targets.window < 1 or self.targets.window % 2 == 0:
            raise InputError(f"--window must be an odd number of frames, found {self.targets.window}")
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any], path: str | Path | None = None) -> TrainConfig:
        """Rebuild from :meth:`to_dict` output (e.g. ``config.yaml``); unknown keys are an InputError."""
        return _from_dict(cls, data, path)


def _from_dict(cls: type, data: Any, path: str | Path | None) -> Any:
    if not isinstance(data, dict):
        raise InputError(f"expected a mapping for {cls.__name__}, found {type(data).__name__}", path=path)
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise InputError(
            f"unknown {cls.__name__} keys {unknown}; expected some of {sorted(known)}", path=path
        )
    nested = {"targets": TargetConfig, "spike": SpikeLossConfig}
    values = {k: _from_dict(nested[k], v, path) if k in nested else v for k, v in data.items()}
    return cls(**values)


def save_config(config: TrainConfig, path: str | Path) -> None:
    """Write ``config.yaml`` atomically."""
    write_text_atomic(path, yaml.safe_dump(config.to_dict(), sort_keys=False))


def load_config(path: str | Path) -> TrainConfig:
    """Read ``config.yaml`` written by :func:`save_config`."""
    path = Path(path)
    if not path.is_file():
        raise InputError("missing run config (not a run folder written by `spikenerf train`?)", path=path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as err:
        raise InputError(f"malformed YAML ({err})", path=path) from err
    return TrainConfig.from_dict(data, path).validate()

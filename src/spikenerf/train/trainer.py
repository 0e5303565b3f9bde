"""The training loop: targets → Adam with exponential decay → periodic evaluation → atomic checkpoints.

The method (:mod:`spikenerf.train.methods`) builds the targets and returns each step's named loss terms
(``recon``, ``reg`` and, for spike-nerf once λ(it) > 0, ``spike``); the trainer sums them, steps the
optimiser, logs the terms and checkpoints. A run interrupted at any point resumes from ``RUN/checkpoint.pt``
to the same parameters as an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

import torch

from spikenerf.core.atomic import clean_stale_temps, write_text_atomic
from spikenerf.core.device import resolve_device
from spikenerf.core.errors import InputError, as_path, is_integer, one_line
from spikenerf.core.faults import failpoint
from spikenerf.core.limits import check_resources
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import check_output, discard_fresh, fresh_state, mark, owned
from spikenerf.core.progress import bar as progress_bar
from spikenerf.data.dataset import SpikeDataset, load_dataset
from spikenerf.data.holdout import write_record
from spikenerf.data.rays import pixel_rays
from spikenerf.data.recon_cache import learned_targets_in
from spikenerf.data.targets import eval_view_targets
from spikenerf.fields.compiled import compile_field
from spikenerf.fields.grid import KERNEL_OPTIONS
from spikenerf.fields.registry import field_config, field_memory
from spikenerf.render.base import RadianceModel
from spikenerf.render.model import build_model, ray_bounds
from spikenerf.render.volume import RenderOutput
from spikenerf.train.amp import autocast
from spikenerf.train.checkpoint import (
    CHECKPOINT,
    check_optimizer_fits,
    check_same_run,
    load_checkpoint,
    match_state_layout,
    model_of,
    restore_rng,
    rng_state,
    save_checkpoint,
)
from spikenerf.train.compiled_optim import CompiledAdamStep, load_state, set_lr, use_tensor_lr
from spikenerf.train.compiled_step import CompiledStep, compile_step, compiles_needed, static_samples
from spikenerf.train.config import CONFIG_FILE, TrainConfig, load_run_config, save_config
from spikenerf.train.dense_adam import DenseAdam
from spikenerf.train.device import batch_bytes, check_batch_fits, keep_targets_on_device
from spikenerf.train.evaluate import CURVES, LOSS_COLUMNS, evaluate_views, read_curves, write_curves
from spikenerf.train.logger import RunningMeans, open_log, step_scalars
from spikenerf.train.losses import mse_to_psnr
from spikenerf.train.methods import StepLosses, make_method, method_class, unused_keys
from spikenerf.train.pose_refine import pose_refinement
from spikenerf.train.run import SUMMARY, TrainSummary, check_resume_fits, dataset_fingerprint, stored_summary

#: options that may change when a run is resumed (everything else must match the stored config)
RESUMABLE = (
    "iters", "eval_every", "ckpt_every", "device", "eval_views", "log", "log_every", "compile",
    "compile_optimizer",
)  # fmt: skip
#: field options that choose how the same model is computed, not the model: a resume may change them (e.g.
#: a run trained with Triton kernels on a GPU resumed on a CPU)
RESUMABLE_FIELD = KERNEL_OPTIONS


def with_kernels(hparams: dict, field_cfg: Any) -> dict:
    """A checkpoint's model ``hparams`` with the kernel choices (:data:`RESUMABLE_FIELD`) of ``field_cfg``,
    the resumed run's field config (the model itself is the stored one)."""
    chosen = {k: getattr(field_cfg, k) for k in RESUMABLE_FIELD if hasattr(field_cfg, k)}
    if not chosen or not isinstance(hparams.get("config"), dict):
        return hparams
    return {**hparams, "config": {**hparams["config"], **chosen}}


def model_config(config: TrainConfig) -> Any:
    """The field config: defaults + ``config.field_config``; its schedules (the grid's) rescaled to
    ``config.iters`` unless ``field_config`` sets ``iterations``."""
    cfg = field_config(config.field, dict(config.field_config))
    if "iterations" not in config.field_config:
        cfg = cfg.for_iterations(config.iters)
    return cfg


def make_optimizer(model: RadianceModel, config: TrainConfig) -> torch.optim.Adam:
    """Adam over the model's parameter groups; each group remembers its undecayed rate as ``base_lr``."""
    groups = model.param_groups(config.lr)
    for g in groups:
        g["base_lr"] = g["lr"]
    # the fused kernel updates each tensor in one pass (7× faster than the per-op loop on a CPU); on a CPU
    # it copies a channels-last tensor (the grid's factors) unless stepped through row-major views
    if config.compile_optimizer:  # plain Adam with tensor rates, stepped by CompiledAdamStep
        optimizer = torch.optim.Adam(groups, betas=(0.9, 0.99))
        use_tensor_lr(optimizer)
        return optimizer
    adam = DenseAdam if model.device.type == "cpu" else torch.optim.Adam
    return adam(groups, betas=(0.9, 0.99), fused=model.device.type in ("cpu", "cuda"))


def set_learning_rate(
    optimizer: torch.optim.Optimizer, iteration: int, iters: int, final_ratio: float
) -> None:
    """Exponential decay ``lr = base_lr · final_ratio^(iteration / iters)``."""
    factor = final_ratio ** (iteration / max(iters, 1))
    for g in optimizer.param_groups:
        set_lr(g, g["base_lr"] * factor)


def _lr_final_ratio(config: TrainConfig, model: RadianceModel) -> float:
    return config.lr_final_ratio if config.lr_final_ratio is not None else float(model.config.lr_final_ratio)


def _stored_and_given(path: Path, given: TrainConfig) -> tuple[TrainConfig, TrainConfig]:
    """The run's stored config and ``given``; a run from before the hold-out (its config.yaml has no
    ``holdout`` key) trained on every step, so it resumes without one unless ``given`` asks for it. Window
    poses, masks, rays per step, windows and tracks that ``given`` leaves to their defaults are the run's
    own; a run from before track windows has none. Keys the method does not read (``unused_keys``) are the
    run's own too: a flag ``train`` called ignored does not block the resume."""
    stored = load_run_config(path)
    if stored.dataset:  # a run from before absolute dataset paths: as seen from here, as ``given``'s is
        stored.dataset = str(Path(stored.dataset).resolve())
    if stored.integral.track is None:  # a run from before track windows: none
        stored.integral.track = 0
    if not any(line.startswith("holdout:") for line in path.read_text(encoding="utf-8").splitlines()):
        stored.holdout = False
        if given.holdout is None:
            given = dataclasses.replace(given, holdout=False)
    if given.targets.window_poses is None:  # not asked: the count the run trained with
        targets = dataclasses.replace(given.targets, window_poses=stored.targets.window_poses)
        given = dataclasses.replace(given, targets=targets)
    if given.targets.mask is None:  # not asked: the masks the run trained with (runs before: on)
        given = dataclasses.replace(
            given, targets=dataclasses.replace(given.targets, mask=stored.targets.mask)
        )
    if given.batch is None:  # not asked: the rays per step the run trained with
        given = dataclasses.replace(given, batch=stored.batch)
    if given.integral.lengths is None:  # not asked: the windows the run trained with
        integral = dataclasses.replace(given.integral, lengths=stored.integral.lengths)
        given = dataclasses.replace(given, integral=integral)
    if given.integral.track is None:  # not asked: the run's tracks
        integral = dataclasses.replace(given.integral, track=stored.integral.track)
        given = dataclasses.replace(given, integral=integral)
    if given.method == stored.method:  # what the method does not read (train warned) cannot differ
        data, old = given.to_dict(), stored.to_dict()
        for section in ("targets", "spike", "integral", "exposure"):
            for key in unused_keys(given.method, [f"{section}.{k}" for k in data[section]]):
                data[section][key.partition(".")[2]] = old[section][key.partition(".")[2]]
        given = TrainConfig.from_dict(data)
    return stored, given


def _check_resume(
    stored: TrainConfig, given: TrainConfig, path: Path, also: tuple[str, ...] = ()
) -> TrainConfig:
    """The stored config with the resumable options (:data:`RESUMABLE` and ``also``, and the field options
    of :data:`RESUMABLE_FIELD` that ``given`` sets) of ``given``; other differences are an InputError."""
    resumable = (*RESUMABLE, *also)
    a, b = stored.to_dict(), given.to_dict()
    for d in (a, b):  # compared without the implementation choices
        d["field_config"] = {k: v for k, v in d["field_config"].items() if k not in RESUMABLE_FIELD}
    diff = sorted(k for k in a if k not in resumable and a[k] != b[k])
    if diff:
        leaves = [(k, x, y) for k in diff for k, x, y in _leaf_changes(k, a[k], b[k])]
        detail = ", ".join(f"{k}: run has {x!r}, asked {y!r}" for k, x, y in leaves)
        raise InputError(
            f"resume with different options ({detail}); use a new out folder to change them",
            path,
            param=(*(k for k, _, _ in leaves), "resume", "out"),
        )
    chosen = {k: v for k, v in given.field_config.items() if k in RESUMABLE_FIELD}
    field = {**stored.field_config, **chosen}  # the stored choices stay unless given again
    return dataclasses.replace(stored, **{k: getattr(given, k) for k in resumable}, field_config=field)


def _leaf_changes(key: str, was: Any, now: Any) -> list[tuple[str, Any, Any]]:
    """The differing entries of a config section, dotted (``targets.recon``), down to its leaves: one
    changed option is named alone, not with its whole section."""
    if isinstance(was, dict) and isinstance(now, dict) and key != "field_config":
        return [
            change
            for k in sorted({*was, *now}, key=str)
            if was.get(k) != now.get(k)
            for change in _leaf_changes(f"{key}.{k}", was.get(k), now.get(k))
        ]
    return [(key, was, now)]


#: the running mean of the static budget's cut slots a ray (read every ``log_every`` steps; not in curves)
DROPPED = "dropped_per_ray"


def check_api_args(config: object, out: object, dataset: object) -> None:
    """InputError naming ``config``, ``out`` or ``dataset`` when it is not what :func:`train` and
    :class:`Trainer` take (a dict for the config, None or a number for the folder, a path for the loaded
    dataset: each failed deep inside as an AttributeError or a TypeError)."""
    if not isinstance(config, TrainConfig):
        raise InputError(
            f"config must be a TrainConfig (TrainConfig.from_dict for a mapping), found "
            f"{type(config).__name__}",
            param="config",
        )
    as_path(out, "out")
    if dataset is not None and not isinstance(dataset, SpikeDataset):
        raise InputError(
            f"dataset must be a loaded SpikeDataset or None (config.dataset gives the folder), found "
            f"{type(dataset).__name__}",
            param="dataset",
        )


def _dataset_recorded(config: TrainConfig, dataset: SpikeDataset | None) -> TrainConfig:
    """``config`` with ``dataset`` the absolute path of the folder the run trains on: ``dataset``'s, when a
    loaded one is given (``config.dataset`` empty or the same folder; another one is an InputError), else
    ``config.dataset`` resolved. ``config.yaml`` records it, so that ``load_run`` and ``evaluate_run`` find
    the data from any working directory (a relative path held only from the folder training ran in)."""
    named = str(config.dataset) if isinstance(config.dataset, (str, os.PathLike)) else config.dataset
    if dataset is None:
        if not isinstance(named, str) or not named:
            return config  # validate() names the problem
        return dataclasses.replace(config, dataset=str(Path(named).resolve()))
    root = Path(dataset.root).resolve()
    if isinstance(named, str) and named and Path(named).resolve() != root:
        raise InputError(
            f"config.dataset names {named} but the dataset given was loaded from {dataset.root}: give one "
            "(or the same folder in both)",
            param=("dataset", "config.dataset"),
        )
    return dataclasses.replace(config, dataset=str(root))


def check_stop_after(stop_after: object) -> None:
    """InputError naming ``stop_after`` unless it is None or an integer ≥ 1."""
    integer = is_integer(stop_after)
    if stop_after is not None and not (integer and stop_after >= 1):  # type: ignore[operator]
        raise InputError(
            f"stop_after must be None or an integer ≥ 1, found {stop_after!r}", param="stop_after"
        )


def warn(message: str) -> None:
    """One warning line on stderr (``spikenerf: warning: ...``)."""
    print(f"spikenerf: warning: {message}", file=sys.stderr)


def learned_cache(method: Any) -> bool:
    """Whether the run caches whole-stream learned reconstructions in its folder (``data/recon_cache.py``)."""
    return bool(method.uses_learned)


def check_train_resources(config: TrainConfig, dataset: SpikeDataset, out: Path) -> None:
    """Refuse a run whose estimated memory (targets, field, one batch) or checkpoint (and learned-target
    cache) exceeds the machine's."""
    k, steps = dataset.intrinsics, len(dataset.trajectory)
    method = make_method(config)
    if method.uses_spike_loss and config.spike.window > steps:  # before its memory: the clearer complaint
        raise InputError(
            f"spike.window: a {config.spike.window}-step window exceeds the {steps} recorded steps",
            param="spike.window",
        )
    targets = float(steps) * k.height * k.width * method.channels * 10 if method.uses_stream else 0.0
    params, per_ray, ckpt = field_memory(config.field, model_config(config))
    spike_rays = config.spike.window * config.spike.pixels if method.uses_spike_loss else 0
    rays = (config.rays_per_step() + spike_rays) * per_ray
    cache = float(steps) * k.height * k.width * method.channels * 2 if learned_cache(method) else 0
    sizes = "batch/spike.window/spike.pixels" if spike_rays else "batch"
    sizes = sizes if rays >= params else "field_config"
    check_resources(targets + params + rays, 2 * ckpt + cache, out, sizes)


def check_step_memory(
    config: TrainConfig, method: Any, device: torch.device, free: int | None = None
) -> None:
    """Refuse, before any work, a step whose rays (the batch and a spike window) do not fit in a CUDA
    device's free memory by estimate (:func:`spikenerf.train.device.check_batch_fits`)."""
    check_batch_fits(config.field, model_config(config), *step_size(config, method), device, free)


def step_size(config: TrainConfig, method: Any) -> tuple[int, float]:
    """(rays, parameter bytes) of a training step: the batch and a spike window's rays; the field's
    parameters with their gradients and Adam state (:func:`spikenerf.train.device.batch_bytes`)."""
    spike_rays = config.spike.window * config.spike.pixels if method.uses_spike_loss else 0
    params, _, _ = field_memory(config.field, model_config(config))
    return config.rays_per_step() + spike_rays, params


def gpu_default_batch(
    given: TrainConfig, config: TrainConfig, device: torch.device, free: int | None = None
) -> TrainConfig:
    """``config`` with the CUDA default batch (``given.rays_per_step("cuda")``, 4× the CPU one) where
    ``given`` named no batch, the run trains on CUDA and that step fits the device's ``free`` bytes (None:
    read from the device) by estimate; else ``config`` unchanged (its batch the CPU default, or the one
    asked for or stored)."""
    if given.batch is not None or device.type != "cuda":
        return config
    wide = dataclasses.replace(config, batch=given.rays_per_step("cuda"))
    try:
        check_step_memory(wide, make_method(wide), device, free)
    except InputError:
        return config
    return wide


class Trainer:
    """Holds the model, optimiser, targets and samplers of one run folder.

    Args:
        config: a validated :class:`TrainConfig`. out: the run folder.
        dataset: an already-loaded dataset (else ``config.dataset`` is loaded). resume: continue from
            ``out/checkpoint.pt`` if present (else start fresh). progress: show a tqdm bar.
    """

    def __init__(
        self,
        config: TrainConfig,
        out: str | Path,
        dataset: SpikeDataset | None = None,
        resume: bool = False,
        progress: bool = True,
    ) -> None:
        check_api_args(config, out, dataset)
        config = _dataset_recorded(config, dataset)
        self.out = Path(out)
        check_output(self.out, "run", overwrite=True)  # (train() checks it too: a Trainer made alone)
        self.progress = progress
        ckpt_path = self.out / CHECKPOINT
        ckpt = None
        curves: list[dict[str, float]] = []  # curves.csv's rows, read (and checked) on a resume
        if ckpt_path.exists():
            if not resume:
                raise InputError(
                    "already holds a training run; pass resume or choose a new out folder",
                    self.out,
                    param=("resume", "out"),
                )
            ckpt = load_checkpoint(ckpt_path)
            # a dataset moved elsewhere may be given where the checkpoint's fingerprint checks its files
            movable = ("dataset",) if "content" in (ckpt.get("dataset") or {}) else ()
            stored_given = _stored_and_given(self.out / CONFIG_FILE, config)
            config = _check_resume(*stored_given, self.out / CONFIG_FILE, movable)
            check_same_run(ckpt, config.to_dict(), ckpt_path)  # not another run's checkpoint copied in
            curves = read_curves(self.out / CURVES)  # before any work: a garbled one refused, 0 bytes []
        self.device = resolve_device(config.device)
        self.config = config.validate().resolved()
        self.dataset = dataset if dataset is not None else load_dataset(config.dataset)
        self.config = method_class(self.config.method).for_dataset(self.config, self.dataset).validate()
        if ckpt is not None:  # the same dataset, and not fewer iterations than already done
            check_resume_fits(ckpt, self.config, self.dataset)
        self.config = gpu_default_batch(config, self.config, self.device)
        if self.config.amp == "fp16" and self.device.type != "cuda" and ckpt is None:  # it runs (CPU tests)
            warn(
                "--amp fp16 is meant for CUDA (with its gradient scaler); "
                f"on {self.device.type} use --amp bf16"
            )
        check_train_resources(self.config, self.dataset, self.out)
        self.method = make_method(self.config)
        check_step_memory(self.config, self.method, self.device)
        field_cfg = model_config(self.config)
        if hasattr(field_cfg, "check_device"):  # e.g. the grid's Triton lookup needs CUDA
            field_cfg.check_device(self.device)
        cache = self.out if learned_cache(self.method) else None
        if cache is not None:
            mark(self.out, "run")  # the cache is written into a marked run folder
        with learned_targets_in(cache, self.device, dataset_fingerprint(self.dataset)):
            self.method.build_targets(self.dataset)  # learned targets: on the training device, cached
        holdout = self.method.hold_out(self.dataset)
        self.holdout = None if holdout is None else holdout.record(self.dataset.trajectory.steps)
        unheld = [f"--{k.replace('_', '-')}" for k in ("holdout_steps", "holdout_radius")
                  if getattr(self.config, k) != getattr(TrainConfig, k)]  # fmt: skip
        if holdout is None and unheld and ckpt is None:  # (on for imported datasets; --holdout elsewhere)
            warn(f"{', '.join(unheld)}: this run holds out no steps (--holdout turns the hold-out on)")
        self.height, self.width = self.dataset.intrinsics.height, self.dataset.intrinsics.width
        self.channels = self.method.channels
        self.test_views = eval_view_targets(self.dataset, config.color, config.eval_views)
        held = 0 if self.dataset.test is None else len(self.dataset.test.images)
        if (
            config.eval_views > held and config.eval_views != TrainConfig.eval_views and ckpt is None
        ):  # (asked)
            views = f"{held} test view{'' if held == 1 else 's'}"
            warn(f"--eval-views {config.eval_views}: the dataset has {views}; evaluating {held}")
        self.samplers: dict[str, Any] = self.method.make_samplers(self.height, self.width)
        torch.manual_seed(config.seed)
        if ckpt is None:
            self.model = build_model(
                config.field, self.channels, self.dataset.scene_box, model_config(config)
            )
        else:  # the stored model, computed with this run's kernels (RESUMABLE_FIELD)
            self.model = model_of({**ckpt, "hparams": with_kernels(ckpt["hparams"], field_cfg)}, ckpt_path)
        self.model.to(self.device)
        self.model.field.prepare()  # the fused CPU kernel's first build is not training time
        if self.config.compile and not static_samples(self.model):  # eager again, with a warning, on failure
            compile_field(self.model.field, warn)
        self.optimizer = make_optimizer(self.model, config)
        #: --compile-optimizer: the compiled Adam update (None: ``optimizer.step`` eagerly)
        self.adam_step = (
            CompiledAdamStep(self.optimizer, warn, compiles_needed(self.model))
            if config.compile_optimizer
            else None
        )
        self.pose_refine = pose_refinement(
            self.config, self.dataset, self.model, self.device, self.method.targets
        )
        #: pose parameters with their own optimisers, by checkpoint key
        self.learners = {
            name: learner
            for name, learner in (
                ("poses", self.pose_refine),
                ("exposure_poses", self.method.learner(self.device)),
            )
            if learner is not None
        }
        # what stays resident leaves room for the step (its rays, gradients and Adam state, not allocated yet)
        step = batch_bytes(self.config.field, model_config(self.config), *step_size(self.config, self.method))
        self.resident = keep_targets_on_device(self.method, self.device, reserve=step)
        if self.config.compile and static_samples(self.model):  # the whole device part of the step instead
            compile_step(self.method, self.model, self.device, warn)
        self.iteration, self.elapsed, self.rays = 0, 0.0, 0
        self.told_dropped = False  # tell_dropped's one warning
        self.interval = RunningMeans()  # the train PSNR's running sums since the last evaluation
        self.curves: list[dict[str, float]] = []
        self.final_ratio = _lr_final_ratio(self.config, self.model)
        self.scaler = torch.amp.GradScaler(self.device.type, enabled=self.config.amp == "fp16")
        if ckpt is not None:
            check_optimizer_fits(self.optimizer, ckpt["optimizer"], ckpt_path)  # (a misfit one crashes)
            try:
                self._restore(ckpt, curves)
            except torch.cuda.OutOfMemoryError:  # (a RuntimeError, but no damage: the device is full)
                raise
            except (KeyError, TypeError, ValueError, AttributeError, IndexError, RuntimeError) as err:
                first = str(err).strip().split("\n")[0][:200]
                raise InputError(
                    f"damaged checkpoint: its training state does not load ({type(err).__name__}: {first})",
                    path=ckpt_path,
                ) from err

    def _restore(self, ckpt: dict[str, Any], curves: list[dict[str, float]]) -> None:
        """Continue from ``ckpt``: the optimisers' and samplers' states, the counters and running means."""
        means = ckpt.get("interval_means", {"sums": {}, "counts": {}})  # absent from older checkpoints
        self.interval.sums = {k: v.to(self.device) for k, v in means["sums"].items()}
        self.interval.counts = {k: int(v) for k, v in means["counts"].items()}
        load_state(self.optimizer, ckpt["optimizer"])  # this run's implementation flags kept
        match_state_layout(self.optimizer)
        for name, learner in self.learners.items():
            learner.load_state_dict(ckpt[name])
        restore_rng(ckpt["rng"], self.samplers)
        self.iteration, self.elapsed = int(ckpt["iteration"]), float(ckpt["elapsed"])
        self.rays = int(ckpt["rays"])
        self.curves = [r for r in curves if r["iteration"] <= self.iteration]
        if ckpt.get("scaler"):  # fp16 loss scale and growth tracker (absent: older)
            self.scaler.load_state_dict(ckpt["scaler"])

    # ------------------------------------------------------------------------------------------------- steps
    def render_rays(self, poses: torch.Tensor, pixels: torch.Tensor, perturb: bool = True) -> RenderOutput:
        """Render the rays through ``pixels`` (N, 2) int ``(x, y)`` of cameras ``poses`` (N, 4, 4)."""
        origins, dirs = pixel_rays(poses.to(self.device), self.dataset.intrinsics, pixels.to(self.device))
        near, far = ray_bounds(self.model, origins, dirs, self.dataset.near, self.dataset.far)
        return self.model.render_rays(origins, dirs, near, far, perturb=perturb)

    # -------------------------------------------------------------------------------------------------- loop
    def evaluate(self, renders: list | None = None) -> float:
        """Mean PSNR (dB, sRGB-encoded [0, 1]) over the evaluation views; NaN without test views.
        ``renders`` (if given) receives each (rendering, target)."""
        if self.test_views is None:
            return math.nan
        views = self.test_views if self.pose_refine is None else self.pose_refine.views(self.test_views)
        with torch.random.fork_rng(devices=[]):
            return evaluate_views(self.model, views, self.dataset, renders=renders)

    def backward(self, step: StepLosses, loss: torch.Tensor, it: int) -> tuple[StepLosses, torch.Tensor]:
        """``loss.backward()`` (scaled); returns the step and loss that were differentiated. The compiled
        step's backward is compiled (or its CUDA graph captured) at its first call: if that fails, the
        step goes eager for good (one warning line) and this iteration's losses are computed again eagerly.
        A failure after a compiled backward has run, or of an eager one, propagates."""
        compiled = vars(self.method).get("step_losses")
        first = isinstance(compiled, CompiledStep) and compiled.failed is None and not compiled.backward_ran
        try:
            self.scaler.scale(loss).backward()
        except Exception as err:  # a compiler or capture failure: the eager step is a correct answer
            if not first:
                raise
            compiled.fail(one_line(f"{type(err).__name__}: {err}"))
            self.optimizer.zero_grad(set_to_none=True)
            with autocast(self.device, self.config.amp):
                step = self.method.losses(self, it)
                loss = step.total()
            self.scaler.scale(loss).backward()
        if first:
            compiled.backward_ran = True
        return step, loss

    def non_finite(self) -> str | None:
        """The name of the first model parameter holding a NaN or an infinity (None: all finite)."""
        return next((n for n, p in self.model.named_parameters() if not p.isfinite().all()), None)

    def diverged(self, what: str) -> NoReturn:
        """InputError naming the rate: the run diverged (``what``); nothing of it is checkpointed."""
        kept = (
            "an earlier checkpoint is kept"
            if (self.out / CHECKPOINT).exists()
            else "no checkpoint was written"
        )
        raise InputError(
            f"training diverged by iteration {self.iteration} ({what}); {kept}: lower lr",
            path=self.out,
            param="lr",
        )

    def checkpoint(self) -> None:
        """Write ``checkpoint.pt`` atomically (model, optimiser, iteration, RNG states, config)."""
        save_checkpoint(
            self.out / CHECKPOINT,
            {
                "iteration": self.iteration,
                "elapsed": self.elapsed,
                "rays": self.rays,
                "interval_means": {"sums": self.interval.sums, "counts": self.interval.counts},
                "dataset": dataset_fingerprint(self.dataset),
                "model": self.model.state_dict(),
                "hparams": self.model.hparams(),
                "optimizer": self.optimizer.state_dict(),
                "scaler": self.scaler.state_dict(),  # {} unless --amp fp16
                "rng": rng_state(self.samplers),
                "config": self.config.to_dict(),
                "poses": None,  # replaced by the refinement's state when --refine-poses is on
                **{name: learner.state_dict() for name, learner in self.learners.items()},
            },
        )
        for learner in self.learners.values():
            learner.write(self.out)

    def train(self, stop_after: int | None = None) -> TrainSummary:
        """Run until ``config.iters`` (or ``stop_after`` more iterations, to simulate an interruption)."""
        check_stop_after(stop_after)
        cfg = self.config
        # first: a missing package leaves no run folder behind
        log = open_log(cfg.log, self.out, self.iteration)
        self.out.mkdir(parents=True, exist_ok=True)
        save_config(cfg, self.out / CONFIG_FILE)
        write_record(self.out, self.holdout)
        mark(self.out, "run")
        end = cfg.iters if stop_after is None else min(cfg.iters, self.iteration + stop_after)
        bar = progress_bar(
            total=cfg.iters, initial=self.iteration, desc="train", unit="it", show=self.progress
        )
        recent, interval = RunningMeans(), self.interval
        train_psnr, started = math.nan, self.iteration
        test_psnr = self.curves[-1]["test_psnr"] if self.curves else math.nan
        while self.iteration < end:
            it = self.iteration
            t0 = time.perf_counter()
            set_learning_rate(self.optimizer, it, cfg.iters, self.final_ratio)
            with autocast(self.device, cfg.amp):
                step = self.method.losses(self, it)
                loss = step.total()
            lam = self.method.lam(it)
            self.optimizer.zero_grad(set_to_none=True)
            for learner in self.learners.values():
                learner.begin(it)
            if loss.requires_grad:  # False only if every sample was culled (e.g. an empty occupancy grid)
                step, loss = self.backward(step, loss, it)
                if self.adam_step is not None:  # never with fp16's scaler (TrainConfig.validate)
                    self.adam_step()
                else:
                    self.scaler.step(self.optimizer)
                for learner in self.learners.values():
                    self.scaler.step(learner.optimizer)
                self.scaler.update()
            self.iteration = it + 1
            if self.model.on_step(self.iteration, self.optimizer):
                self.optimizer = make_optimizer(self.model, cfg)
                if self.adam_step is not None:
                    self.adam_step.use(self.optimizer)
            self.elapsed += time.perf_counter() - t0
            self.rays += step.rays
            for means in (recent, interval):
                means.add({"loss": loss, **step.terms, "srgb_mse": step.srgb_mse})
            if step.dropped is not None:  # static_samples: slots cut a ray, read with the log's values
                recent.add({DROPPED: step.dropped / max(step.rays, 1)})
            bar.update()
            last = self.iteration == cfg.iters
            if self.iteration % cfg.log_every == 0 or last:  # the only per-step read of device values
                m = recent.read()
                if not math.isfinite(m["loss"]) and cfg.amp != "fp16":  # fp16's scaler skips such steps
                    bar.close()
                    self.diverged(f"loss {m['loss']}")
                dropped = m.pop(DROPPED, 0.0)
                self.tell_dropped(dropped)
                bar.set_postfix(loss=f"{m['loss']:.4f}", psnr=f"{mse_to_psnr(m['srgb_mse']):.2f}",
                                rays_s=f"{self.rays_per_second:.0f}")  # fmt: skip
                if log is not None:
                    log.scalars(self.iteration, step_scalars(m, lam, self.optimizer, self.rays_per_second))
                    if static_samples(self.model):
                        log.scalars(self.iteration, {"render/dropped_samples_per_ray": dropped})
            if (cfg.eval_every and self.iteration % cfg.eval_every == 0) or last:
                renders: list | None = [] if log is not None else None
                m = interval.read()
                train_psnr, test_psnr = mse_to_psnr(m["srgb_mse"]), self.evaluate(renders)
                terms_mean = {k: m.get(k, math.nan) for k in LOSS_COLUMNS}
                self.curves.append(
                    {
                        "iteration": self.iteration,
                        "seconds": self.elapsed,
                        "train_psnr": train_psnr,
                        "test_psnr": test_psnr,
                        **terms_mean,
                        "lambda": lam,
                    }
                )
                write_curves(self.out / CURVES, self.curves)
                if log is not None:
                    log.scalars(self.iteration, {"psnr/train": train_psnr, "psnr/test": test_psnr})
                    log.images(self.iteration, renders or [])
            if self.iteration % cfg.ckpt_every == 0 or last or self.iteration == end:
                scheduled = self.iteration % cfg.ckpt_every == 0 or last  # (a stop_after pause reads nothing)
                if scheduled and (bad := self.non_finite()) is not None:
                    bar.close()
                    self.diverged(f"{bad} is not finite")
                self.checkpoint()
            failpoint("train.iteration")
        if log is not None:
            log.close()
        bar.close()
        if self.iteration >= cfg.iters and not (self.out / CHECKPOINT).exists():
            self.checkpoint()
        if "srgb_mse" in (m := interval.read()):
            train_psnr = mse_to_psnr(m["srgb_mse"])
        elif self.curves:
            train_psnr = self.curves[-1]["train_psnr"]
        if self.iteration == started and (stored := stored_summary(self.out, self.iteration)) is not None:
            return stored  # a finished run resumed: its summary as written, not rounded from curves.csv
        scored = 0 if self.test_views is None else len(self.test_views.images)
        held = 0 if self.dataset.test is None else len(self.dataset.test.images)
        summary = TrainSummary(
            self.iteration, self.elapsed, self.rays_per_second, train_psnr, test_psnr, str(self.device),
            scored, held,
        )  # fmt: skip
        if self.iteration >= cfg.iters:
            data = {
                k: None if isinstance(v, float) and not math.isfinite(v) else v
                for k, v in dataclasses.asdict(summary).items()
            }
            write_text_atomic(self.out / SUMMARY, json.dumps(data, indent=2) + "\n")
        return summary

    def tell_dropped(self, per_ray: float) -> None:
        """One warning line, the first time the ``static_samples`` budget cut samples (``per_ray``: slots
        cut a ray, averaged over the steps since the last log), with a budget that would have held them."""
        if per_ray <= 0 or self.told_dropped:
            return
        self.told_dropped = True
        budgets = {"static_samples": static_samples(self.model)}
        visible = int(getattr(self.model.field.config, "static_visible", 0) or 0)
        if visible:  # either budget may have cut: raise both
            budgets["static_visible"] = visible
        now = " ".join(f"{k}={v}" for k, v in budgets.items())
        enough = " ".join(f"--field-option {k}={math.ceil(1.25 * (v + per_ray))}" for k, v in budgets.items())
        warn(
            f"{now} cut {per_ray:.2f} samples a ray (averaged over the last {self.config.log_every} steps,"
            f" iteration {self.iteration}): far parts of rays are not rendered; {enough} would hold them"
        )

    @property
    def rays_per_second(self) -> float:
        return self.rays / self.elapsed if self.elapsed > 0 else 0.0


def train(
    config: TrainConfig,
    out: str | Path,
    dataset: SpikeDataset | None = None,
    resume: bool = False,
    progress: bool = True,
    stop_after: int | None = None,
    notes: Sequence[str] = (),
) -> TrainSummary:
    """Train ``config`` into the run folder ``out`` (see :class:`Trainer`), holding its writer lock.

    ``out`` must be new, empty or a run folder; ``resume`` needs it to exist. Temporaries that a killed
    writer left in it are removed first. A folder this call created is removed again when the setup is
    refused.

    Args:
        config: the settings; ``config.dataset`` names the data folder (``config.yaml`` records its
            absolute path, so that ``load_run`` finds it from any working directory).
        out: the run folder. dataset: an already-loaded dataset to train on instead of loading
            ``config.dataset`` (which must then be empty or the same folder).
        resume: continue from ``out``'s checkpoint. progress: a progress bar.
        stop_after: run at most this many iterations in this call, counted from where it starts (a resume
            at 25 with ``stop_after=20`` stops at 45), then write the checkpoint and return; None: up to
            ``config.iters``.
        notes: warning lines shown once the setup succeeded (a refused setup shows its one error line
            alone).
    Returns:
        The run's :class:`TrainSummary` (also in ``out/summary.json``).
    """
    check_api_args(config, out, dataset)
    check_stop_after(stop_after)
    out = Path(out)
    if resume and not out.is_dir():
        raise InputError("resume: no run folder here to resume (start one without it)", out, param="resume")
    check_output(out, "run", overwrite=True)
    with output_lock(out):
        check_output(out, "run", overwrite=True)
        if owned(out):  # a folder of ours (one recognised by its files alone may be a user's)
            clean_stale_temps(out)
        state = fresh_state(out)
        try:
            trainer = Trainer(config, out, dataset, resume, progress)
        except Exception:  # refused or failed setting up (e.g. after caching learned targets): nothing stays
            discard_fresh(out, state)
            raise
        for note in notes:
            warn(note)
        return trainer.train(stop_after)

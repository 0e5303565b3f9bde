"""A training run: :class:`Trainer` sets up one run folder (targets, model, optimiser, samplers, pose
learners; restored from ``RUN/checkpoint.pt`` on a resume), renders rays for the method and checkpoints;
:func:`train` runs it under the folder's writer lock.

The method (:mod:`spikenerf.train.methods`) builds the targets and returns each step's named loss terms
(``recon``, ``reg`` and, for spike-nerf once λ(it) > 0, ``spike``); the step loop
(:mod:`spikenerf.train.loop`) sums them, steps the optimiser, logs the terms and checkpoints. What is checked
before any work is :mod:`spikenerf.train.preflight`; what a resume may change, :mod:`spikenerf.train.resume`.
A run interrupted at any point resumes from ``RUN/checkpoint.pt`` to the same parameters as an uninterrupted
one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any, NoReturn

import torch

from spikenerf.core.atomic import clean_stale_temps
from spikenerf.core.device import resolve_device
from spikenerf.core.errors import InputError
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import check_output, mark, owned
from spikenerf.core.replacement import discard_fresh, fresh_state
from spikenerf.data.dataset import SpikeDataset, load_dataset
from spikenerf.data.holdout import read_record
from spikenerf.data.rays import pixel_rays
from spikenerf.data.recon_cache import learned_targets_in
from spikenerf.data.targets import eval_view_targets
from spikenerf.fields.compiled import compile_field
from spikenerf.render.model import build_model, ray_bounds
from spikenerf.render.volume import RenderOutput
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
from spikenerf.train.compiled_optim import CompiledAdamStep, load_state
from spikenerf.train.compiled_step import compile_step, compiles_needed, static_samples
from spikenerf.train.config import TrainConfig
from spikenerf.train.config_file import CONFIG_FILE
from spikenerf.train.device import batch_bytes, keep_targets_on_device
from spikenerf.train.evaluate import CURVES, evaluate_views, read_curves
from spikenerf.train.logger import RunningMeans, tell, warn
from spikenerf.train.loop import train_steps
from spikenerf.train.methods import make_method, method_class
from spikenerf.train.optimizer import lr_final_ratio, make_optimizer
from spikenerf.train.pose_refine import pose_refinement
from spikenerf.train.preflight import (
    check_api_args,
    check_step_memory,
    check_stop_after,
    check_train_resources,
    dataset_recorded,
    gpu_default_batch,
    learned_cache,
    model_config,
    step_size,
)
from spikenerf.train.resume import began_uncut, check_resume, stored_and_given, with_kernels
from spikenerf.train.run import TrainSummary, check_resume_fits, dataset_fingerprint


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
        config = dataset_recorded(config, dataset)
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
            stored_given = stored_and_given(self.out / CONFIG_FILE, config)
            config = check_resume(*stored_given, self.out / CONFIG_FILE, movable)
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
        whole = ckpt is not None and began_uncut(self.out, self.config.targets.recon)
        began = (read_record(self.out) or {}).get("radius") if ckpt is not None else None  # (its bands)
        holdout = self.method.hold_out(self.dataset, whole, began)  # (first: TFI, TFSTP targets cut at it)
        if whole and holdout is not None:
            recon = self.config.targets.recon
            warn(f"this run began with {recon} targets of the whole stream, not cut at the hold-out's bands: "
                 "it resumes so (eval scores its checks as such)")  # fmt: skip
        with learned_targets_in(cache, self.device, dataset_fingerprint(self.dataset)):
            self.method.build_targets(self.dataset)  # learned targets: on the training device, cached
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
        #: parameters with their own optimisers (poses, the method's own), by checkpoint key
        self.learners = {
            name: learner
            for name, learner in (
                ("poses", self.pose_refine),
                (self.method.learner_key, self.method.learner(self.device)),
            )
            if learner is not None
        }
        # what stays resident leaves room for the step (its rays, gradients and Adam state, not allocated yet)
        step = batch_bytes(self.config.field, model_config(self.config), *step_size(self.config, self.method))
        self.resident = keep_targets_on_device(self.method, self.device, reserve=step)
        if self.config.compile and static_samples(self.model):  # the whole device part of the step instead
            compile_step(self.method, self.model, self.device, warn)
        self.iteration, self.elapsed, self.rays = 0, 0.0, 0
        self.told_dropped = False  # loop.tell_dropped's one warning
        self.interval = RunningMeans()  # the train PSNR's running sums since the last evaluation
        self.curves: list[dict[str, float]] = []
        self.final_ratio = lr_final_ratio(self.config, self.model)
        self.scaler = torch.amp.GradScaler(self.device.type, enabled=self.config.amp == "fp16")
        self.resumed = ckpt is not None  # (train() says where it resumes)
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

    # ----------------------------------------------------------------------------------- evaluate, checkpoint
    def evaluate(self, renders: list | None = None) -> float:
        """Mean PSNR (dB, sRGB-encoded [0, 1]) over the evaluation views; NaN without test views.
        ``renders`` (if given) receives each (rendering, target)."""
        if self.test_views is None:
            return math.nan
        views = self.test_views if self.pose_refine is None else self.pose_refine.views(self.test_views)
        with torch.random.fork_rng(devices=[]):
            return evaluate_views(self.model, views, self.dataset, renders=renders)

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
        """Write ``checkpoint.pt`` atomically (model, optimiser, iteration, RNG states, config without the
        dataset folder, which ``config.yaml`` names)."""
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
                # config.yaml names the dataset folder (rewritten where a run is shipped or moved); a path
                # kept in here would still name the machine and folder that trained it
                "config": {**self.config.to_dict(), "dataset": ""},
                "poses": None,  # replaced by the refinement's state when --refine-poses is on
                **{name: learner.state_dict() for name, learner in self.learners.items()},
            },
        )
        for learner in self.learners.values():
            learner.write(self.out)

    def train(self, stop_after: int | None = None) -> TrainSummary:
        """Run until ``config.iters`` (or ``stop_after`` more iterations, to simulate an interruption)."""
        return train_steps(self, stop_after)

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

    ``out`` must be new, empty or a run folder; ``resume`` needs a run folder (a missing or empty ``out``
    holds no run to continue: refused, never a new run started silently). Temporaries that a killed writer
    left in it are removed first. A folder this call created is removed again when the setup is refused.

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
    state = fresh_state(out)
    if resume and (not out.is_dir() or state == "empty"):  # nothing to continue (never a new run started)
        where = "in this empty folder" if state == "empty" else "folder here"
        raise InputError(f"resume: no run {where} to resume (start one without it)", out, param="resume")
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
        if trainer.resumed:
            tell(resume_line(trainer))
        for note in notes:
            warn(note)
        return trainer.train(stop_after)


def resume_line(trainer: Trainer) -> str:
    """Where a resumed run continues: ``resuming RUN at iteration 60 of 70 (checkpoint written
    2026-01-02T03:04:05+00:00, after 12.3 s of training)``; train's last line counts the whole run."""
    done, iters = trainer.iteration, trainer.config.iters
    written = datetime.fromtimestamp((trainer.out / CHECKPOINT).stat().st_mtime).astimezone()
    left = "" if done < iters else ": it has finished, nothing left to train"
    return (
        f"resuming {trainer.out} at iteration {done} of {iters} (checkpoint written "
        f"{written.isoformat(timespec='seconds')}, after {trainer.elapsed:.1f} s of training){left}"
    )

"""The step loop of a run: one optimisation step after another (the method's summed loss terms, backward,
Adam, the pose learners, the learning-rate decay), with the periodic work between steps: the log's values
read every ``log_every`` steps, an evaluation into ``curves.csv`` every ``eval_every``, a checkpoint every
``ckpt_every`` (each refused when the run diverged), and the run's summary at the end.

The functions take the :class:`~spikenerf.train.trainer.Trainer` that holds the run's state (its model,
optimiser, method, learners, counters and run folder) and advance it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from typing import Any

import torch

from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import one_line
from spikenerf.core.faults import failpoint
from spikenerf.core.marker import mark
from spikenerf.core.progress import bar as progress_bar
from spikenerf.data.holdout import write_record
from spikenerf.train.amp import autocast
from spikenerf.train.checkpoint import CHECKPOINT
from spikenerf.train.compiled_step import CompiledStep, static_samples
from spikenerf.train.config_file import CONFIG_FILE, save_config
from spikenerf.train.evaluate import CURVES, LOSS_COLUMNS, write_curves
from spikenerf.train.logger import RunningMeans, open_log, step_scalars, warn
from spikenerf.train.losses import mse_to_psnr
from spikenerf.train.methods import StepLosses
from spikenerf.train.optimizer import make_optimizer, set_learning_rate
from spikenerf.train.preflight import check_stop_after
from spikenerf.train.run import SUMMARY, TrainSummary, stored_summary

#: the running mean of the static budget's cut slots a ray (read every ``log_every`` steps; not in curves)
DROPPED = "dropped_per_ray"


def train_steps(trainer: Any, stop_after: int | None = None) -> TrainSummary:
    """``Trainer.train``: run ``trainer`` until ``config.iters`` (or ``stop_after`` more iterations, to
    simulate an interruption)."""
    check_stop_after(stop_after)
    cfg = trainer.config
    # first: a missing package leaves no run folder behind
    log = open_log(cfg.log, trainer.out, trainer.iteration)
    trainer.out.mkdir(parents=True, exist_ok=True)
    save_config(cfg, trainer.out / CONFIG_FILE)
    write_record(trainer.out, trainer.holdout)
    mark(trainer.out, "run")
    end = cfg.iters if stop_after is None else min(cfg.iters, trainer.iteration + stop_after)
    bar = progress_bar(
        total=cfg.iters, initial=trainer.iteration, desc="train", unit="it", show=trainer.progress
    )
    recent, interval = RunningMeans(), trainer.interval
    train_psnr, started = math.nan, trainer.iteration
    test_psnr = trainer.curves[-1]["test_psnr"] if trainer.curves else math.nan
    while trainer.iteration < end:
        it = trainer.iteration
        t0 = time.perf_counter()
        set_learning_rate(trainer.optimizer, it, cfg.iters, trainer.final_ratio)
        with autocast(trainer.device, cfg.amp):
            step = trainer.method.losses(trainer, it)
            loss = step.total()
        lam = trainer.method.lam(it)
        trainer.optimizer.zero_grad(set_to_none=True)
        for learner in trainer.learners.values():
            learner.begin(it)
        if loss.requires_grad:  # False only if every sample was culled (e.g. an empty occupancy grid)
            step, loss = backward(trainer, step, loss, it)
            if trainer.adam_step is not None:  # never with fp16's scaler (TrainConfig.validate)
                trainer.adam_step()
            else:
                trainer.scaler.step(trainer.optimizer)
            for learner in trainer.learners.values():
                trainer.scaler.step(learner.optimizer)
            trainer.scaler.update()
        trainer.iteration = it + 1
        if trainer.model.on_step(trainer.iteration, trainer.optimizer):
            trainer.optimizer = make_optimizer(trainer.model, cfg)
            if trainer.adam_step is not None:
                trainer.adam_step.use(trainer.optimizer)
        trainer.elapsed += time.perf_counter() - t0
        trainer.rays += step.rays
        for means in (recent, interval):
            means.add({"loss": loss, **step.terms, "srgb_mse": step.srgb_mse})
        if step.dropped is not None:  # static_samples: slots cut a ray, read with the log's values
            recent.add({DROPPED: step.dropped / max(step.rays, 1)})
        bar.update()
        last = trainer.iteration == cfg.iters
        if trainer.iteration % cfg.log_every == 0 or last:  # the only per-step read of device values
            m = recent.read()
            if not math.isfinite(m["loss"]) and cfg.amp != "fp16":  # fp16's scaler skips such steps
                bar.close()
                trainer.diverged(f"loss {m['loss']}")
            dropped = m.pop(DROPPED, 0.0)
            tell_dropped(trainer, dropped)
            bar.set_postfix(loss=f"{m['loss']:.4f}", psnr=f"{mse_to_psnr(m['srgb_mse']):.2f}",
                            rays_s=f"{trainer.rays_per_second:.0f}")  # fmt: skip
            if log is not None:
                scalars = step_scalars(m, lam, trainer.optimizer, trainer.rays_per_second)
                log.scalars(trainer.iteration, scalars)
                if static_samples(trainer.model):
                    log.scalars(trainer.iteration, {"render/dropped_samples_per_ray": dropped})
        if (cfg.eval_every and trainer.iteration % cfg.eval_every == 0) or last:
            renders: list | None = [] if log is not None else None
            m = interval.read()
            train_psnr, test_psnr = mse_to_psnr(m["srgb_mse"]), trainer.evaluate(renders)
            terms_mean = {k: m.get(k, math.nan) for k in LOSS_COLUMNS}
            trainer.curves.append(
                {
                    "iteration": trainer.iteration,
                    "seconds": trainer.elapsed,
                    "train_psnr": train_psnr,
                    "test_psnr": test_psnr,
                    **terms_mean,
                    "lambda": lam,
                }
            )
            write_curves(trainer.out / CURVES, trainer.curves)
            if log is not None:
                log.scalars(trainer.iteration, {"psnr/train": train_psnr, "psnr/test": test_psnr})
                log.images(trainer.iteration, renders or [])
        if trainer.iteration % cfg.ckpt_every == 0 or last or trainer.iteration == end:
            scheduled = trainer.iteration % cfg.ckpt_every == 0 or last  # (a stop_after pause reads nothing)
            if scheduled and (bad := trainer.non_finite()) is not None:
                bar.close()
                trainer.diverged(f"{bad} is not finite")
            trainer.checkpoint()
        failpoint("train.iteration")
    if log is not None:
        log.close()
    bar.close()
    if trainer.iteration >= cfg.iters and not (trainer.out / CHECKPOINT).exists():
        trainer.checkpoint()
    if "srgb_mse" in (m := interval.read()):
        train_psnr = mse_to_psnr(m["srgb_mse"])
    elif trainer.curves:
        train_psnr = trainer.curves[-1]["train_psnr"]
    stored = stored_summary(trainer.out, trainer.iteration) if trainer.iteration == started else None
    if stored is not None:
        return stored  # a finished run resumed: its summary as written, not rounded from curves.csv
    scored = 0 if trainer.test_views is None else len(trainer.test_views.images)
    held = 0 if trainer.dataset.test is None else len(trainer.dataset.test.images)
    summary = TrainSummary(
        trainer.iteration, trainer.elapsed, trainer.rays_per_second, train_psnr, test_psnr,
        str(trainer.device), scored, held,
    )  # fmt: skip
    if trainer.iteration >= cfg.iters:
        data = {
            k: None if isinstance(v, float) and not math.isfinite(v) else v
            for k, v in dataclasses.asdict(summary).items()
        }
        write_text_atomic(trainer.out / SUMMARY, json.dumps(data, indent=2) + "\n")
    return summary


def backward(trainer: Any, step: StepLosses, loss: torch.Tensor, it: int) -> tuple[StepLosses, torch.Tensor]:
    """``loss.backward()`` (scaled); returns the step and loss that were differentiated. The compiled
    step's backward is compiled (or its CUDA graph captured) at its first call: if that fails, the
    step goes eager for good (one warning line) and this iteration's losses are computed again eagerly.
    A failure after a compiled backward has run, or of an eager one, propagates."""
    compiled = vars(trainer.method).get("step_losses")
    first = isinstance(compiled, CompiledStep) and compiled.failed is None and not compiled.backward_ran
    try:
        trainer.scaler.scale(loss).backward()
    except Exception as err:  # a compiler or capture failure: the eager step is a correct answer
        if not first:
            raise
        compiled.fail(one_line(f"{type(err).__name__}: {err}"))
        trainer.optimizer.zero_grad(set_to_none=True)
        with autocast(trainer.device, trainer.config.amp):
            step = trainer.method.losses(trainer, it)
            loss = step.total()
        trainer.scaler.scale(loss).backward()
    if first:
        compiled.backward_ran = True
    return step, loss


def tell_dropped(trainer: Any, per_ray: float) -> None:
    """One warning line, the first time the ``static_samples`` budget cut samples (``per_ray``: slots
    cut a ray, averaged over the steps since the last log), with a budget that would have held them."""
    if per_ray <= 0 or trainer.told_dropped:
        return
    trainer.told_dropped = True
    budgets = {"static_samples": static_samples(trainer.model)}
    visible = int(getattr(trainer.model.field.config, "static_visible", 0) or 0)
    if visible:  # either budget may have cut: raise both
        budgets["static_visible"] = visible
    now = " ".join(f"{k}={v}" for k, v in budgets.items())
    enough = " ".join(f"--field-option {k}={math.ceil(1.25 * (v + per_ray))}" for k, v in budgets.items())
    warn(
        f"{now} cut {per_ray:.2f} samples a ray (averaged over the last {trainer.config.log_every} steps,"
        f" iteration {trainer.iteration}): far parts of rays are not rendered; {enough} would hold them"
    )

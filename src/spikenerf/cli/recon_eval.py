"""``spikenerf recon-eval``: score TFP, TFI, TFSTP and the learned reconstruction against a simulated
dataset's sharp GT frames (PSNR, SSIM, LPIPS, linear errors); a table, and ``OUT/scores.json`` +
``OUT/scores.csv``.

A command of its own rather than ``reconstruct --score``: ``reconstruct`` reads a bare ``.dat`` recording
(its size, layout and row width given or beside it) and writes images, while scoring needs a dataset folder
(its streams, φ and the steps of its ``gt/`` frames) and writes scores; the names of the options they share
(``--window``, ``--weights``, ``--color``) are ``reconstruct``'s.
"""

from __future__ import annotations

from pathlib import Path

import click

from spikenerf.camera.modes import COLORS
from spikenerf.camera.reconstruct import DEFAULT_WINDOW
from spikenerf.cli.options import check_lpips_given, lpips_option
from spikenerf.cli.types import BoundedInt, OutPath
from spikenerf.data.reconstruction import RECONS

#: lower-layer parameters → the flags that set them
PARAM_FLAGS = {"dataset_root": "DATASET", "steps": "--steps"}


@click.command(
    help="Score TFP, TFI, TFSTP and the learned reconstruction against a simulated dataset's sharp gt/ "
    "frames (PSNR, SSIM, LPIPS; linear errors); writes OUT/scores.json and OUT/scores.csv."
)
@click.argument("dataset", type=click.Path(path_type=Path))
@click.option(
    "--methods", default=",".join(RECONS), show_default=True,
    help=f"Reconstructions to compare, comma-separated, among {', '.join(RECONS)}.",
)  # fmt: skip
@click.option(
    "--color", type=click.Choice(COLORS),
    help="The dataset's stream to reconstruct (bayer: scored as the RGGB mosaic) [default: its first].",
)  # fmt: skip
@click.option("--window", type=int, help=f"TFP window length in frames, odd [default: {DEFAULT_WINDOW}].")
@click.option("--weights", type=click.Path(path_type=Path), help="learned: weights file [default: shipped].")
@click.option(
    "--steps", "steps_range",
    help="Score the gt frames in this step range A:B (B exclusive; negative: from the end) [default: all].",
)  # fmt: skip
@click.option("--count", type=BoundedInt(1), help="At most N of the selected gt frames, evenly spread.")
@lpips_option
@click.option("--out", type=OutPath(), required=True, help="Folder for scores.json and scores.csv.")
@click.option("--overwrite", is_flag=True, help="Replace the scores of an earlier recon-eval in --out.")
@click.option("--quiet", "--no-progress", "quiet", is_flag=True, help="No progress bar.")
def command(
    dataset: Path, methods: str, color: str | None, window: int | None, weights: Path | None,
    steps_range: str | None, count: int | None, lpips_backbone: str, out: Path, overwrite: bool, quiet: bool,
) -> None:  # fmt: skip
    from spikenerf.cli import command_line
    from spikenerf.core.errors import parse_range
    from spikenerf.core.lock import output_lock
    from spikenerf.core.marker import check_inputs_outside, check_output, folder_kind, mark
    from spikenerf.eval.recon_scores import (
        pair_problem,
        parse_methods,
        score_reconstructions,
        scores_table,
        write_scores,
    )  # fmt: skip

    parse_methods(methods)  # (before anything is read)
    check_lpips_given(lpips_backbone)
    steps = parse_range(steps_range, "steps") if steps_range is not None else None
    unfinished = folder_kind(out) == "scores" and pair_problem(out) not in ("", "absent")
    check_output(out, "scores", overwrite=overwrite or unfinished)  # (an interrupted pair: written again)
    check_inputs_outside(out, [dataset, weights])
    result = score_reconstructions(
        dataset, methods, color=color, window=window, steps=steps, count=count, weights=weights,
        lpips_backbone=None if lpips_backbone == "none" else lpips_backbone, progress=not quiet,
        log=lambda msg: click.echo(msg, err=True),
    )  # fmt: skip
    result["command"] = command_line()
    if unfinished:
        click.echo(f"replacing the unfinished scores in {out} ({pair_problem(out)})", err=True)
    with output_lock(out):
        if folder_kind(out) != "scores":  # (first: a write cut short leaves a folder known as recon-eval's)
            mark(out, "scores")
        mark(out, "scores", write_scores(out, result))
    n = len(result["steps"])
    click.echo(
        f"{result['color']} stream, {n} gt step{'s' if n != 1 else ''} "
        f"({result['steps'][0]}..{result['steps'][-1]}), {result['space']}:"
    )
    for line in scores_table(result):
        click.echo(line)
    if result["lpips_reason"] and lpips_backbone != "none":
        click.echo(f"LPIPS not computed: {result['lpips_reason']}")
    click.echo(f"wrote {out / 'scores.json'}, {out / 'scores.csv'}")

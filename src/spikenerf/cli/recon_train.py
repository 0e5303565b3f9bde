"""``spikenerf recon-train PAIRS --out RUN``: train the learned reconstructor (resumable)."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import click

from spikenerf.cli.types import COUNT, SEED, OutPath
from spikenerf.recon.config import ReconTrainConfig

_D = ReconTrainConfig()


@click.command(
    help="Train the learned spike-to-image reconstructor on a pair folder written by `spikenerf recon-data`. "
    "Writes RUN/config.json, RUN/checkpoint.pt (atomic; re-running the same command resumes it), "
    "RUN/curves.csv (train L1, held-out PSNR of learned vs TFP) and at the end RUN/weights.pt (fp16) with "
    "RUN/weights.json recording the command and the data. Use the weights with "
    "`spikenerf reconstruct --method learned --weights RUN/weights.pt`."
)
@click.argument("pairs", type=click.Path(path_type=Path))
@click.option("--out", required=True, type=OutPath(), help="Run folder to write.")
@click.option("--iters", type=COUNT, default=_D.iters, show_default=True, help="Optimiser steps.")
@click.option("--batch", type=int, default=_D.batch, show_default=True, help="Crops per step.")
@click.option(
    "--crop",
    type=int,
    default=_D.crop,
    show_default=True,
    help="Crop side in pixels (a larger one takes the whole pair).",
)
@click.option("--lr", type=float, default=_D.lr, show_default=True, help="Adam learning rate (cosine decay).")
@click.option("--width", type=int, default=_D.width, show_default=True, help="Network channels at full size.")
@click.option("--seed", type=SEED, default=_D.seed, show_default=True)
@click.option(
    "--eval-every", type=int, default=_D.eval_every, show_default=True, help="Steps between val scores."
)
@click.option(
    "--ckpt-every", type=int, default=_D.ckpt_every, show_default=True, help="Steps between checkpoints."
)
def command(pairs: Path, out: Path, **options: float) -> None:
    from spikenerf.recon.training import train_recon

    cfg = ReconTrainConfig(**options)  # type: ignore[arg-type]
    command_line = "spikenerf " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    summary = train_recon(pairs, out, cfg, command_line)
    click.echo(
        f"wrote {out / 'weights.pt'}: held-out PSNR learned {summary['val_psnr_learned']:.2f} dB, "
        f"TFP {summary['val_psnr_tfp']:.2f} dB"
    )

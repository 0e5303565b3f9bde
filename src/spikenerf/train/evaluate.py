"""Evaluation during training (PSNR on held-out views) and the ``curves.csv`` log: PSNR and the mean loss
terms against training time."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import torch

from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.color import srgb_mse
from spikenerf.core.csvtable import read_table
from spikenerf.core.errors import InputError
from spikenerf.core.psnr import mse_to_psnr
from spikenerf.data.dataset import SpikeDataset
from spikenerf.data.targets import ImageTargets
from spikenerf.render.base import RadianceModel
from spikenerf.render.model import render_image

CURVES = "curves.csv"
COLUMNS = ("iteration", "seconds", "train_psnr", "test_psnr")
#: mean loss terms since the previous row (NaN when a term was not computed, e.g. before the spike loss)
LOSS_COLUMNS = ("loss", "recon", "spike", "reg", "lambda")


def srgb_psnr(pred: torch.Tensor, target: torch.Tensor) -> float:
    """PSNR (dB) between two linear images after sRGB encoding to display values in [0, 1]."""
    return mse_to_psnr(srgb_mse(pred, target).item())


@torch.no_grad()
def evaluate_views(
    model: RadianceModel,
    views: ImageTargets,
    dataset: SpikeDataset,
    chunk: int = 8192,
    renders: list[tuple[torch.Tensor, torch.Tensor]] | None = None,
) -> float:
    """Mean PSNR over ``views`` (their first pose each), rendered without perturbation; ``renders`` (if given)
    receives each (rendering, target), linear (H, W, C) on the CPU."""
    was_training = model.training
    model.eval()
    scores = []
    for pose, image in zip(views.poses[:, 0], views.images, strict=True):
        color = render_image(model, pose, dataset.intrinsics, dataset.near, dataset.far, chunk).color.cpu()
        scores.append(srgb_psnr(color, image))
        if renders is not None:
            renders.append((color, image))
    model.train(was_training)
    return sum(scores) / len(scores) if scores else math.nan


def write_curves(path: str | Path, rows: list[dict[str, float]]) -> None:
    """Rewrite ``curves.csv`` atomically: iteration, seconds (training time), train_psnr, test_psnr (dB),
    then the mean loss terms since the previous row (``LOSS_COLUMNS``; λ at the row's iteration)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(COLUMNS + LOSS_COLUMNS)
    for r in rows:
        writer.writerow(
            [int(r["iteration"]), f"{r['seconds']:.3f}", f"{r['train_psnr']:.4f}", f"{r['test_psnr']:.4f}"]
            + [f"{r.get(k, math.nan):.6g}" for k in LOSS_COLUMNS]
        )
    write_text_atomic(path, buf.getvalue())


def read_curves(path: str | Path) -> list[dict[str, float]]:
    """Rows of ``curves.csv`` (empty if the file does not exist or is empty; loss columns absent in older
    files → NaN). InputError naming the file when it is not such a table (a header without a column, a
    value that is no number, bytes that are not text).

    Only a file of zero bytes counts as empty, so that ``train --resume`` writes it again from its next
    evaluation: what a crash leaves of a file being written (``write_curves`` replaces it atomically, but a
    file system may still lose its data). A file with any content must be a curve table, its header line
    included: a header alone (no rows yet) is one; a line of anything else (a cut header, another tool's
    file) is refused like a table with a wrong header, not replaced: it is not what train writes, and
    replacing it would lose what it holds.
    """
    path = Path(path)
    aside = "move it aside to resume without the earlier curve points"
    if path.is_dir():  # (not replaced by the next write either: refused before the work)
        raise InputError(f"is a folder, not a training curve table ({aside})", path=path)
    if not path.is_file() or path.stat().st_size == 0:
        return []

    def header_problem(header: list[str]) -> str | None:
        missing = [k for k in COLUMNS if k not in header]
        return f"no column {missing[0]!r}" if missing else None

    def parse(header: list[str], row: list[str]) -> dict:
        r = dict(zip(header, row, strict=False))  # a row cut short lacks its last columns: None
        return {
            "iteration": int(r.get("iteration")),  # type: ignore[arg-type]
            **{k: float(r.get(k)) for k in COLUMNS[1:]},  # type: ignore[arg-type]
            **{k: float(r.get(k) or math.nan) for k in LOSS_COLUMNS},
        }

    return read_table(path, "training curve table", header_problem, parse, aside)

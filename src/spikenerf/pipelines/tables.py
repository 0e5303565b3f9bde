"""The paper's tables from per-run metrics: Table I (methods × scenes, gray and RGB) and Table II (ablation).

Pure functions over a list of :class:`Cell` results; the benchmark writes them as Markdown, CSV and JSON.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

#: metric name -> True when higher is better
HIGHER_IS_BETTER = {"ssim": True, "psnr": True, "lpips": False}

#: method variant -> label used in the tables (the paper's naming in brackets)
METHOD_LABELS = {
    "nerf-gt": "NeRF on sharp GT (oracle)",
    "nerf-blur": "NeRF on 400 fps blur",
    "nerf-blur-aware": "Exposure-aware NeRF (BAD-NeRF-like)",
    "nerf-recon": "NeRF + TFP reconstruction",
    "nerf-recon-learned": "NeRF + learned reconstruction (Spk2ImgNet+NeRF)",
    "spike-nerf": "Spike-NeRF (ours)",
    "spike-nerf-learned": "Spike-NeRF on learned targets",
    "spike-nerf-no-mask": "W/O spike masks",
    "spike-nerf-no-spike-loss": "W/O spike loss",
}
ABLATION_VARIANTS = ("spike-nerf-no-mask", "spike-nerf-no-spike-loss", "spike-nerf")


@dataclass(frozen=True)
class Cell:
    """One finished (scene, method variant, colour) run and its mean test metrics (None = not available)."""

    scene: str
    variant: str
    color: str
    psnr: float
    ssim: float
    lpips: float | None = None
    seconds: float | None = None


def _mean(values: Sequence[float | None]) -> float | None:
    vals = [v for v in values if v is not None and not math.isnan(v)]
    return sum(vals) / len(vals) if len(vals) == len(values) and vals else None


def _fmt(value: float | None, metric: str) -> str:
    if value is None:
        return "–"
    return f"{value:.2f}" if metric == "psnr" else f"{value:.3f}"


def rank_marks(values: dict[str, float | None], metric: str) -> dict[str, str]:
    """'best' / 'second' / '' per key, as the paper highlights (red best, yellow second).

    Args:
        values: key -> metric value (None is never ranked).
    """
    present = sorted(
        ((v, k) for k, v in values.items() if v is not None),
        reverse=HIGHER_IS_BETTER[metric],
        key=lambda x: x[0],
    )
    marks = dict.fromkeys(values, "")
    distinct = sorted({v for v, _ in present}, reverse=HIGHER_IS_BETTER[metric])
    for v, k in present:
        if v == distinct[0]:
            marks[k] = "best"
        elif len(distinct) > 1 and v == distinct[1]:
            marks[k] = "second"
    return marks


def _decorate(text: str, mark: str) -> str:
    return f"**{text}**" if mark == "best" else f"_{text}_" if mark == "second" else text


def table1_markdown(cells: Sequence[Cell], variants: Sequence[str], scenes: Sequence[str], color: str) -> str:
    """Table I block for one colour: rows = variants, columns = (SSIM, PSNR) per scene and their average.

    Best values are bold, second best italic (the paper's red and yellow).
    """
    lookup = {(c.scene, c.variant): c for c in cells if c.color == color}
    columns = [*scenes, "average"]
    header = "| method | " + " | ".join(f"{s} SSIM ↑ | {s} PSNR ↑" for s in columns) + " |"
    sep = "|---|" + "---:|---:|" * len(columns)
    table: dict[tuple[str, str, str], float | None] = {}
    for v in variants:
        for metric in ("ssim", "psnr"):
            per_scene = [getattr(lookup[(s, v)], metric) if (s, v) in lookup else None for s in scenes]
            for s, value in zip(scenes, per_scene, strict=True):
                table[(v, s, metric)] = value
            table[(v, "average", metric)] = _mean(per_scene)
    marks = {
        (s, m): rank_marks({v: table[(v, s, m)] for v in variants}, m)
        for s in columns
        for m in ("ssim", "psnr")
    }
    lines = [f"**{color.upper()}**", "", header, sep]
    for v in variants:
        row = [
            _decorate(_fmt(table[(v, s, m)], m), marks[(s, m)][v]) for s in columns for m in ("ssim", "psnr")
        ]
        lines.append(f"| {METHOD_LABELS.get(v, v)} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def table2_markdown(cells: Sequence[Cell], color: str) -> str:
    """Table II (ablation) for one colour: SSIM, PSNR, LPIPS averaged over scenes for the three variants."""
    rows = {v: [c for c in cells if c.variant == v and c.color == color] for v in ABLATION_VARIANTS}
    values = {
        (v, m): _mean([getattr(c, m) for c in rows[v]]) if rows[v] else None
        for v in ABLATION_VARIANTS
        for m in ("ssim", "psnr", "lpips")
    }
    marks = {
        m: rank_marks({v: values[(v, m)] for v in ABLATION_VARIANTS}, m) for m in ("ssim", "psnr", "lpips")
    }
    lines = [f"**{color.upper()}**", "", "| method | SSIM ↑ | PSNR ↑ | LPIPS ↓ |", "|---|---:|---:|---:|"]
    for v in ABLATION_VARIANTS:
        row = [_decorate(_fmt(values[(v, m)], m), marks[m][v]) for m in ("ssim", "psnr", "lpips")]
        lines.append(f"| {METHOD_LABELS[v]} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def cells_csv(cells: Sequence[Cell]) -> str:
    """All cells as CSV (one row per scene, variant and colour)."""
    buffer = io.StringIO()
    fields = list(asdict(cells[0]).keys()) if cells else [f for f in Cell.__dataclass_fields__]
    writer = csv.DictWriter(buffer, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for c in cells:
        writer.writerow(asdict(c))
    return buffer.getvalue()

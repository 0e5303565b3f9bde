"""The paper's tables from per-run metrics: Table I (methods × scenes, gray and RGB), Table II (ablation) and
the paired ``differences`` table, each a :class:`Table`, rendered as Markdown here and as HTML by the report.

Pure functions over a list of :class:`Cell` results. With several seeds a value is "mean ± std" over the seeds
(sample standard deviation); a scene average is the mean over scenes per seed, then mean ± std over seeds.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

from spikenerf.pipelines.benchmark.stats import HIGHER_IS_BETTER, Cell, Difference, Stat, summarize
from spikenerf.pipelines.benchmark.variants import ABLATION_VARIANTS, label

__all__ = ["HIGHER_IS_BETTER", "Cell", "Table"]

TRAINED_ON = "trained on"


@dataclass(frozen=True)
class Table:
    """A table for Markdown and HTML: ``rows`` are (label, [(text, mark)]); mark is '' (a number), 'best',
    'second', 'shown' (a verdict) or 'text' (a non-numeric column)."""

    header: list[str]
    rows: list[tuple[str, list[tuple[str, str]]]]


def decimals(metric: str) -> int:
    """Decimals a table prints of ``metric``: 2 for PSNR, 3 for SSIM and LPIPS."""
    return 2 if metric == "psnr" else 3


def fmt(stat: Stat | None, metric: str) -> str:
    """'–', the value, or 'mean ± std' (:func:`decimals` of them)."""
    if stat is None:
        return "–"
    digits = decimals(metric)
    text = f"{stat.mean:.{digits}f}"
    return text if stat.std is None else f"{text} ± {stat.std:.{digits}f}"


def rank_marks(values: dict[str, float | None], metric: str) -> dict[str, str]:
    """'best' / 'second' / '' per key, as the paper highlights (red best, yellow second).

    Args:
        values: key -> metric value (None is never ranked), ranked as printed (values that print the same
            get the same mark).
    """
    present = sorted(
        ((round(v, decimals(metric)), k) for k, v in values.items() if v is not None),
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


def scene_stats(
    cells: Sequence[Cell], variant: str, scenes: Sequence[str], color: str, metric: str
) -> dict[str, Stat | None]:
    """scene (and ``average``) -> mean ± std over seeds of ``metric`` for one variant and colour.

    The average uses the seeds that have every scene: per seed the mean over scenes, then over seeds.
    """
    per: dict[str, dict[int, float | None]] = {s: {} for s in scenes}
    for c in cells:
        if c.variant == variant and c.color == color and c.scene in per:
            per[c.scene][c.seed] = getattr(c, metric)
    out: dict[str, Stat | None] = {s: summarize(list(per[s].values())) for s in scenes}
    seeds = set.intersection(*(set(per[s]) for s in scenes)) if scenes else set()
    averages = []
    for seed in sorted(seeds):
        vals = [per[s][seed] for s in scenes]
        averages.append(None if any(v is None for v in vals) else sum(vals) / len(vals))  # type: ignore[arg-type]
    out["average"] = summarize(averages)
    return out


def _marked(stats: dict[tuple[str, str, str], Stat | None], variants: Sequence[str], cols, metrics) -> Table:
    """Rows of ``stats[(variant, column, metric)]`` with best/second marks per column (by the mean)."""
    means = {key: None if stat is None else stat.mean for key, stat in stats.items()}
    marks = {(s, m): rank_marks({v: means[(v, s, m)] for v in variants}, m) for s in cols for m in metrics}
    rows = [
        (
            label(v),
            [(fmt(stats[(v, s, m)], m), marks[(s, m)][v]) for s in cols for m in metrics],
        )
        for v in variants
    ]
    return Table([], rows)


def _with_trained_on(
    table: Table, header: list[str], trained_on: Mapping[str, str] | None, variants
) -> Table:
    if trained_on is None:
        return Table(header, table.rows)
    rows = [
        (label, [(trained_on.get(v, "–"), "text"), *vals])
        for (label, vals), v in zip(table.rows, variants, strict=True)
    ]
    return Table([header[0], TRAINED_ON, *header[1:]], rows)


def table1(
    cells: Sequence[Cell],
    variants: Sequence[str],
    scenes: Sequence[str],
    color: str,
    trained_on: Mapping[str, str] | None = None,
) -> Table:
    """Table I for one colour: rows = variants, (SSIM, PSNR) per scene and their average; best, second.

    ``trained_on`` (variant -> e.g. "1000 poses") adds a column with what each method trained on.
    """
    cols, metrics = [*scenes, "average"], ("ssim", "psnr")
    stats = {}
    for v in variants:
        for m in metrics:
            for s, stat in scene_stats(cells, v, scenes, color, m).items():
                stats[(v, s, m)] = stat
    header = ["method", *[f"{s} {m}" for s in cols for m in ("SSIM ↑", "PSNR ↑")]]
    return _with_trained_on(_marked(stats, variants, cols, metrics), header, trained_on, variants)


def table2(cells: Sequence[Cell], color: str, trained_on: Mapping[str, str] | None = None) -> Table:
    """Table II (ablation) for one colour: SSIM, PSNR, LPIPS averaged over scenes, mean ± std over seeds;
    a row for each ablation variant with cells of that colour (one never run is left out, as in Table I)."""
    metrics = ("ssim", "psnr", "lpips")
    variants = [v for v in ABLATION_VARIANTS if any(c.variant == v and c.color == color for c in cells)]
    scenes = sorted({c.scene for c in cells if c.color == color and c.variant in variants})
    stats = {
        (v, "average", m): scene_stats(cells, v, scenes, color, m)["average"] if scenes else None
        for v in variants
        for m in metrics
    }
    header = ["method", "SSIM ↑", "PSNR ↑", "LPIPS ↓"]
    return _with_trained_on(_marked(stats, variants, ["average"], metrics), header, trained_on, variants)


def _num(x: float | None, metric: str, sign: str = "+") -> str:
    """``x`` to the metric's table precision (2 decimals for PSNR, else 3), or to 2 significant digits where
    that precision would round it to 0 (a tiny but nonzero difference is not shown as 0)."""
    if x is None:
        return "–"
    digits = 2 if metric == "psnr" else 3
    if x != 0 and abs(x) < 0.5 * 10.0**-digits:
        return f"{x:{sign}#.2g}"
    return f"{x:{sign}.{digits}f}"


def differences_table(diffs: Sequence[Difference]) -> Table:
    """One row per (comparison, colour, metric): pairs, mean difference ± std, the 95% interval, verdict."""
    header = ["difference", "colour", "metric", "pairs", "mean ± std", "95% CI", "per-seed 95% CI", "verdict"]
    rows = []
    for d in diffs:
        name = f"{label(d.ours)} − {label(d.baseline)}"
        ci, seed_ci = (
            "–" if lo is None else f"[{_num(lo, d.metric)}, {_num(hi, d.metric)}]"
            for lo, hi in ((d.low, d.high), (d.seed_low, d.seed_high))
        )
        std = "" if d.std is None else f" ± {_num(d.std, d.metric, sign='')}"
        arrow = "↓" if not HIGHER_IS_BETTER[d.metric] else "↑"
        mark = "shown" if d.verdict == "shown" else ""
        values = [(d.color, "text"), (f"{d.metric.upper()} {arrow}", "text"), (str(d.n), ""),
                  (_num(d.mean, d.metric) + std, ""), (ci, ""), (seed_ci, ""), (d.verdict, mark)]  # fmt: skip
        rows.append((name, values))
    return Table(header, rows)


def to_markdown(table: Table, title: str = "") -> str:
    """The table as GitHub Markdown (best bold, second italic), under ``title`` when given."""

    def cell(text: str, mark: str) -> str:
        return f"**{text}**" if mark in ("best", "shown") else f"_{text}_" if mark == "second" else text

    align = "|".join("---" if i == 0 or mark == "text" else "---:" for i, (_, mark) in
                     enumerate([("", "text"), *(table.rows[0][1] if table.rows else [])]))  # fmt: skip
    lines = [*([title, ""] if title else []), "| " + " | ".join(table.header) + " |", f"|{align}|"]
    lines += ["| " + " | ".join([label, *(cell(t, m) for t, m in vals)]) + " |" for label, vals in table.rows]
    return "\n".join(lines)


def table1_markdown(cells: Sequence[Cell], variants: Sequence[str], scenes: Sequence[str], color: str,
                    trained_on: Mapping[str, str] | None = None) -> str:  # fmt: skip
    """Table I block for one colour (see :func:`table1`): best values bold, second best italic."""
    return to_markdown(table1(cells, variants, scenes, color, trained_on), f"**{color.upper()}**")


def table2_markdown(cells: Sequence[Cell], color: str, trained_on: Mapping[str, str] | None = None) -> str:
    """Table II (ablation) block for one colour (see :func:`table2`)."""
    return to_markdown(table2(cells, color, trained_on), f"**{color.upper()}**")


def per_scene_table(cells: Sequence[Cell], pairs: Sequence[tuple[str, str]]) -> str:
    """A Markdown table: one row per scene, one column per (ours, baseline) pair that the scene has for
    every seed; each entry is the mean PSNR difference over the paired seeds, then each seed's (a cell
    whose PSNR is null pairs with none)."""
    psnr = {(c.scene, c.variant, c.seed): c.psnr for c in cells if c.psnr is not None}
    scenes = list(dict.fromkeys(c.scene for c in cells))
    seeds = sorted({c.seed for c in cells})
    lines = ["| scene | " + " | ".join(f"{a} − {b}" for a, b in pairs) + " |", "|---|" + "---:|" * len(pairs)]
    for scene in scenes:
        entries = []
        for ours, base in pairs:
            d = [psnr[scene, ours, k] - psnr[scene, base, k] for k in seeds
                 if (scene, ours, k) in psnr and (scene, base, k) in psnr]  # fmt: skip
            each = ", ".join(f"{x:+.2f}" for x in d)
            entries.append(f"{sum(d) / len(d):+.2f} ({each})" if d else "—")
        lines.append(f"| {scene} | " + " | ".join(entries) + " |")
    return "\n".join(lines)


def cells_csv(cells: Sequence[Cell]) -> str:
    """All cells as CSV (one row per scene, variant, colour and seed)."""
    buffer = io.StringIO()
    fields = list(asdict(cells[0]).keys()) if cells else [f for f in Cell.__dataclass_fields__]
    writer = csv.DictWriter(buffer, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for c in cells:
        writer.writerow(asdict(c))
    return buffer.getvalue()

"""The tables of the benchmark's HTML report (:mod:`spikenerf.pipelines.report`), as HTML: Table I per
colour, Table II, the paired differences and a note per missing cell or missing LPIPS."""

from __future__ import annotations

import html
import json
from collections.abc import Mapping, Sequence
from pathlib import Path

from spikenerf.pipelines.benchmark.cells import BenchmarkConfig, CellKey, cell_keys, run_dir, training_seeds
from spikenerf.pipelines.benchmark.stats import differences
from spikenerf.pipelines.benchmark.tables import Cell, Table, differences_table, table1, table2
from spikenerf.pipelines.benchmark.variants import ABLATION_VARIANTS, TABLE1_VARIANTS, label


def esc(text: object) -> str:
    """``text`` as a string escaped for HTML."""
    return html.escape(str(text))


def table_html(table: Table) -> str:
    """A :class:`~spikenerf.pipelines.benchmark.tables.Table` as HTML (numbers right-aligned; best, second,
    shown)."""
    head = "".join(f"<th>{esc(h)}</th>" for h in table.header)
    body = "".join(
        f"<tr><td>{esc(row)}</td>"
        + "".join(
            "<td>" + esc(text) + "</td>" if mark == "text" else f'<td class="n {mark}">{esc(text)}</td>'
            for text, mark in values
        )
        + "</tr>"
        for row, values in table.rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def table1_html(cells: Sequence[Cell], variants: Sequence[str], scenes: Sequence[str], color: str,
                trained_on: Mapping[str, str] | None = None) -> str:  # fmt: skip
    """Table I for one colour: rows = variants, (SSIM, PSNR) per scene and their average; best, second."""
    return table_html(table1(cells, variants, scenes, color, trained_on))


def table2_html(cells: Sequence[Cell], color: str, trained_on: Mapping[str, str] | None = None) -> str:
    """Table II (ablation) for one colour: SSIM, PSNR, LPIPS averaged over scenes."""
    return table_html(table2(cells, color, trained_on))


def read_json(path: Path) -> dict:
    """A JSON object file; {} where it is missing, unreadable or not an object."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):
        return {}
    return data if isinstance(data, dict) else {}


def _cell_notes(cfg: BenchmarkConfig, cells: Sequence[Cell], local: set[CellKey] | None = None) -> list[str]:
    """One note per missing cell, per LPIPS null (with its reason) and per cell without renders; the files
    of a cell outside ``local`` (one merged from another call's results; None: every cell is local) are
    not looked for."""
    have = {(c.scene, c.color, c.variant, c.seed) for c in cells}
    notes = []
    for key in cell_keys(cfg):
        run = run_dir(cfg, *key)
        where = f"{key.scene}/{key.color}/{label(key.variant)}" + (
            "" if key.seed == cfg.seed else f" (seed {key.seed})"
        )
        if key not in have:
            notes.append(f"{where}: no result (the cell has not finished).")
            continue
        if local is not None and key not in local:  # merged from another call: its files are there
            continue
        metrics = read_json(run / "metrics.json")
        mean = metrics.get("mean")
        if not isinstance(mean, dict) or mean.get("lpips") is None:
            notes.append(f"{where}: LPIPS – ({metrics.get('lpips_reason') or 'not computed'}).")
        if cfg.render and not (run / "render" / "render.json").is_file():
            notes.append(f"{where}: no rendered test views (render did not run).")
    return notes


def tables_section(cfg: BenchmarkConfig, cells: Sequence[Cell], local: set[CellKey] | None = None) -> str:
    from spikenerf.pipelines.benchmark.results import differences_note, seed_note, trained_on

    t1 = [v for v in cfg.variants if v in TABLE1_VARIANTS] or list(cfg.variants)
    views = trained_on(cfg)
    parts = ["<h2>Tables</h2><p class='note'>Mean over the held-out test views, metrics on sRGB-encoded "
             f"[0, 1] values. {esc(seed_note(training_seeds(cfg)))} "
             "<span style='background:#f6a5a5'>red</span> = best, "
             "<span style='background:#fbe79a'>yellow</span> = second best (by the mean); – = not available; "
             "'trained on' is counted from the datasets.</p>",
             "<h3>Table I: comparison</h3>"]  # fmt: skip
    for color in cfg.colors:
        parts += [f"<h4>{color.upper()}</h4>", table1_html(cells, t1, cfg.scenes, color, views)]
    if sum(v in ABLATION_VARIANTS for v in cfg.variants) > 1:
        parts.append("<h3>Table II: ablation (mean over scenes)</h3>")
        for color in cfg.colors:
            parts += [f"<h4>{color.upper()}</h4>", table2_html(cells, color, views)]
    diffs = differences(cells, cfg.colors)
    parts.append(f"<h3 id='differences'>Paired differences</h3><p class='note'>{esc(differences_note())}</p>")
    parts.append(
        table_html(differences_table(diffs)) if diffs else "<p class='note'>– no comparable pairs.</p>"
    )
    notes = _cell_notes(cfg, cells, local)
    if notes:
        parts.append("<ul class='note'>" + "".join(f"<li>{esc(n)}</li>" for n in notes) + "</ul>")
    return "".join(parts)

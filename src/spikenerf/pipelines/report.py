"""The benchmark's self-contained HTML report (``OUT/report.html``; see docs/report.md).

One file that opens offline: inline CSS, every figure a base64 PNG data URI, no scripts. Sections (their HTML
ids): ``tables`` (Table I per colour, Table II), ``views`` (GT, each method and error maps on one test view),
``spikes`` (raster of a few pixels, TFP next to its spike mask), ``curves`` (test PSNR against training time),
``novel-spikes`` (a predicted novel-view spike stream next to the one simulated from GT) and ``environment``
(versions, hardware, and the command behind every figure). A missing piece (a cell without renders, LPIPS
null, a figure that cannot be made) shows as "–" with a note; the report itself never fails on it (a figure
that cannot be made is also named in a warning line on stderr, once the report is written). Every figure is
also saved as a PNG under ``OUT/figures/``. The tables are made in ``report_tables.py``, the figures in
``report_figures.py`` (drawn by ``figures.py``); this module assembles and writes the page.
"""

from __future__ import annotations

import base64
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from spikenerf.core.atomic import write_bytes_atomic, write_text_atomic
from spikenerf.core.errors import one_line
from spikenerf.data.dataset import SpikeDataset, load_dataset
from spikenerf.pipelines.benchmark.cells import BenchmarkConfig, cell_keys, environment
from spikenerf.pipelines.benchmark.run import dataset_mismatch
from spikenerf.pipelines.benchmark.tables import Cell
from spikenerf.pipelines.report_figures import Fig, curves_fig, novel_fig, spikes_figs, views_fig
from spikenerf.pipelines.report_tables import esc, tables_section

REPORT, FIGURES = "report.html", "figures"
SECTIONS = ("tables", "views", "spikes", "curves", "novel-spikes", "environment")
CSS = """body{font-family:sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:.5em 0 1em}td,th{border:1px solid #bbb;padding:3px 7px;font-size:13px}
td.n{text-align:right;font-variant-numeric:tabular-nums}td.best{background:#f6a5a5;font-weight:bold}
td.second{background:#fbe79a}.note{color:#666;font-size:12px}figure{margin:.6em 0 1.2em}
td.shown{background:#b6e3b0;font-weight:bold}figcaption{font-size:12px;color:#444}img{max-width:100%}
nav a{margin-right:1em}
code{font-size:11px;background:#f3f3f3;padding:1px 3px;word-break:break-all}"""

#: section id -> (heading, explanation) of the figure sections
HEADS = {
    "views": ("Novel views", "One held-out test view per scene and colour: ground truth, each method's "
              "render (RUN/render/images) and its error |pred − GT| of display values on a shared scale."),
    "spikes": ("Spike streams", "The dataset's recorded stream: a raster of a few pixels, and a TFP "
               "reconstruction next to its spike mask."),
    "curves": ("Training curves", "Test PSNR (on the run's evaluation views) against training time."),
    "novel-spikes": ("Novel-view spike streams", "At the static pose of a test view: the GT test image "
                     "through the ideal camera simulator vs the trained model's radiance through the spiking "
                     "renderer's firing rule, both from a seeded uniform [0, φ) start; TFP of each."),
}  # fmt: skip


def _figure_name(name: str, section: str, key: str) -> bool:
    """Whether ``name`` is one this report writes for job ``section``/``key``: ``SECTION-KEY.png`` or
    ``SECTION-KEY-N.png`` (a user's file of another name in ``figures/`` is never touched)."""
    stem, prefix = name.removesuffix(".png"), f"{section}-{key}"
    return stem == prefix or (stem.startswith(f"{prefix}-") and stem[len(prefix) + 1 :].isdigit())


def _figure_html(fig: Fig) -> str:
    parts = ["<figure>"]
    if fig.png is not None:
        data = base64.b64encode(fig.png).decode("ascii")
        parts.append(f'<img src="data:image/png;base64,{data}" alt="{esc(fig.title)}">')
    caption = f"{esc(fig.title)}" + (f"<br><span class='note'>{esc(fig.note)}</span>" if fig.note else "")
    cmds = "".join(f"<br>command: <code>{esc(c)}</code>" for c in fig.commands)
    cmds += f"<br><span class='note'>also {esc(fig.file)}</span>" if fig.file else ""
    parts.append(f"<figcaption>{caption}{cmds}</figcaption></figure>")
    return "".join(parts)


def _env_section(cfg: BenchmarkConfig, recorded: Sequence[dict] = ()) -> str:
    """The environment: ``recorded`` (each call's ``results.json`` environment, a rebuilt report's) or,
    without it, this process's."""
    import os

    import matplotlib
    import torch

    if recorded:
        env, where = dict(recorded[0]), "as recorded in results.json"
        others = [e for e in recorded[1:] if e != recorded[0]]
        if others:
            where += "; the merged calls ran on " + "; ".join(json.dumps(e) for e in others)
    else:
        env = {**environment(), "numpy": np.__version__, "matplotlib": matplotlib.__version__}
        env |= {"cpu cores": os.cpu_count(), "torch threads": torch.get_num_threads()}
        where = "the machine that ran the benchmark"
    rows = "".join(f"<tr><td>{esc(k)}</td><td>{esc(v)}</td></tr>" for k, v in env.items())
    conf = {k: (str(v) if isinstance(v, Path) else v) for k, v in cfg.__dict__.items()}
    return (
        f"<h2>Environment</h2><p class='note'>{esc(where)}</p><table>{rows}</table><p class='note'>"
        "benchmark config: "
        f"<code>{esc(json.dumps(conf))}</code>; every run's exact commands are in results.json.</p>"
    )


def build_report(
    cfg: BenchmarkConfig,
    cells: list[Cell],
    progress: bool = True,
    own: BenchmarkConfig | None = None,
    recorded: Sequence[dict] = (),
) -> Path:
    """Write ``cfg.out/report.html`` (self-contained) from the benchmark's folders; returns its path.

    Each figure is also written as ``cfg.out/figures/<section>-<scene>[-<colour>][-<n>].png``. With cells of
    other calls merged in (``spikenerf report``), ``cfg`` holds their union for the tables, ``own`` the
    folder's own config (its figures and file notes; None: ``cfg``) and ``recorded`` each call's recorded
    environment (empty: this process's). Nothing is written until the whole page is built: a table that
    cannot be made leaves ``figures/`` and the old report as they were.
    """
    fig_cfg = cfg if own is None else own
    from spikenerf.core.progress import bar

    jobs: list[tuple[str, str, Callable[[], list[Fig]]]] = []
    datasets: dict[str, SpikeDataset] = {}

    def dataset(scene: str) -> SpikeDataset:
        if scene not in datasets:
            if (problem := dataset_mismatch(fig_cfg, scene)) is not None:  # changed since: not the cells'
                raise problem
            datasets[scene] = load_dataset(cfg.out / "datasets" / scene)
        return datasets[scene]

    for s in fig_cfg.scenes:
        jobs.append(("spikes", s, lambda s=s: spikes_figs(fig_cfg, dataset(s), s)))
        for c in fig_cfg.colors:
            jobs.append(("views", f"{s}-{c}", lambda s=s, c=c: [views_fig(fig_cfg, dataset(s), s, c)]))
            jobs.append(("curves", f"{s}-{c}", lambda s=s, c=c: [curves_fig(fig_cfg, s, c)]))
            jobs.append(("novel-spikes", f"{s}-{c}", lambda s=s, c=c: [novel_fig(fig_cfg, s, c)]))
    local = None if own is None else set(cell_keys(own))
    # the tables first: nothing is written (figures/ included) unless the whole page can be built
    body = [f"<section id='tables'>{tables_section(cfg, cells, local)}</section>"]
    made: dict[str, list[Fig]] = {k: [] for k in SECTIONS}
    left_out = []  # a warning line per figure that cannot be made, said once the report is written
    for section, key, make in bar(jobs, desc="report figures", unit="fig", show=progress):
        try:
            figs = make()
        except Exception as err:  # never crash the report: show what is missing and why, and say so
            why = one_line(f"{type(err).__name__}: {err}")
            figs = [Fig(f"{section}: {key}", None, note=f"– figure not available: {why}")]
            left_out.append(f"spikenerf: warning: report: the {section} figure of {key} is left out ({why})")
        for i, fig in enumerate(figs):
            if fig.png is not None:  # each figure also as a PNG file, for READMEs and slides
                fig.file = f"{FIGURES}/{section}-{key}{f'-{i + 1}' if len(figs) > 1 else ''}.png"
        made[section] += figs
    for sid, (head, text) in HEADS.items():
        figs = "".join(_figure_html(f) for f in made[sid]) or "<p class='note'>–</p>"
        body.append(f"<section id='{sid}'><h2>{head}</h2><p class='note'>{esc(text)}</p>{figs}</section>")
    body.append(f"<section id='environment'>{_env_section(cfg, recorded)}</section>")
    nav = "".join(f"<a href='#{s}'>{s}</a>" for s in SECTIONS)
    head = f"<head><meta charset='utf-8'><title>spikenerf report</title><style>{CSS}</style></head>"
    page = f"<!DOCTYPE html><html lang='en'>{head}<body><h1>spikenerf report</h1><nav>{nav}</nav>"
    page += "".join(body) + "</body></html>\n"
    written = {f.file for figs in made.values() for f in figs if f.file}
    for fig in (f for figs in made.values() for f in figs if f.file):
        write_bytes_atomic(cfg.out / fig.file, fig.png)  # type: ignore[arg-type]
    for section, key, _ in jobs:  # an earlier build's figure of a job that failed now (or drew fewer)
        names = [
            f"{section}-{key}.png",
            *(p.name for p in (cfg.out / FIGURES).glob(f"{section}-{key}-*.png")),
        ]
        for name in names:
            if f"{FIGURES}/{name}" not in written and _figure_name(name, section, key):
                (cfg.out / FIGURES / name).unlink(missing_ok=True)
    path = cfg.out / REPORT
    write_text_atomic(path, page)
    for line in left_out:  # (after the write: a report refused there says its one error line alone)
        print(line, file=sys.stderr, flush=True)
    return path

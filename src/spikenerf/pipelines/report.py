"""The benchmark's self-contained HTML report (``OUT/report.html``; see docs/report.md).

One file that opens offline: inline CSS, every figure a base64 PNG data URI, no scripts. Sections (their HTML
ids): ``tables`` (Table I per colour, Table II), ``views`` (GT, each method and error maps on one test view),
``spikes`` (raster of a few pixels, TFP next to its spike mask), ``curves`` (test PSNR against training time),
``novel-spikes`` (a predicted novel-view spike stream next to the one simulated from GT) and ``environment``
(versions, hardware, and the command behind every figure). A missing piece (a cell without renders, LPIPS
null, a figure that cannot be made) shows as "–" with a note; the report itself never fails on it. Every
figure is also saved as a PNG under ``OUT/figures/``.
"""

from __future__ import annotations

import base64
import html
import json
import shlex
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from spikenerf.camera.reconstruct import fitting_window
from spikenerf.core.atomic import write_bytes_atomic, write_text_atomic
from spikenerf.core.color import rgb_to_gray, srgb_encode
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import SpikeDataset, load_dataset, spike_files
from spikenerf.pipelines import figures
from spikenerf.pipelines.benchmark.cells import (
    BenchmarkConfig,
    CellKey,
    cell_commands,
    cell_keys,
    dataset_command,
    environment,
    run_dir,
    training_seeds,
)
from spikenerf.pipelines.benchmark.run import dataset_mismatch
from spikenerf.pipelines.benchmark.stats import differences
from spikenerf.pipelines.benchmark.tables import (
    Cell,
    Table,
    differences_table,
    table1,
    table2,
)
from spikenerf.pipelines.benchmark.variants import ABLATION_VARIANTS, TABLE1_VARIANTS, label

REPORT, FIGURES = "report.html", "figures"
SECTIONS = ("tables", "views", "spikes", "curves", "novel-spikes", "environment")
#: the test view shown in ``views`` and ``novel-spikes``; TFP window and mask half window of ``spikes``
VIEW, MASK_N, RASTER_PIXELS, RASTER_STEPS = 0, 5, 6, 120
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


@dataclass
class Fig:
    """One figure of the report: PNG bytes (None = could not be made), the commands behind its data."""

    title: str
    png: bytes | None
    commands: list[str] = field(default_factory=list)
    note: str = ""
    file: str = ""  # the PNG's path relative to the benchmark folder, once written


def _cmd(command: list[str]) -> str:
    """``python -m spikenerf ARGS`` → the user-facing ``spikenerf ARGS`` (without ``--resume``)."""
    return shlex.join(["spikenerf", *[a for a in command[3:] if a != "--resume"]])


def _esc(text: object) -> str:
    return html.escape(str(text))


# ----------------------------------------------------------------------------------------------- tables
def table_html(table: Table) -> str:
    """A :class:`~spikenerf.pipelines.benchmark.tables.Table` as HTML (numbers right-aligned; best, second,
    shown)."""
    head = "".join(f"<th>{_esc(h)}</th>" for h in table.header)
    body = "".join(
        f"<tr><td>{_esc(row)}</td>"
        + "".join(
            "<td>" + _esc(text) + "</td>" if mark == "text" else f'<td class="n {mark}">{_esc(text)}</td>'
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


def _read_json(path: Path) -> dict:
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
        metrics = _read_json(run / "metrics.json")
        mean = metrics.get("mean")
        if not isinstance(mean, dict) or mean.get("lpips") is None:
            notes.append(f"{where}: LPIPS – ({metrics.get('lpips_reason') or 'not computed'}).")
        if cfg.render and not (run / "render" / "render.json").is_file():
            notes.append(f"{where}: no rendered test views (render did not run).")
    return notes


def _tables_section(cfg: BenchmarkConfig, cells: Sequence[Cell], local: set[CellKey] | None = None) -> str:
    from spikenerf.pipelines.benchmark.results import differences_note, seed_note, trained_on

    t1 = [v for v in cfg.variants if v in TABLE1_VARIANTS] or list(cfg.variants)
    views = trained_on(cfg)
    parts = ["<h2>Tables</h2><p class='note'>Mean over the held-out test views, metrics on sRGB-encoded "
             f"[0, 1] values. {_esc(seed_note(training_seeds(cfg)))} "
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
    parts.append(
        f"<h3 id='differences'>Paired differences</h3><p class='note'>{_esc(differences_note())}</p>"
    )
    parts.append(
        table_html(differences_table(diffs)) if diffs else "<p class='note'>– no comparable pairs.</p>"
    )
    notes = _cell_notes(cfg, cells, local)
    if notes:
        parts.append("<ul class='note'>" + "".join(f"<li>{_esc(n)}</li>" for n in notes) + "</ul>")
    return "".join(parts)


# ---------------------------------------------------------------------------------------------- figures
def _display(linear: np.ndarray, color: str) -> np.ndarray:
    """Linear RGB (H, W, 3) → display values (H, W) gray or (H, W, 3)."""
    return srgb_encode(rgb_to_gray(linear, channel_axis=-1) if color == "gray" else linear)


def _read_png(path: Path) -> np.ndarray | None:
    """An 8-bit PNG as display values (H, W) or (H, W, 3); None if it is not there."""
    if not path.is_file():
        return None
    arr = np.asarray(iio.imread(path)).astype(np.float64) / 255.0
    return arr[..., :3] if arr.ndim == 3 else arr


def _shown_seed(cfg: BenchmarkConfig) -> int:
    """The training seed whose runs the figures show: the dataset seed where it was trained, else the first
    of ``--seeds``."""
    seeds = training_seeds(cfg)
    return cfg.seed if cfg.seed in seeds else seeds[0]


def _views_fig(cfg: BenchmarkConfig, ds: SpikeDataset, scene: str, color: str) -> Fig:
    gt = _display(ds.test.images[VIEW], color)
    preds, commands = {}, [_cmd(dataset_command(cfg, scene))]
    for v in cfg.variants:
        run = run_dir(cfg, scene, color, v, _shown_seed(cfg))
        per_view = _read_json(run / "metrics.json").get("per_view") or [{}]
        psnr = per_view[VIEW].get("psnr") if len(per_view) > VIEW else None
        name = label(v) + ("" if psnr is None else f"\n{psnr:.2f} dB")
        preds[name] = _read_png(run / "render" / "images" / f"{VIEW:05d}.png")
        if cfg.render:
            commands.append(_cmd(cell_commands(cfg, scene, color, v, _shown_seed(cfg), todo=False)[-1]))
    missing = [k.split("\n")[0] for k, p in preds.items() if p is None]
    note = f"– no rendered test view for: {', '.join(missing)}." if missing else ""
    title = (
        f"{scene}, {color}: test view {VIEW} (cropped to the content); error = |pred − GT| of display values"
    )
    png = figures.views_figure(gt, preds, f"{scene} · {color} · test view {VIEW}")
    return Fig(title, png, commands, note)


def _spikes_figs(cfg: BenchmarkConfig, ds: SpikeDataset, scene: str) -> list[Fig]:
    from spikenerf.camera.layout import to_channels_last
    from spikenerf.camera.masks import spike_masks
    from spikenerf.data.reconstruction import frame_at

    mode = "gray" if "gray" in ds.modes else ds.modes[0]
    stream = ds.spikes(mode)  # (T, H, W) or (T, 3, H, W)
    gray = stream if stream.ndim == 3 else stream.max(axis=1)
    t, h, w = gray.shape
    window = fitting_window(t, figures.TFP_WINDOW)
    k = int(ds.gt.steps[np.argmin(np.abs(ds.gt.steps - t // 2))]) if len(ds.gt) else t // 2
    rate = gray.mean(0).ravel()
    picks = figures.raster_pixels(rate, RASTER_PIXELS)
    xy = np.stack([picks % w, picks // w], -1)
    steps = min(t, RASTER_STEPS)
    raster = gray[:steps].reshape(steps, -1)[:, picks]
    labels = [f"x={x} y={y} ({rate[p]:.2f}/step)" for (x, y), p in zip(xy, picks, strict=True)]
    sim = _cmd(dataset_command(cfg, scene))
    recon = [  # rgb: one command per channel file (spikes_rgb_{r,g,b}.dat), each that channel's image
        f"spikenerf reconstruct {shlex.quote(str(ds.root / name))} --height {h} --width {w} --method tfp "
        f"--window {window} --frame {k} --out tfp{name.removeprefix('spikes').removesuffix('.dat')}.png"
        for name in spike_files(mode)
    ]
    raster_fig = Fig(
        f"{scene}: {mode} spikes of {RASTER_PIXELS} pixels, dimmest → brightest, steps 0…{steps - 1}",
        figures.raster_figure(raster, labels, f"{scene} · {mode} stream · spike raster"),
        [sim],
    )
    rec = frame_at(stream, k, "tfp", window, ds.threshold)
    rec = rec if rec.ndim == 2 else to_channels_last(rec, frame=True)
    mask = spike_masks(stream, n=MASK_N, frames=k)[0]
    mask = mask.any(0) if mask.ndim == 3 else mask
    gi = int(np.flatnonzero(ds.gt.steps == k)[0]) if len(ds.gt) and k in ds.gt.steps else None
    gt_img = None if gi is None else _display(ds.gt.images[gi], "gray" if rec.ndim == 2 else "rgb")
    panels = [(f"GT render, step {k}", gt_img), (f"TFP (window {window})", srgb_encode(rec)),
              (f"spike mask (n = {MASK_N})", mask.astype(float))]  # fmt: skip
    tfp_fig = Fig(
        f"{scene}: step {k}: TFP reconstruction next to its spike mask M_k (OR over k−{MASK_N}…k+{MASK_N}); "
        "circles = the raster's pixels",
        figures.panels_figure(panels, f"{scene} · {mode} · step {k}", points=xy),
        [
            sim,
            *recon,
            f"spikenerf.camera.masks.spike_masks(spikes, n={MASK_N}, frames={k})",
        ],
    )
    return [raster_fig, tfp_fig]


def _curves_fig(cfg: BenchmarkConfig, scene: str, color: str) -> Fig:
    from spikenerf.train.evaluate import read_curves

    seed = _shown_seed(cfg)
    curves = {label(v): read_curves(run_dir(cfg, scene, color, v, seed) / "curves.csv") for v in cfg.variants}
    missing = [k for k, rows in curves.items() if not rows]
    return Fig(
        f"{scene}, {color}: test PSNR against training time (RUN/curves.csv)",
        figures.curves_figure(curves, f"{scene} · {color}"),
        [_cmd(cell_commands(cfg, scene, color, v, seed, todo=False)[0]) for v in cfg.variants],
        f"– no curves.csv for: {', '.join(missing)}." if missing else "",
    )


def _figure_name(name: str, section: str, key: str) -> bool:
    """Whether ``name`` is one this report writes for job ``section``/``key``: ``SECTION-KEY.png`` or
    ``SECTION-KEY-N.png`` (a user's file of another name in ``figures/`` is never touched)."""
    stem, prefix = name.removesuffix(".png"), f"{section}-{key}"
    return stem == prefix or (stem.startswith(f"{prefix}-") and stem[len(prefix) + 1 :].isdigit())


def figure_device(cfg: BenchmarkConfig) -> str:
    """The device the report renders its figures on: the benchmark's where this machine has it (a report
    rebuilt on a CPU machine from a CUDA benchmark renders on the CPU)."""
    from spikenerf.core.device import resolve_device

    try:
        return str(resolve_device(cfg.device))
    except InputError:
        return "cpu"


def _novel_fig(cfg: BenchmarkConfig, scene: str, color: str) -> Fig:
    seed = _shown_seed(cfg)
    runs = [run_dir(cfg, scene, color, v, seed) for v in ("spike-nerf", *cfg.variants) if v in cfg.variants]
    run = next((r for r in runs if (r / "checkpoint.pt").is_file()), None)
    if run is None:
        return Fig(f"{scene}, {color}: novel-view spikes", None, note="– no trained run to render from.")
    dataset = cfg.out / "datasets" / scene  # (not the run's recorded path: the folder may have moved)
    if (problem := dataset_mismatch(cfg, scene)) is not None:  # changed since: not the cells' dataset
        raise problem
    r = figures.novel_spikes(run, VIEW, device=figure_device(cfg), dataset_root=dataset)
    panels = [
        ("GT test image\n→ camera simulator", r.gt_tfp),
        (f"{label(r.method)}\n→ spiking renderer", r.pred_tfp),
        ("|difference|", figures.error_map(r.pred_tfp, r.gt_tfp)),
    ]
    title = (
        f"{scene}, {color}: TFP (window {r.window}, step {r.step} of {r.steps}) of static-pose spike streams "
        f"at test view {VIEW}: spike rate GT {r.gt_rate:.3f}, predicted {r.pred_rate:.3f} spikes/step/pixel; "
        f"PSNR between the two TFP images {r.psnr:.2f} dB"
    )
    cmaps = {2: (figures.ERROR_CMAP, figures.ERROR_VMAX)}
    fig = figures.panels_figure(panels, f"{scene} · {color} · novel-view spikes", cmaps=cmaps)
    commands = [
        _cmd(cell_commands(cfg, scene, color, r.method, seed, todo=False)[0]),
        f"spikenerf.pipelines.figures.novel_spikes({str(run)!r}, view={VIEW}, steps={r.steps})",
    ]
    return Fig(title, fig, commands)


# ------------------------------------------------------------------------------------------------- HTML
def _figure_html(fig: Fig) -> str:
    parts = ["<figure>"]
    if fig.png is not None:
        data = base64.b64encode(fig.png).decode("ascii")
        parts.append(f'<img src="data:image/png;base64,{data}" alt="{_esc(fig.title)}">')
    caption = f"{_esc(fig.title)}" + (f"<br><span class='note'>{_esc(fig.note)}</span>" if fig.note else "")
    cmds = "".join(f"<br>command: <code>{_esc(c)}</code>" for c in fig.commands)
    cmds += f"<br><span class='note'>also {_esc(fig.file)}</span>" if fig.file else ""
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
    rows = "".join(f"<tr><td>{_esc(k)}</td><td>{_esc(v)}</td></tr>" for k, v in env.items())
    conf = {k: (str(v) if isinstance(v, Path) else v) for k, v in cfg.__dict__.items()}
    return (
        f"<h2>Environment</h2><p class='note'>{_esc(where)}</p><table>{rows}</table><p class='note'>"
        "benchmark config: "
        f"<code>{_esc(json.dumps(conf))}</code>; every run's exact commands are in results.json.</p>"
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
        jobs.append(("spikes", s, lambda s=s: _spikes_figs(fig_cfg, dataset(s), s)))
        for c in fig_cfg.colors:
            jobs.append(("views", f"{s}-{c}", lambda s=s, c=c: [_views_fig(fig_cfg, dataset(s), s, c)]))
            jobs.append(("curves", f"{s}-{c}", lambda s=s, c=c: [_curves_fig(fig_cfg, s, c)]))
            jobs.append(("novel-spikes", f"{s}-{c}", lambda s=s, c=c: [_novel_fig(fig_cfg, s, c)]))
    local = None if own is None else set(cell_keys(own))
    # the tables first: nothing is written (figures/ included) unless the whole page can be built
    body = [f"<section id='tables'>{_tables_section(cfg, cells, local)}</section>"]
    made: dict[str, list[Fig]] = {k: [] for k in SECTIONS}
    for section, key, make in bar(jobs, desc="report figures", unit="fig", show=progress):
        try:
            figs = make()
        except Exception as err:  # never crash the report: show what is missing and why
            figs = [
                Fig(f"{section}: {key}", None, note=f"– figure not available: {type(err).__name__}: {err}")
            ]
        for i, fig in enumerate(figs):
            if fig.png is not None:  # each figure also as a PNG file, for READMEs and slides
                fig.file = f"{FIGURES}/{section}-{key}{f'-{i + 1}' if len(figs) > 1 else ''}.png"
        made[section] += figs
    for sid, (head, text) in HEADS.items():
        figs = "".join(_figure_html(f) for f in made[sid]) or "<p class='note'>–</p>"
        body.append(f"<section id='{sid}'><h2>{head}</h2><p class='note'>{_esc(text)}</p>{figs}</section>")
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
    return path

"""The figures of the benchmark's HTML report (:mod:`spikenerf.pipelines.report`), each a :class:`Fig`: its
data read from the benchmark's folders, drawn by :mod:`spikenerf.pipelines.figures`, with the commands behind
it. Novel views, spike streams, training curves and novel-view spike streams."""

from __future__ import annotations

import shlex
from dataclasses import dataclass, field
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from spikenerf.camera.reconstruct import fitting_window
from spikenerf.core.color import rgb_to_gray, srgb_encode
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import SpikeDataset, spike_files
from spikenerf.pipelines import figures
from spikenerf.pipelines.benchmark.cells import (
    BenchmarkConfig,
    cell_commands,
    dataset_command,
    run_dir,
    training_seeds,
)
from spikenerf.pipelines.benchmark.run import dataset_mismatch
from spikenerf.pipelines.benchmark.variants import label
from spikenerf.pipelines.report_tables import read_json

#: the test view shown in ``views`` and ``novel-spikes``; TFP window and mask half window of ``spikes``
VIEW, MASK_N, RASTER_PIXELS, RASTER_STEPS = 0, 5, 6, 120


@dataclass
class Fig:
    """One figure of the report: PNG bytes (None = could not be made), the commands behind its data."""

    title: str
    png: bytes | None
    commands: list[str] = field(default_factory=list)
    note: str = ""
    file: str = ""  # the PNG's path relative to the benchmark folder, once written


def cmd(command: list[str]) -> str:
    """``python -m spikenerf ARGS`` → the user-facing ``spikenerf ARGS`` (without ``--resume``)."""
    return shlex.join(["spikenerf", *[a for a in command[3:] if a != "--resume"]])


def _display(linear: np.ndarray, color: str) -> np.ndarray:
    """Linear RGB (H, W, 3) → display values (H, W) gray or (H, W, 3)."""
    return srgb_encode(rgb_to_gray(linear, channel_axis=-1) if color == "gray" else linear)


def _read_png(path: Path) -> np.ndarray | None:
    """An 8-bit PNG as display values (H, W) or (H, W, 3); None if it is not there."""
    if not path.is_file():
        return None
    arr = np.asarray(iio.imread(path)).astype(np.float64) / 255.0
    return arr[..., :3] if arr.ndim == 3 else arr


def shown_seed(cfg: BenchmarkConfig) -> int:
    """The training seed whose runs the figures show: the dataset seed where it was trained, else the first
    of ``--seeds``."""
    seeds = training_seeds(cfg)
    return cfg.seed if cfg.seed in seeds else seeds[0]


def views_fig(cfg: BenchmarkConfig, ds: SpikeDataset, scene: str, color: str) -> Fig:
    gt = _display(ds.test.images[VIEW], color)
    preds, commands = {}, [cmd(dataset_command(cfg, scene))]
    for v in cfg.variants:
        run = run_dir(cfg, scene, color, v, shown_seed(cfg))
        per_view = read_json(run / "metrics.json").get("per_view") or [{}]
        psnr = per_view[VIEW].get("psnr") if len(per_view) > VIEW else None
        name = label(v) + ("" if psnr is None else f"\n{psnr:.2f} dB")
        preds[name] = _read_png(run / "render" / "images" / f"{VIEW:05d}.png")
        if cfg.render:
            commands.append(cmd(cell_commands(cfg, scene, color, v, shown_seed(cfg), todo=False)[-1]))
    missing = [k.split("\n")[0] for k, p in preds.items() if p is None]
    note = f"– no rendered test view for: {', '.join(missing)}." if missing else ""
    title = (
        f"{scene}, {color}: test view {VIEW} (cropped to the content); error = |pred − GT| of display values"
    )
    png = figures.views_figure(gt, preds, f"{scene} · {color} · test view {VIEW}")
    return Fig(title, png, commands, note)


def spikes_figs(cfg: BenchmarkConfig, ds: SpikeDataset, scene: str) -> list[Fig]:
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
    sim = cmd(dataset_command(cfg, scene))
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


def curves_fig(cfg: BenchmarkConfig, scene: str, color: str) -> Fig:
    from spikenerf.train.evaluate import read_curves

    seed = shown_seed(cfg)
    curves = {label(v): read_curves(run_dir(cfg, scene, color, v, seed) / "curves.csv") for v in cfg.variants}
    missing = [k for k, rows in curves.items() if not rows]
    return Fig(
        f"{scene}, {color}: test PSNR against training time (RUN/curves.csv)",
        figures.curves_figure(curves, f"{scene} · {color}"),
        [cmd(cell_commands(cfg, scene, color, v, seed, todo=False)[0]) for v in cfg.variants],
        f"– no curves.csv for: {', '.join(missing)}." if missing else "",
    )


def figure_device(cfg: BenchmarkConfig) -> str:
    """The device the report renders its figures on: the benchmark's where this machine has it (a report
    rebuilt on a CPU machine from a CUDA benchmark renders on the CPU)."""
    from spikenerf.core.device import resolve_device

    try:
        return str(resolve_device(cfg.device))
    except InputError:
        return "cpu"


def novel_fig(cfg: BenchmarkConfig, scene: str, color: str) -> Fig:
    seed = shown_seed(cfg)
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
        cmd(cell_commands(cfg, scene, color, r.method, seed, todo=False)[0]),
        f"spikenerf.pipelines.figures.novel_spikes({str(run)!r}, view={VIEW}, steps={r.steps})",
    ]
    return Fig(title, fig, commands)

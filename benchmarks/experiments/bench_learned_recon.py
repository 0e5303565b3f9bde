"""Learned reconstruction vs TFP and TFI (same window) on held-out scenes, and its speed at 250×400.

Run: ``OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.experiments.bench_learned_recon [--draws N]
[--weights FILE] [--content analytic|natural]``.

Quality: pairs drawn like the training pairs (random still/orbit/pan motion up to 1.5°/step, log-uniform
brightness 0.04–1) but from the two analytic scenes held out of training (``analytic-orbs``,
``analytic-blocks``), at 96 × 96 (training used 64 × 64), under two simulator configurations: the one the
network was trained with (φ = 1, the realistic preset as is) and one it never saw (φ = 2, every realistic
noise parameter × 1.5, shot noise × 1.5). Each reconstruction and the sharp frame are divided by the draw's
brightness (i.e. shown at the right exposure), clipped to [0, 1], sRGB-encoded, and scored by PSNR and SSIM
(RGB: over the three channels of one image; Bayer: over the mosaic). Δ is learned − TFP per draw, with a 95 %
interval (t, paired over draws).

``--content natural`` draws from the photographs held out of every training split instead
(``spikenerf.recon.natural.NATURAL_HELDOUT``: a camera panning, rolling or zooming over them; needs
scikit-image), at the same size, motion speeds and brightness.

Speed: frames/s of the learned reconstruction of 8 consecutive frames of a 250 × 400 gray stream (one tile) at
1 and 2 torch threads: the fast path (``learned_frames``: running-count features, channels-last network)
against, in the same run, the reference path (``predict_frame`` of each frame's window: features from the
whole window, contiguous layout) and TFP of the same frames; best of 3, wall and CPU time
(``--speed-only``; also ``run_all --only learned-recon``).
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np
import torch

from benchmarks._table import Row, best_seconds, format_table
from spikenerf.camera.reconstruct import tfi, tfp
from spikenerf.core.color import srgb_encode
from spikenerf.eval.metrics import psnr, ssim
from spikenerf.recon.generate import VAL_SCENES
from spikenerf.recon.infer import learned_frames, mirrored, predict_frame, predict_plane
from spikenerf.recon.natural import NATURAL_HELDOUT, load_images, natural_pairs
from spikenerf.recon.net import load_weights
from spikenerf.recon.pairs import PairConfig, analytic_pairs

#: (label, threshold φ, realistic-noise scale)
CONFIGS = (("trained config (φ=1)", 1.0, 1.0), ("unseen config (φ=2, noise ×1.5)", 2.0, 1.5))
T_95 = {n: t for n, t in ((4, 2.776), (8, 2.306), (12, 2.179), (16, 2.120), (24, 2.064), (32, 2.040))}


def _display(rate: np.ndarray, brightness: float, threshold: float) -> torch.Tensor:
    """Rates (intensity / φ) → intensity / brightness, clipped, sRGB-encoded, as (1, C, H, W) float64."""
    x = np.clip(rate * threshold / brightness, 0.0, 1.0)
    x = torch.from_numpy(np.asarray(srgb_encode(x.astype(np.float64))))
    return x.reshape(1, -1, *x.shape[-2:])


def _draw_images(net, samples, mode: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(prediction, target) rate images of one draw per method: (C, H, W), the Bayer planes re-mosaicked."""
    k = samples[0].window.shape[0]
    c = k // 2
    preds = {
        "TFP": [tfp(s.window, window=k, frames=c)[0] for s in samples],
        "TFI": [tfi(s.window, frames=c)[0] for s in samples],
        "learned": [predict_plane(net, s.window) for s in samples],
    }
    targets = [s.target for s in samples]
    if mode == "bayer":

        def mosaic(planes):
            h, w = planes[0].shape
            out = np.empty((1, 2 * h, 2 * w), np.float32)
            for p, (i, j) in zip(planes, ((0, 0), (0, 1), (1, 0), (1, 1)), strict=True):
                out[0, i::2, j::2] = p
            return out

        return {m: (mosaic(p), mosaic(targets)) for m, p in preds.items()}
    return {m: (np.stack(p), np.stack(targets)) for m, p in preds.items()}


def quality(net, draws: int, size: int = 96, content: str = "analytic") -> list[str]:
    """Markdown rows: config, noise, colour, then PSNR / SSIM of TFP, TFI, learned and Δ PSNR ± 95 %
    (``content``: the held-out analytic scenes, or the held-out photographs)."""
    rows = []
    k = net.config.window
    images = load_images(NATURAL_HELDOUT) if content == "natural" else {}

    def draw(cfg: PairConfig):
        if images:
            return natural_pairs(images, range(draws), cfg, seed=2024)
        return analytic_pairs(VAL_SCENES, range(draws), cfg, seed=2024)

    for label, phi, noise_scale in CONFIGS:
        for noise in ("ideal", "realistic"):
            for mode in ("gray", "rgb", "bayer"):
                cfg = PairConfig(
                    size=size,
                    window=k,
                    modes=(mode,),
                    noises=(noise,),
                    threshold=phi,
                    noise_scale=noise_scale,
                )
                scores: dict[str, list[tuple[float, float]]] = {"TFP": [], "TFI": [], "learned": []}
                group: list = []
                for s in draw(cfg):
                    group.append(s)
                    if len(group) < {"gray": 1, "rgb": 3, "bayer": 4}[mode]:
                        continue
                    b = group[0].info["brightness"]
                    for m, (pred, tgt) in _draw_images(net, group, mode).items():
                        a, t = _display(pred, b, phi), _display(tgt, b, phi)
                        scores[m].append((float(psnr(a, t)[0]), float(ssim(a, t)[0])))
                    group = []
                delta = np.array(
                    [lp[0] - tp[0] for lp, tp in zip(scores["learned"], scores["TFP"], strict=True)]
                )
                half = T_95.get(len(delta), 2.0) * delta.std(ddof=1) / math.sqrt(len(delta))
                cells = [
                    f"{np.mean([p for p, _ in v]):.2f} / {np.mean([q for _, q in v]):.3f}"
                    for v in scores.values()
                ]
                rows.append(
                    f"| {label} | {noise} | {mode} | {' | '.join(cells)} | {delta.mean():+.2f} ± {half:.2f} |"
                )
    return rows


def speed(threads: int, frames: int = 8, height: int = 250, width: int = 400, repeats: int = 3) -> list[Row]:
    """Learned frames/s at 250 × 400 with ``threads`` torch threads: the fast path (``learned_frames``)
    against the reference path (``predict_frame`` of each window) and TFP, same run, best of ``repeats``.
    Wall-clock rows, and with 1 thread also CPU-time rows (``time.process_time``: less sensitive to load)."""
    torch.set_num_threads(threads)
    fast_net, _ = load_weights(None)
    ref_net, _ = load_weights(None)
    k = fast_net.config.window
    half = k // 2
    rng = np.random.default_rng(0)
    stream = (rng.random((frames + k, height, width), dtype=np.float32) < 0.3).astype(np.uint8)
    total = stream.shape[0]
    sel = range(half, half + frames)

    def fast():
        learned_frames(fast_net, lambda a, b: stream[a:b], total, sel.start, sel.stop)

    def reference():
        for f in sel:
            predict_frame(ref_net, stream[mirrored(f, half, total)], "gray")

    def tfp_frames():
        tfp(stream, window=k, frames=slice(sel.start, sel.stop))

    learned_frames(fast_net, lambda a, b: stream[a:b], total, half, half + 1)  # warm-up
    predict_frame(ref_net, stream[:k], "gray")
    rows = []
    clocks = [("wall", time.perf_counter)] + ([("CPU", time.process_time)] if threads == 1 else [])
    for clock_name, clock in clocks:
        t = {
            name: best_seconds(fn, repeats, clock)
            for name, fn in (("fast", fast), ("ref", reference), ("tfp", tfp_frames))
        }
        label = f"learned recon {height}×{width}, {threads} thread(s), {clock_name} time"
        rows.append(Row(label, frames / t["fast"], frames / t["ref"], "frames/s", "reference path"))
        rows.append(Row(label, frames / t["fast"], frames / t["tfp"], "frames/s", "TFP"))
    return rows


def measure() -> list[Row]:
    """Speed rows for ``benchmarks.suites.run_all`` (shipped weights, 1 and 2 threads)."""
    before = torch.get_num_threads()
    try:
        return speed(1) + speed(2)
    finally:
        torch.set_num_threads(before)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=16, help="draws per (config, noise, colour) cell")
    parser.add_argument("--weights", default=None, help="weights file [default: the shipped one]")
    parser.add_argument("--content", choices=("analytic", "natural"), default="analytic",
                        help="held-out analytic scenes, or held-out photographs (scikit-image)")  # fmt: skip
    parser.add_argument("--no-speed", action="store_true")
    parser.add_argument("--speed-only", action="store_true")
    args = parser.parse_args()
    net, meta = load_weights(args.weights)
    print(
        f"weights: {args.weights or 'shipped'} ({meta['record'].get('command', '?')}); "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}, load {os.getloadavg()[0]:.1f}"
    )
    if args.speed_only:
        print(format_table(speed(1) + speed(2)))
        return
    torch.set_num_threads(1)
    print(
        "| simulator | noise | colour | TFP PSNR / SSIM | TFI PSNR / SSIM | learned PSNR / SSIM "
        "| Δ PSNR vs TFP (95 %) |"
    )
    print("|---|---|---|---|---|---|---|")
    for row in quality(net, args.draws, content=args.content):
        print(row, flush=True)
    if not args.no_speed:
        print()
        print(format_table(speed(1) + speed(2)))


if __name__ == "__main__":
    main()

"""TFSTP against TFP and TFI: accuracy against sharp GT and speed, in one run.

Run: ``.venv/bin/python -m benchmarks.experiments.bench_tfstp --out /tmp/bench-tfstp`` (the dataset in
``--out`` is reused). An analytic scene (``--scene``, default ``analytic-orbs``) is simulated at
``--size``² gray for ``--frames`` steps along the default orbit (``--turns``; 0: a camera that stands still)
with a sharp GT frame every ``--gt-every`` steps. Each GT frame is reconstructed from the dataset's own stream
by TFP (window 41), TFI and TFSTP (SpikeCV's defaults) and scored as ``spikenerf recon-eval`` scores it
(:func:`spikenerf.eval.recon_scores.score_reconstructions`: sRGB-encoded PSNR and SSIM).

Printed: each method's mean PSNR/SSIM over the GT frames, the mean per-frame difference from TFP with its 95%
t interval over the frames (``t_interval``), and each method's frames/s reconstructing every frame of the
in-memory stream (best of ``--repeats``, one thread, in this run). ``--random 250x400`` adds the same
speeds on a random stream of that size (``--frames`` steps, spike rate 0.3) and TFSTP's time for its last
frame alone (the scans from frame 0, without the per-frame readout of the others).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from spikenerf.camera.io import read_dat
from spikenerf.camera.reconstruct import tfi, tfp
from spikenerf.camera.tfstp import tfstp
from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.eval.recon_scores import score_reconstructions
from spikenerf.pipelines.benchmark.stats import t_interval
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.registry import DEFAULT_ELEVATION, DEFAULT_RADIUS
from spikenerf.scenes.trajectory import novel_views, orbit

FPS = 40000.0
METHODS = ("tfp", "tfi", "tfstp")


def simulate(out: Path, scene: str, size: int, frames: int, gt_every: int, turns: float) -> Path:
    """The gray dataset of ``scene`` in ``out/data`` (reused where it exists)."""
    root = out / "data"
    if not (root / "transforms.json").exists():
        traj = orbit(DEFAULT_RADIUS, DEFAULT_ELEVATION, turns, frames / FPS, FPS)
        source = AnalyticSource(scene, size, size, traj, novel_views(DEFAULT_RADIUS, 1), supersample=2)
        options = SimulateOptions(colors=("gray",), gt_every=gt_every, blur_fps=0.0)
        simulate_dataset(source, root, options, progress=False)
    return root


def frames_per_second(spikes: np.ndarray, repeats: int) -> dict[str, float]:
    """Frames a second of each method reconstructing every frame of ``spikes`` (T, H, W), best of
    ``repeats``."""
    run = {"tfp": lambda: tfp(spikes, 41), "tfi": lambda: tfi(spikes), "tfstp": lambda: tfstp(spikes)}
    speed = {}
    for name in METHODS:
        best = np.inf
        for _ in range(repeats):
            start = time.perf_counter()
            run[name]()
            best = min(best, time.perf_counter() - start)
        speed[name] = len(spikes) / best
    return speed


def random_speed(size: str, frames: int, repeats: int) -> None:
    """Print frames/s of each method on a random ``HxW`` stream of ``frames`` steps at spike rate 0.3."""
    height, width = (int(x) for x in size.split("x"))
    spikes = np.random.default_rng(0).random((frames, height, width)) < 0.3
    speed = frames_per_second(spikes, repeats)
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        tfstp(spikes, frames=frames - 1)
        best = min(best, time.perf_counter() - start)
    rates = ", ".join(f"{m} {speed[m]:.3g}" for m in METHODS)
    print(f"random {size}, {frames} frames, rate 0.3: frames/s {rates}; tfstp last frame alone {best:.3f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--scene", default="analytic-orbs")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--gt-every", type=int, default=10)
    parser.add_argument("--turns", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--random", metavar="HxW", help="also time a random stream of this size")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    root = simulate(args.out, args.scene, args.size, args.frames, args.gt_every, args.turns)
    result = score_reconstructions(root, ",".join(METHODS), lpips_backbone=None, progress=False)
    speed = frames_per_second(read_dat(root / "spikes_gray.dat", args.size, args.size), args.repeats)
    rows = result["rows"]
    per = {
        m: {k: np.array([r[k] for r in rows if r["method"] == m]) for k in ("psnr", "ssim")} for m in METHODS
    }
    n = len(per["tfp"]["psnr"])
    print(
        f"{args.scene} {args.size}x{args.size} gray, {args.frames} steps, {args.turns:g} turns, {n} GT frames"
    )
    print("method  PSNR (dB)  ΔPSNR vs tfp [95% CI]      SSIM    ΔSSIM vs tfp [95% CI]        frames/s")
    for m in METHODS:
        cells = []
        for key, fmt in (("psnr", "{:+.2f}"), ("ssim", "{:+.4f}")):
            diff = per[m][key] - per["tfp"][key]
            ci = t_interval(diff.tolist()) if m != "tfp" else None
            span = f"[{fmt.format(ci[0])}, {fmt.format(ci[1])}]" if ci else ""
            cells.append(f"{fmt.format(diff.mean()) if m != 'tfp' else '-':>7} {span:<19}")
        print(
            f"{m:<7} {per[m]['psnr'].mean():9.2f}  {cells[0]}  {per[m]['ssim'].mean():.4f}  {cells[1]}"
            f"  {speed[m]:8.0f}"
        )
    if args.random:
        random_speed(args.random, args.frames, args.repeats)


if __name__ == "__main__":
    main()

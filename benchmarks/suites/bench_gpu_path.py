"""The GPU path against its reference in the same run: eval, learned targets and ``--compile``.

Usage (from the repository root; meant for a CUDA host, runs on a CPU too)::

    .venv/bin/python -m benchmarks.suites.bench_gpu_path [--device cuda] [--size 400] [--frames 300]
        [--iters 300] [--rounds 2] [--compile] [--dataset DIR]

Without ``--dataset`` an ``analytic-orbs`` SIZE × SIZE gray dataset of FRAMES steps with 4 test views is
simulated first; ``nerf-gt`` trains ITERS iterations on the device (not timed here). Then, each pair
alternated for ROUNDS rounds, the median wall time of:

* ``eval``: the reference ``--chunk 8192 --precision fp32`` against ``--chunk 0`` (automatic) with the half
  precision of the device (fp16 on CUDA, fp32 elsewhere), seconds per view and the PSNR difference;
* learned targets of the whole stream: one frame per network call against ``CUDA_BATCH`` frames, on the
  device, seconds per 1000 frames and the largest difference;
* with ``--compile``: ms per training step, eager against ``--compile`` (compilation excluded: timed after
  20 warm-up steps).

Printed: every timing and each ratio reference / ours (> 1: ours is faster).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.data.dataset import load_dataset
from spikenerf.data.targets import load_stream
from spikenerf.eval.evaluate import evaluate_run
from spikenerf.recon.infer import CUDA_BATCH, reconstruct_learned
from spikenerf.scenes.registry import make_scene_source
from spikenerf.scenes.trajectory import novel_views, orbit
from spikenerf.train.config import TrainConfig
from spikenerf.train.trainer import Trainer


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed(fn: Callable[[], object], device: torch.device) -> tuple[float, object]:
    """(wall seconds, result) of ``fn()``, the device synchronised before and after."""
    _sync(device)
    t0 = time.perf_counter()
    out = fn()
    _sync(device)
    return time.perf_counter() - t0, out


def pair(name: str, unit: str, ref: Callable[[], float], ours: Callable[[], float], rounds: int) -> None:
    """Alternate ``ref`` and ``ours`` (each returns its time in ``unit``); print the medians and the ratio."""
    times: dict[str, list[float]] = {"reference": [], "ours": []}
    for r in range(rounds):
        for label, fn in (("reference", ref), ("ours", ours)):
            times[label].append(fn())
            print(f"{name} round {r} {label}: {times[label][-1]:.4g} {unit}", flush=True)
    a, b = statistics.median(times["reference"]), statistics.median(times["ours"])
    print(f"{name}: reference {a:.4g} {unit}, ours {b:.4g} {unit}, ratio {a / b:.2f}×", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--size", type=int, default=400)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--iters", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--compile", action="store_true", help="also time --compile against eager")
    parser.add_argument("--dataset", type=Path)
    args = parser.parse_args()
    device = torch.device(args.device)
    half = "fp16" if device.type == "cuda" else "fp32"
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        ds = args.dataset
        if ds is None:
            traj = orbit(4.0, 30.0, duration=args.frames / 40000)
            source = make_scene_source("analytic-orbs", args.size, args.size, traj, novel_views(4.0, 4))
            ds = simulate_dataset(
                source, root / "ds", SimulateOptions(gt_every=2, blur_fps=0), progress=False
            )
        cfg = TrainConfig(dataset=str(ds), method="nerf-gt", iters=args.iters, batch=4096, eval_every=0,
                          eval_views=1, device=args.device)  # fmt: skip
        Trainer(cfg, root / "run", progress=False).train()
        psnr: dict[str, float] = {}

        def view_seconds(chunk: int, precision: str) -> Callable[[], float]:
            def run() -> float:
                s, result = timed(lambda: evaluate_run(root / "run", device=args.device, lpips_backbone=None,
                                                       chunk=chunk, progress=False, precision=precision),
                                  device)  # fmt: skip
                psnr[precision] = result["mean"]["psnr"]  # type: ignore[index]
                return s / result["views"]  # type: ignore[index]

            return run

        pair("eval", "s/view", view_seconds(8192, "fp32"), view_seconds(0, half), args.rounds)
        print(f"eval: PSNR fp32 {psnr['fp32']:.3f} dB, {half} {psnr[half]:.3f} dB", flush=True)
        stream = load_stream(load_dataset(ds), "gray")
        images: dict[int, np.ndarray] = {}

        def learned(batch: int) -> Callable[[], float]:
            def run() -> float:
                s, out = timed(
                    lambda: reconstruct_learned(stream, "gray", device=device, batch=batch), device
                )
                images[batch] = out  # type: ignore[assignment]
                return 1000 * s / len(stream)

            return run

        pair("learned targets", "s/1000 frames", learned(1), learned(CUDA_BATCH), args.rounds)
        print(f"learned targets: largest difference {np.abs(images[1] - images[CUDA_BATCH]).max():.2e}")
        if args.compile:
            step_ms = {}
            for flag in (False, True):
                cfg.compile, cfg.iters = flag, 10**6
                trainer = Trainer(cfg, root / f"compile-{flag}", progress=False)
                trainer.evaluate = lambda *_a, **_k: float("nan")  # type: ignore[method-assign]
                trainer.checkpoint = lambda *_a, **_k: None  # type: ignore[method-assign]
                trainer.train(stop_after=20)
                s, _ = timed(lambda t=trainer: t.train(stop_after=50), device)
                step_ms[flag] = 1000 * s / 50
                print(f"train step {'compiled' if flag else 'eager'}: {step_ms[flag]:.3g} ms", flush=True)
            print(f"train step: eager / compiled {step_ms[False] / step_ms[True]:.2f}×")


if __name__ == "__main__":
    main()

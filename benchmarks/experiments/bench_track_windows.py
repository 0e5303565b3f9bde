"""Spike counts gathered along each point's image track: longer windows without the motion blur (issue 26).

spike-integral compares a render at one step ``k`` of a window with the window's spike count at the same
pixel; the image moves during the window, so windows must stay short (3 steps at 400×400) and their counts
noisy (``bench_count_noise``: an unbiased L-step count costs the oracle 1.7 dB at L = 3, 0.4 dB at L = 11).
Here, after ``--warmup`` iterations of the default method, each target is the count along the *track* of
the rendered point instead (``--set integral.track=h --set integral.track_after=WARMUP``; docs/spike-
integral.md): the point at the render's depth is projected into the poses of the ``2h + 1`` steps around
``k`` and the spike of each step is read at the pixel it falls in, ``φ/L Σ_j s_j(pixel_j)``. The depth is
the field's own (detached); occlusion changes along the track are not modelled.

Run (one thread per training; at 400×400 each run takes 5–7 minutes on the development CPU)::

    spikenerf --threads 1 simulate --scene analytic-orbs --width 400 --height 400 --color gray --out DS
    python -m benchmarks.experiments.bench_track_windows DS --half 5 --warmup 400

Prints the test PSNR (8 views) of the default spike-integral run and of the track run, trained in the same
run with the same seed, and their difference.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch

from spikenerf.train.config import IntegralConfig, TrainConfig
from spikenerf.train.trainer import Trainer


def train(dataset: Path, args: argparse.Namespace, out: Path, half: int) -> float:
    """Test PSNR of spike-integral (``half`` 0: as it is; else ``integral.track`` after the warm-up)."""
    integral = IntegralConfig(track=half, track_after=args.warmup)
    cfg = TrainConfig(dataset=str(dataset), iters=args.iters, eval_every=0, eval_views=8, seed=args.seed,
                      device="cpu", integral=integral)  # fmt: skip
    return float(Trainer(cfg, out, progress=False).train().test_psnr)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--half", type=int, default=5, help="h: tracks of 2h + 1 steps")
    parser.add_argument("--warmup", type=int, default=400, help="iterations of the default method first")
    parser.add_argument("--iters", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--skip-reference", action="store_true", help="train the track run only")
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        ref = float("nan") if args.skip_reference else train(args.dataset, args, Path(tmp) / "ref", 0)
        print(f"spike-integral (default): {ref:.2f} dB", flush=True)
        psnr = train(args.dataset, args, Path(tmp) / "track", args.half)
        print(f"track targets, {2 * args.half + 1} steps: {psnr:.2f} dB ({psnr - ref:+.2f} dB)", flush=True)


if __name__ == "__main__":
    main()

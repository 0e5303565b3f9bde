"""How much of spike-integral's gap to the oracle is the spike counts' quantisation noise alone.

The oracle (``nerf-gt``) is trained on its sharp ground-truth views twice or more in one run: once as it is
(the reference), and once per window length L with every target value ``v`` it draws replaced by
``floor(u + L v) / L``, ``u`` uniform in [0, 1) and drawn anew each time. That is the count of an ideal
spike pixel of steady light ``v`` (threshold 1) over L steps with an unknown accumulator start, divided by
L: unbiased, with the same ``± 1 / L`` spread as spike-integral's window targets, but with no camera
motion inside the window and the oracle's own views and poses. Comparing the noisy oracle with the clean one
gives the cost of the count noise alone; comparing it with spike-integral (L-step windows) gives what the
motion inside the windows and the stream's other differences add.

Run (one thread per training; at 400×400 each run takes 5–7 minutes on the development CPU)::

    spikenerf --threads 1 simulate --scene analytic-orbs --width 400 --height 400 --color gray --out DS
    python -m benchmarks.experiments.bench_count_noise DS --lengths 3,1 --iters 2000 --batch 4096

Prints the test PSNR of each run (8 test views, the trainer's own evaluation) and its difference to the clean
oracle trained in the same run with the same seed.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch

from spikenerf.train.config import TrainConfig
from spikenerf.train.trainer import Trainer


def count_noise(gather, length: int, seed: int):  # type: ignore[no-untyped-def]
    """``gather`` (index, pixels) → targets, with each value v replaced by floor(u + L v) / L (L = ``length``;
    0: unchanged)."""
    generator = torch.Generator().manual_seed(seed)

    def noisy(index: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
        value = gather(index, pixels)
        if length == 0:
            return value
        u = torch.rand(value.shape, generator=generator).to(value.device, value.dtype)
        return torch.floor(u + length * value.clamp(0.0, 1.0)) / length

    return noisy


def train_oracle(dataset: Path, length: int, args: argparse.Namespace, out: Path) -> float:
    """Test PSNR of ``nerf-gt`` on ``dataset`` with L-step count noise on its targets (0: none)."""
    cfg = TrainConfig(dataset=str(dataset), method="nerf-gt", batch=args.batch, iters=args.iters,
                      eval_every=0, eval_views=8, seed=args.seed, device="cpu")  # fmt: skip
    trainer = Trainer(cfg, out, progress=False)
    targets = trainer.method.targets
    targets.gather = count_noise(targets.gather, length, 1234 + args.seed)  # type: ignore[method-assign]
    return float(trainer.train().test_psnr)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--lengths", default="3,1", help="window lengths L of the noisy runs")
    parser.add_argument("--iters", type=int, default=2000)
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    lengths = [int(x) for x in args.lengths.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        clean = train_oracle(args.dataset, 0, args, Path(tmp) / "clean")
        print(f"oracle, clean targets: {clean:.2f} dB", flush=True)
        for length in lengths:
            psnr = train_oracle(args.dataset, length, args, Path(tmp) / f"L{length}")
            print(f"oracle, {length}-step count noise: {psnr:.2f} dB ({psnr - clean:+.2f} dB)", flush=True)


if __name__ == "__main__":
    main()

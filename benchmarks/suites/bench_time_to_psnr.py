"""Time to the same test PSNR: the ``grid`` field against the paper's vanilla NeRF ``mlp`` (target ≥ 20×).

Both train ``nerf-gt`` (sharp targets, so the comparison is about the field, not the supervision) on the same
small analytic dataset, each with its own schedule: the MLP with the paper's architecture, batch and learning
rate decay over 2·10⁵ iterations, the grid with its default 1500-iteration schedule. The MLP trains for a
budget of training seconds (evaluation excluded); the target PSNR is the best test PSNR it reached; then the
grid trains until it reaches that PSNR (or its own run ends). The ratio is MLP time / grid time to the target.

    .venv/bin/python -m benchmarks.suites.bench_time_to_psnr [--size 32] [--budget 1800] [--device auto]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from benchmarks._table import Row, format_table
from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.scenes.registry import make_scene_source
from spikenerf.scenes.trajectory import novel_views, orbit
from spikenerf.train.config import TrainConfig
from spikenerf.train.trainer import Trainer

SCENE = "analytic-orbs"


def make_dataset(root: Path, size: int) -> Path:
    """A 200-step orbit with a sharp GT render at every other step and 4 test views."""
    traj = orbit(4.0, 30.0, duration=200 / 40000)
    source = make_scene_source(SCENE, size, size, traj, novel_views(4.0, 4))
    return simulate_dataset(source, root / "ds", SimulateOptions(gt_every=2, blur_fps=0), progress=False)


def train_until(
    dataset: Path,
    out: Path,
    field: str,
    iters: int,
    budget_s: float,
    target: float | None,
    device: str,
    eval_every: int,
) -> list[tuple[float, float]]:
    """Train until ``budget_s`` training seconds pass, ``iters`` end or test PSNR ≥ ``target``.

    Returns the (training seconds, test PSNR on 2 views) curve, also printed as it grows.
    """
    config = TrainConfig(dataset=str(dataset), method="nerf-gt", field=field, iters=iters, device=device,
                         eval_every=eval_every, eval_views=2, ckpt_every=10**9)  # fmt: skip
    trainer = Trainer(config, out, progress=False)
    points: list[tuple[float, float]] = []
    while trainer.elapsed < budget_s and trainer.iteration < iters:
        trainer.train(stop_after=eval_every)
        points = [(row["seconds"], row["test_psnr"]) for row in trainer.curves]
        print(
            f"  {field}: iteration {trainer.iteration}, {points[-1][0]:.1f} s, {points[-1][1]:.2f} dB",
            flush=True,
        )
        if target is not None and points[-1][1] >= target:
            break
    return points


def first_time_at(points: list[tuple[float, float]], target: float) -> float | None:
    """The first training time (s) at which the test PSNR reached ``target`` (None if never)."""
    return next((t for t, psnr in points if psnr >= target), None)


def measure(size: int = 32, budget_s: float = 1800.0, device: str = "auto") -> list[Row]:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        dataset = make_dataset(root, size)
        mlp = train_until(dataset, root / "mlp", "mlp", 200_000, budget_s, None, device, eval_every=10)
        target = max(psnr for _, psnr in mlp)
        t_mlp = first_time_at(mlp, target)
        grid = train_until(dataset, root / "grid", "grid", 1500, budget_s, target, device, eval_every=10)
        t_grid = first_time_at(grid, target)
    print(f"target PSNR {target:.2f} dB (best of the MLP in {budget_s:.0f} s); "
          f"grid reached {max(p for _, p in grid):.2f} dB")  # fmt: skip
    if t_grid is None or t_mlp is None:
        print("the grid did not reach the target within its budget")
        return []
    return [Row(f"time to {target:.1f} dB ({size}×{size}, nerf-gt)", 1 / t_grid, 1 / t_mlp, "1/s", "mlp")]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--size", type=int, default=32)
    parser.add_argument("--budget", type=float, default=1800.0, help="training seconds of the MLP")
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    print(format_table(measure(args.size, args.budget, args.device)))


if __name__ == "__main__":
    main()

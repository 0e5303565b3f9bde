"""Spike counts gathered along each point's image track: longer windows without the motion blur (issue 26).

spike-integral compares a render at one step ``k`` of a window with the window's spike count at the same
pixel; the image moves during the window, so windows must stay short (3 steps at 400×400) and their counts
noisy (``bench_count_noise``: an unbiased L-step count costs the oracle 1.7 dB at L = 3, 0.4 dB at L = 11).
Here, after ``--warmup`` iterations of the default method, each target is the count along the *track* of
the rendered point instead: the point at the render's depth is projected into the poses of the ``2h + 1``
steps around ``k`` and the spike of each step is read at the pixel it falls in, ``φ/L Σ_j s_j(pixel_j)``.
Steps whose pixel leaves the image are left out. The depth is the field's own (detached), so occlusion
changes within the track and early depth errors are not modelled: this is an experiment, not a method.

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

from spikenerf.data.rays import pixel_rays
from spikenerf.train.config import TrainConfig
from spikenerf.train.losses import window_mean_loss
from spikenerf.train.methods import Term
from spikenerf.train.trainer import Trainer


def track_counts(trainer: Trainer, points: torch.Tensor, steps: torch.Tensor, half: int) -> torch.Tensor:
    """The mean spike intensity (B, C) along the image tracks of world ``points`` (B, 3) over the steps
    ``steps − half … steps + half`` (B,): each step's spike read at the pixel the point projects to."""
    counts = trainer.method.counts
    k = trainer.dataset.intrinsics
    prefix = counts.counts
    device = prefix.device
    offsets = torch.arange(-half, half + 1, device=device)
    j = steps.to(device)[:, None] + offsets[None]  # (B, L)
    valid = (j >= 0) & (j < prefix.shape[0] - 1)
    j = j.clamp(0, prefix.shape[0] - 2)
    c2w = counts.poses.to(device)[j]  # (B, L, 4, 4)
    rel = points.to(device)[:, None, :] - c2w[..., :3, 3]
    cam = torch.einsum("blij,bli->blj", c2w[..., :3, :3], rel)  # world → camera axes
    depth = -cam[..., 2]
    safe = torch.where(depth > 1e-6, depth, torch.ones_like(depth))
    x = torch.floor(k.fl_x * cam[..., 0] / safe + k.cx).long()
    y = torch.floor(k.cy - k.fl_y * cam[..., 1] / safe).long()
    valid &= (depth > 1e-6) & (x >= 0) & (x < k.width) & (y >= 0) & (y < k.height)
    x, y = x.clamp(0, k.width - 1), y.clamp(0, k.height - 1)
    spikes = (prefix[j + 1, y, x].int() - prefix[j, y, x].int()).float()  # (B, L, C)
    spikes = spikes * valid[..., None]
    return counts.threshold * spikes.sum(dim=1) / valid.sum(dim=1).clamp_min(1)[:, None].float()


def track_term(trainer: Trainer, half: int):  # type: ignore[no-untyped-def]
    """A replacement of ``SpikeIntegral.integral_term`` (one render per target) with track targets."""
    method = trainer.method

    def term(state, drawn=None):  # type: ignore[no-untyped-def]
        counts = method.counts
        _, _, pixels, steps = method.draw(state) if drawn is None else drawn
        step = steps[:, 0]
        poses = counts.poses[step.to(counts.poses.device)].to(state.device)
        out = state.render_rays(poses, pixels)
        with torch.no_grad():
            origins, dirs = pixel_rays(poses, trainer.dataset.intrinsics, pixels.to(state.device))
            points = origins + out.depth.detach()[:, None] * dirs
            target = track_counts(trainer, points, step, half).to(state.device)
        loss = window_mean_loss(out.color[:, None], target, None)
        return Term(loss, loss.detach(), poses.shape[0], out.dropped_samples)

    return term


def train(dataset: Path, args: argparse.Namespace, out: Path, half: int) -> float:
    """Test PSNR of spike-integral (``half`` 0: as it is; else track targets after the warm-up)."""
    cfg = TrainConfig(dataset=str(dataset), iters=args.iters, eval_every=0, eval_views=8, seed=args.seed,
                      device="cpu")  # fmt: skip
    trainer = Trainer(cfg, out, progress=False)
    if half:
        trainer.train(stop_after=args.warmup)
        trainer.method.integral_term = track_term(trainer, half)  # type: ignore[method-assign]
    return float(trainer.train().test_psnr)


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

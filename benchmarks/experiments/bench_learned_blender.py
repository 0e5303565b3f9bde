"""Learned reconstruction against TFP (same window) on datasets' sharp frames, e.g. the Blender scenes.

The learned network never sees a Blender scene in training, so this measures how far it carries to content
unlike its training set. PSNR of the sRGB-encoded gray frame against the dataset's sharp frame at each GT
step away from the stream's ends (where both windows are whole); one row per dataset and weights file, all
in the same run, then the mean over the datasets with a 95 % t-interval over them.

    spikenerf simulate --scene bricks --width 200 --height 200 --color gray --out /tmp/bricks200
    python -m benchmarks.experiments.bench_learned_blender /tmp/bricks200 [/tmp/plant200 ...] \\
        [--weights A.pt ...]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from scipy import stats

from spikenerf.camera.reconstruct import tfp
from spikenerf.core.color import srgb_encode
from spikenerf.core.psnr import mse_to_psnr
from spikenerf.data.dataset import load_dataset
from spikenerf.data.targets import image_channels
from spikenerf.recon.infer import reconstruct_learned


def _psnr(frame: np.ndarray, reference: np.ndarray) -> float:
    shown = srgb_encode(np.clip(frame, 0.0, 1.0))
    return float(mse_to_psnr(float(np.mean((shown - reference) ** 2))))


def gains(dataset: str, weights: list[str | None], window: int) -> tuple[int, float, list[np.ndarray]]:
    """(frames scored, mean TFP PSNR, per weights file the per-frame learned − TFP PSNR gains)."""
    ds = load_dataset(dataset)
    raw = np.asarray(ds.spikes("gray"))
    half = window // 2
    gt = image_channels(ds.gt.images, "gray").numpy()[..., 0]
    keep = [(i, int(s)) for i, s in enumerate(ds.gt.steps) if half <= int(s) < raw.shape[0] - half]
    refs = [srgb_encode(np.clip(gt[i], 0.0, 1.0)) for i, _ in keep]
    base = np.array(
        [
            _psnr(tfp(raw, window=window, threshold=ds.threshold, frames=slice(s, s + 1))[0], r)
            for (_, s), r in zip(keep, refs, strict=True)
        ]
    )
    out = []
    for w in weights:
        learned = [
            _psnr(reconstruct_learned(raw, "gray", ds.threshold, weights=w, frames=slice(s, s + 1))[0], r)
            for (_, s), r in zip(keep, refs, strict=True)
        ]
        out.append(np.array(learned) - base)
    return len(keep), float(base.mean()), out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("datasets", nargs="+", help="dataset folders with a gray stream and gt/ frames")
    p.add_argument(
        "--weights", action="append", default=None, help="weights file (repeatable; default shipped)"
    )
    p.add_argument("--window", type=int, default=41, help="window of both methods (the network's is 41)")
    a = p.parse_args()
    weights = a.weights or [None]
    names = [Path(w).name if w else "shipped" for w in weights]
    print(
        f"window {a.window}; PSNR (dB) of the gray frame at each GT step; Δ = learned − TFP (±95 % over them)"
    )
    print("| dataset | frames | TFP | " + " | ".join(f"Δ {n}" for n in names) + " |")
    print("|---|---:|---:|" + "---:|" * len(names))
    per_scene: list[list[float]] = [[] for _ in weights]
    for d in a.datasets:
        n, base, deltas = gains(d, weights, a.window)
        cells = []
        for j, g in enumerate(deltas):
            per_scene[j].append(float(g.mean()))
            ci = 1.96 * g.std(ddof=1) / math.sqrt(len(g)) if len(g) > 1 else float("nan")
            cells.append(f"{g.mean():+.2f} ± {ci:.2f} (min {g.min():+.2f})")
        print(f"| {Path(d).name} | {n} | {base:.2f} | " + " | ".join(cells) + " |", flush=True)
    if len(a.datasets) > 1:
        cells = []
        for scene in per_scene:
            x = np.array(scene)
            half = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x))
            cells.append(
                f"{x.mean():+.2f} [{x.mean() - half:+.2f}, {x.mean() + half:+.2f}] (min {x.min():+.2f})"
            )
        print(f"| mean over {len(a.datasets)} datasets (95 % t over them) | | | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()

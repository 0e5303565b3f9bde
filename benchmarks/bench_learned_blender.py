"""Learned reconstruction against TFP (same window) on a dataset's sharp frames, e.g. a Blender scene.

The shipped network was trained on analytic scenes only; this measures how far it carries to other content.
PSNR of the sRGB-encoded gray frame against the dataset's sharp frame at each GT step away from the stream's
ends (where both windows are whole).

    spikenerf simulate --scene bricks --width 200 --height 200 --color gray --out /tmp/bricks200
    python -m benchmarks.bench_learned_blender /tmp/bricks200
"""

from __future__ import annotations

import argparse

import numpy as np

from spikenerf.core.color import srgb_encode
from spikenerf.core.psnr import mse_to_psnr
from spikenerf.data.dataset import load_dataset
from spikenerf.data.targets import image_channels, reconstruct_stream

METHODS = ("tfp", "learned")


def _psnr(frame: np.ndarray, reference: np.ndarray) -> float:
    shown = srgb_encode(np.clip(frame, 0.0, 1.0))
    return float(mse_to_psnr(float(np.mean((shown - reference) ** 2))))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset", help="a dataset folder with a gray stream and gt/ frames")
    p.add_argument("--window", type=int, default=41, help="window of both methods (the network's is 41)")
    a = p.parse_args()
    ds = load_dataset(a.dataset)
    raw = ds.spikes("gray")
    half = a.window // 2
    gt = image_channels(ds.gt.images, "gray").numpy()[..., 0]
    scores = {m: [] for m in METHODS}
    for i, step in enumerate(int(s) for s in ds.gt.steps):
        if not half <= step < raw.shape[0] - half:
            continue
        reference = srgb_encode(np.clip(gt[i], 0.0, 1.0))
        for m in METHODS:
            frame = reconstruct_stream(raw, m, a.window, ds.threshold, slice(step, step + 1))[0]
            scores[m].append(_psnr(frame, reference))
    tfp, learned = (np.array(scores[m]) for m in METHODS)
    gain = learned - tfp
    ci = 1.96 * gain.std(ddof=1) / np.sqrt(len(gain)) if len(gain) > 1 else float("nan")
    print(f"{len(gain)} GT steps of {a.dataset} (window {a.window})")
    print("| reconstruction | PSNR (dB) |\n|---|---:|")
    print(f"| TFP (reference, same run) | {tfp.mean():.2f} |\n| learned | {learned.mean():.2f} |")
    print(
        f"learned − TFP: {gain.mean():+.2f} dB (±{ci:.2f}, 95 %; "
        f"min {gain.min():+.2f}, max {gain.max():+.2f})"
    )


if __name__ == "__main__":
    main()

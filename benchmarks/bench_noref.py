"""Do the no-reference checks of ``spikenerf eval`` see wrong poses? Real-data workflow, truth known.

Run: ``.venv/bin/python -m benchmarks.bench_noref --out /tmp/bench-noref`` (resumable: finished steps in
``--out`` are reused). ``simulate --noise realistic --raw-width W+16`` writes a raw recording with a SpikeCV
``config.yaml`` and no poses; it is imported twice with ``--poses orbit``: with the true orbit (the reference)
and with a wrong elevation (``--wrong-elevation``, a misregistered trajectory). ``--method`` (spike-nerf)
trains on each for the same iterations, then ``spikenerf eval`` reports the no-reference checks at the same
check steps (the imported test keyframes). Printed: each metric's mean ± std over the check steps for both,
the ratio wrong / true, and the paired difference over the check steps with its 95% t interval (one training
run per pose set: the interval covers the check steps, not training seeds).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy import stats

FOV_DEG = 39.5978  # the analytic scenes' horizontal field of view
METRICS = ("masked_psnr", "masked_ssim", "interval_violation_rate", "interval_violation_mean")


def spikenerf(*args: object) -> None:
    cmd = [sys.executable, "-m", "spikenerf", "--threads", "1", *map(str, args)]
    print("$", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, check=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scene", default="analytic-blocks")
    p.add_argument("--width", type=int, default=96)
    p.add_argument("--height", type=int, default=64)
    p.add_argument("--frames", type=int, default=400)
    p.add_argument("--iters", type=int, default=300)
    p.add_argument("--method", default="spike-nerf")
    p.add_argument("--wrong-elevation", type=float, default=36.0, help="degrees; the truth is 30")
    a = p.parse_args()
    sim, rec = a.out / "sim", a.out / "rec" / "recording.dat"
    if not sim.exists():
        spikenerf("simulate", "--scene", a.scene, "--width", a.width, "--height", a.height, "--frames",
                  a.frames, "--noise", "realistic", "--raw-width", a.width + 16, "--blur-fps", 0,
                  "--test-views", 1, "--no-progress", "--out", sim)  # fmt: skip
    if not rec.exists():  # the camera's files alone
        rec.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(sim / "raw" / "config.yaml", rec.parent / "config.yaml")
        shutil.copy(sim / "raw" / "recording.dat", rec)
    rows = {}
    for name, elevation in (("true", 30.0), ("wrong", a.wrong_elevation)):
        ds, run = a.out / f"ds-{name}", a.out / f"run-{name}"
        if not ds.exists():
            spikenerf("import", rec, "--poses", "orbit", "--orbit", f"4,{elevation}", "--fov", FOV_DEG,
                      "--out", ds)  # fmt: skip
        if not (run / "metrics.json").exists():
            spikenerf("train", ds, "--method", a.method, "--iters", a.iters, "--eval-every", 0, "--quiet",
                      "--out", run)  # fmt: skip
            spikenerf("eval", run, "--lpips", "none", "--quiet")
        rows[name] = json.loads((run / "metrics.json").read_text())["no_reference"]
    print(f"\n{a.scene} {a.width}×{a.height}, {a.frames} steps, {a.method} {a.iters} it; check steps "
          f"{[r['step'] for r in rows['true']['per_step']]}; mean ± std over them")  # fmt: skip
    print("| metric | true orbit | wrong elevation | ratio wrong/true | paired wrong − true, 95% CI |")
    print("|---|---:|---:|---:|---:|")
    for key in METRICS:
        vals = {n: np.array([r[key] for r in rows[n]["per_step"]], dtype=float) for n in rows}
        cells = [f"{v.mean():.4f} ± {v.std(ddof=1) if len(v) > 1 else 0:.4f}" for v in vals.values()]
        diff = vals["wrong"] - vals["true"]  # the same check steps in both
        half = stats.t.ppf(0.975, len(diff) - 1) * diff.std(ddof=1) / np.sqrt(len(diff))
        ci = f"{diff.mean():+.4f} [{diff.mean() - half:+.4f}, {diff.mean() + half:+.4f}]"
        ratio = vals["wrong"].mean() / vals["true"].mean()
        print(f"| {key} | {cells[0]} | {cells[1]} | {ratio:.3f} | {ci} |")


if __name__ == "__main__":
    main()

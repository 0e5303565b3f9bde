"""What does modelling the lens gain? Training through the lens against ignoring it (the pinhole part only).

Run: ``.venv/bin/python -m benchmarks.experiments.bench_distortion --out /tmp/bench-distortion`` (resumable:
finished runs in ``--out`` are reused). An analytic scene is filmed through a barrel lens (``--k1``, ``--k2``,
OpenCV radial terms) along the default 30° orbit: spike streams, GT frames and the held-out test views all
through that lens (``AnalyticSource(distortion=...)``, then ``simulate_dataset``). The same dataset is copied
with the lens keys removed from its ``transforms*.json`` files: what a toolkit that keeps only the pinhole
part of a calibration trains on. Each method of ``--methods`` trains on both, once per seed, and
``spikenerf eval`` scores the held-out views, which are the lens's images in both cases.

Printed: test PSNR per condition (mean ± std over seeds), the paired difference lens − pinhole with its 95% t
interval over the seeds, each seed's difference, and how far the lens moves the image's corner pixel.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.pipelines.benchmark.stats import t_interval
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.distortion import TERMS, Distortion
from spikenerf.scenes.registry import DEFAULT_ELEVATION, DEFAULT_RADIUS
from spikenerf.scenes.trajectory import held_out_elevations, novel_views, orbit

FPS = 40000.0


def spikenerf(*args: object) -> None:
    cmd = [sys.executable, "-m", "spikenerf", "--threads", "1", *map(str, args)]
    print("$", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, check=True)


def simulate(out: Path, scene: str, size: int, frames: int, test_views: int, lens: Distortion) -> None:
    """The dataset of ``scene`` filmed through ``lens`` into ``out`` (skipped where it exists)."""
    if (out / "transforms.json").exists():
        return
    traj = orbit(DEFAULT_RADIUS, DEFAULT_ELEVATION, 1.0, frames / FPS, FPS)
    tests = novel_views(DEFAULT_RADIUS, test_views, held_out_elevations(DEFAULT_ELEVATION, 0.0), (0, 0, 0))
    source = AnalyticSource(scene, size, size, traj, tests, supersample=2, distortion=lens)
    simulate_dataset(source, out, SimulateOptions(blur_fps=0), progress=False)


def strip_lens(lens_ds: Path, out: Path) -> None:
    """A copy of ``lens_ds`` whose ``transforms*.json`` files keep only the pinhole part of the camera."""
    if (out / "transforms.json").exists():
        return
    shutil.copytree(lens_ds, out)
    for path in out.glob("transforms*.json"):
        meta = json.loads(path.read_text())
        for key in ("camera_model", *TERMS):
            meta.pop(key, None)
        path.write_text(json.dumps(meta, indent=1))


def test_psnr(run: Path) -> float:
    """The run's mean test PSNR (dB) from its metrics.json."""
    return float(json.loads((run / "metrics.json").read_text())["mean"]["psnr"])


def interval(diff: np.ndarray) -> str:
    """Mean of ``diff`` (N,) with its 95% t interval (N ≥ 2)."""
    low, high = t_interval(diff.tolist())
    return f"{diff.mean():+.2f} [{low:+.2f}, {high:+.2f}]"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scene", default="analytic-orbs")
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--test-views", type=int, default=4)
    p.add_argument("--iters", type=int, default=300)
    p.add_argument("--methods", default="nerf-gt,spike-integral")
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--k1", type=float, default=-0.3)
    p.add_argument("--k2", type=float, default=0.08)
    a = p.parse_args()
    lens = Distortion(k1=a.k1, k2=a.k2)
    lens_ds, pin_ds = a.out / "ds-lens", a.out / "ds-pinhole"
    simulate(lens_ds, a.scene, a.size, a.frames, a.test_views, lens)
    strip_lens(lens_ds, pin_ds)
    seeds = [int(s) for s in a.seeds.split(",")]
    scores: dict[tuple[str, str], list[float]] = {}
    for method in a.methods.split(","):
        for seed in seeds:
            for name, ds in (("lens", lens_ds), ("pinhole", pin_ds)):
                run = a.out / f"run-{method}-{name}-s{seed}"
                if not (run / "metrics.json").exists():
                    spikenerf("train", ds, "--method", method, "--iters", a.iters, "--seed", seed,
                              "--eval-every", 0, "--quiet", "--out", run)  # fmt: skip
                    spikenerf("eval", run, "--lpips", "none", "--quiet")
                scores.setdefault((method, name), []).append(test_psnr(run))
    k = AnalyticSource(a.scene, a.size, a.size, orbit(DEFAULT_RADIUS, 30.0, 1.0, 2 / FPS, FPS)).intrinsics
    xd, yd = np.array([k.cx / k.fl_x]), np.array([k.cy / k.fl_y])  # the corner pixel's (distorted) position
    x, y = lens.undistort(xd, yd)  # where its ray really points: a pinhole model puts it at (xd, yd)
    shift = float(np.hypot((x - xd)[0] * k.fl_x, (y - yd)[0] * k.fl_y))
    head = f"{a.scene} {a.size}×{a.size}, {a.frames} steps, lens k1={a.k1:g} k2={a.k2:g}"
    print(f"\n{head} (the corner pixel moves {shift:.1f} px), {a.iters} it, seeds {a.seeds}; test PSNR (dB)")
    print("\n| method | lens modelled | lens ignored (pinhole part) | modelled − ignored, paired (95% CI) | "
          "per seed |\n|---|---:|---:|---:|---:|")  # fmt: skip
    for method in a.methods.split(","):
        on, off = np.array(scores[(method, "lens")]), np.array(scores[(method, "pinhole")])
        per_seed = ", ".join(f"{d:+.2f}" for d in on - off)
        cells = [f"{v.mean():.2f} ± {v.std(ddof=1):.2f}" for v in (on, off)]
        print(f"| {method} | {cells[0]} | {cells[1]} | {interval(on - off)} | {per_seed} |")


if __name__ == "__main__":
    main()

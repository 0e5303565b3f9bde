"""How much the grid field cares which way the scene is turned in its box: the same simulation, exact poses.

Run after ``benchmarks.experiments.bench_import`` (it reads ``sim-SCENE`` from ``--data``)::

    PYTHONPATH=src python -m benchmarks.experiments.bench_axes --data /tmp/bench-import \\
        --out /tmp/bench-axes --angles 0,1,10,45 --scale 0.78

For each angle D it writes a copy of the simulated dataset whose world is turned by D degrees about +Z and
shrunk by ``--scale`` (``OUT/data-rotD/sim-SCENE``; the box stays [-1, 1]³, so the shrink keeps the turned
scene inside it at 45°), trains the same run on it as ``bench_refine.py``'s exact condition (``nerf-recon``,
``--iters``, the reduced grid, the hold-out; ``OUT/rotD/run-SCENE-exact-holdout``) and scores it the same way
on its own turned test views, off the orbit and on the path, with and without test-time pose fitting.
The reference is the copy at the first angle (0°: the analytic scenes' boxes lie along the grid's axes),
trained and scored in the same run; the table gives each angle's PSNR minus it. ``import --orient up``
turns an imported scene onto its vertical planes for this reason (docs/real-data.md).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from benchmarks.experiments import bench_refine
from spikenerf.data.dataset import load_dataset


def turned_copy(sim: Path, dst: Path, degrees: float, scale: float) -> Path:
    """A copy of the dataset folder ``sim`` whose world is turned by ``degrees`` about +Z and scaled by
    ``scale`` about the origin (every ``transforms*.json`` pose, near and far; the scene box is kept)."""
    from scipy.spatial.transform import Rotation

    if (dst / "transforms.json").exists():
        return dst
    turn = Rotation.from_euler("z", degrees, degrees=True).as_matrix()
    partial = dst.with_name(dst.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    shutil.copytree(sim, partial, ignore=shutil.ignore_patterns("tfp", "transforms_tfp.json"))
    for path in partial.glob("transforms*.json"):
        data = json.loads(path.read_text())
        for frame in data.get("frames", []):
            pose = np.asarray(frame["transform_matrix"], np.float64)
            pose[:3, :3] = turn @ pose[:3, :3]
            pose[:3, 3] = scale * (turn @ pose[:3, 3])
            frame["transform_matrix"] = pose.tolist()
        for key in ("near", "far"):
            if key in data:
                data[key] = data[key] * scale
        path.write_text(json.dumps(data))
    partial.rename(dst)
    return dst


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, required=True, help="bench_import's --out (sim-SCENE)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scenes", default="analytic-blocks")
    p.add_argument(
        "--angles", default="0,1,10,45", help="turns about +Z, degrees; the first is the reference"
    )
    p.add_argument("--scale", type=float, default=0.78, help="shrink of every copy (the 45° turn must fit)")
    p.add_argument("--holdout-steps", type=int, default=7, help="held-out check steps (an import's 7)")
    p.add_argument("--method", default="nerf-recon")
    p.add_argument("--iters", type=int, default=2000)
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--grid-init", type=int, default=32)
    p.add_argument("--grid", type=int, default=128)
    p.add_argument("--window-poses", type=int, default=4)
    p.add_argument("--fit-steps", type=int, default=50)
    p.add_argument("--fit-lr", type=float, default=2e-3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1)
    a = p.parse_args()
    a.holdout, a.pose_lr = True, None  # what bench_refine's training reads
    angles = [float(x) for x in a.angles.split(",")]
    rows = []
    for scene in a.scenes.split(","):
        sim = a.data / f"sim-{scene}"
        load_dataset(sim)  # a missing or broken simulation fails here, in one line
        for deg in angles:
            tag = f"rot{deg:g}"
            data = turned_copy(sim, a.out / f"data-{tag}" / f"sim-{scene}", deg, a.scale)
            run = a.out / tag / bench_refine.run_name(scene, "exact", a.seed, True)
            bench_refine.train(data, run, a, False, a.holdout_steps)
            row = {"scene": scene, "degrees": deg, "scale": a.scale, "seed": a.seed}
            rows.append({**row, **bench_refine.score(run, data, a.fit_steps, a.fit_lr)})
            print(json.dumps(rows[-1]), flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "results.json").write_text(json.dumps(rows, indent=1))
    keys = ("psnr", "psnr_pose_opt", "path_psnr", "path_psnr_pose_opt")
    print(
        f"\n{a.method}, {a.iters} iterations, grid {a.grid_init}³→{a.grid}³, scale {a.scale}, seed {a.seed}"
    )
    print(
        "| scene | turn° | off-orbit | Δ | pose-optimised | Δ | on path | Δ | on path, pose-optimised | Δ |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        ref = next(x for x in rows if x["scene"] == r["scene"] and x["degrees"] == angles[0])
        cells = " | ".join(
            f"{r.get(k, np.nan):.2f} | {r.get(k, np.nan) - ref.get(k, np.nan):+.2f}" for k in keys
        )
        print(f"| {r['scene']} | {r['degrees']:g} | {cells} |")
    sys.stdout.flush()


if __name__ == "__main__":
    main()

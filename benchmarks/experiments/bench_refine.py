"""Pose refinement (``train --refine-poses``) on imported recordings, scored against the simulated truth.

Run after ``benchmarks.experiments.bench_import`` (it reads ``sim-SCENE`` and ``imp-SCENE-fov-w21`` from
``--data``): ``PYTHONPATH=src python -m benchmarks.experiments.bench_refine --data /tmp/bench-import
--out /tmp/bench-refine``.

Per scene, three runs of the same training (``--method``, ``--iters``, a reduced grid): exact poses (the
simulated dataset), the COLMAP-estimated poses as imported (``--no-refine-poses``) and the estimated poses
with ``--refine-poses``. Every run is scored on the simulation's true held-out views (novel views off the
orbit): the run's trajectory (per step; refined where refined) is aligned with the true one by a similarity
(Umeyama on the positions, ``importing/alignment.py``), the true test poses are mapped into the run's frame by
the inverse of that alignment, rendered, and compared with the true images (PSNR on sRGB-encoded gray). The
exact run goes through the same alignment (≈ the identity): it is the reference, and the table gives each
run's PSNR minus the exact run's. The rotation error (mean / max, degrees) at the refined keyframes is given
before and after refinement (after the same similarity alignment).

Test-time pose optimisation (``--fit-steps``, default 100; 0 = off): every run, the exact one included, is
also scored after each mapped test pose was fitted to its own test image with the field frozen
(``train/pose_fit.py``, the BARF evaluation protocol; docs/metrics.md). Both PSNRs are printed: the
positions-only alignment above, and the pose-optimised one beside it.

The true test views lie off the orbit (elevations 15° and 45° against the orbit's 30°). With ``--holdout``
every run is also scored the same two ways on views **on the recorded path**: the simulation's sharp ``gt/``
frame nearest each of the run's held-out check steps (``RUN/holdout.json``; the first and last left out),
which no run trained on (``path_psnr``, ``path_psnr_pose_opt``).

``--seed N`` is every run's ``train --seed``. ``--holdout`` holds steps out of training as an imported
dataset does by default: an imported run its test keyframes (with their guard bands), the exact run as many
evenly spaced steps with the same band radius (so every condition trains on about as many steps); the
default ``--no-holdout`` trains on every step, as first measured. Run folders are named by seed (when not 0)
and hold-out; a folder whose ``config.yaml`` records other settings is refused.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from spikenerf.data.dataset import SpikeDataset, load_dataset
from spikenerf.data.holdout import read_record
from spikenerf.data.targets import ImageTargets, eval_view_targets, image_channels
from spikenerf.importing.alignment import trajectory_errors, umeyama
from spikenerf.train.checkpoint import load_checkpoint
from spikenerf.train.evaluate import evaluate_views
from spikenerf.train.pose_fit import fit_view_poses
from spikenerf.train.pose_refine import PoseRefiner, keyframes_of
from spikenerf.train.run import load_run

CONDITIONS = ("exact", "estimated", "refined")


def wanted(dataset: Path, a: argparse.Namespace, refine: bool, check_steps: int) -> dict:
    """The settings of one training run, as its ``config.yaml`` records them (the run folder's stamp)."""
    want = {"dataset": str(dataset), "method": a.method, "iters": a.iters, "batch": a.batch, "seed": a.seed,
            "holdout": a.holdout, "poses.refine": refine, "field_config.n_voxels_init": a.grid_init**3,
            "field_config.n_voxels_final": a.grid**3, "targets.window_poses": a.window_poses}  # fmt: skip
    if a.holdout and check_steps:
        want["holdout_steps"] = check_steps
    if refine:
        want["poses.lr"] = 1e-3 if a.pose_lr is None else a.pose_lr
    return want


#: settings a run written before they existed had, by their default
BEFORE_THE_KEY = {"targets.window_poses": 1}


def made_with(run: Path, want: dict) -> None:
    """Refuse (one line) a run folder whose ``config.yaml`` was written with other settings than ``want``."""
    if not (run / "config.yaml").exists():
        return
    have = yaml.safe_load((run / "config.yaml").read_text())
    got = {}
    for key in want:
        value = have
        for part in key.split("."):
            value = (value or {}).get(part)
        got[key] = value
    if "window_poses" not in (have.get("targets") or {}):  # written before the key: one pose per target
        got["targets.window_poses"] = BEFORE_THE_KEY["targets.window_poses"]
    if got["dataset"] is not None:
        got["dataset"] = str(Path(got["dataset"]))
    diff = {
        k: got[k] for k in want if (False if got[k] is None else got[k]) != want[k]
    }  # None: before the key
    if diff:
        sys.exit(f"{run}: made with {diff}, not {dict((k, want[k]) for k in diff)}; use another --out")


def train(dataset: Path, run: Path, a: argparse.Namespace, refine: bool, check_steps: int = 0) -> None:
    """Train one run (skipped when finished, resumed when interrupted). ``check_steps`` > 0: the hold-out
    of a dataset without imported test keyframes (the exact run) holds out that many evenly spaced steps."""
    made_with(run, wanted(dataset, a, refine, check_steps))
    if (run / "summary.json").exists():
        return
    grid = [
        f"field_config.{k}={v}" for k, v in (("n_voxels_init", a.grid_init**3), ("n_voxels_final", a.grid**3))
    ]
    cmd = [sys.executable, "-m", "spikenerf", "--threads", str(a.threads), "train", str(dataset),
           "--method", a.method, "--iters", str(a.iters), "--batch", str(a.batch), "--eval-every", "0",
           "--eval-views", "1", "--quiet", "--refine-poses" if refine else "--no-refine-poses",
           "--seed", str(a.seed), "--window-poses", str(a.window_poses), "--out", str(run),
           *(x for kv in grid for x in ("--set", kv))]  # fmt: skip
    # --no-holdout: as first measured, every step trains (the hold-out came later; docs/real-data.md)
    cmd.append("--holdout" if a.holdout else "--no-holdout")
    if a.holdout and check_steps:
        cmd += ["--holdout-steps", str(check_steps)]
    if refine and a.pose_lr is not None:
        cmd += ["--set", f"poses.lr={a.pose_lr}"]
    if (run / "checkpoint.pt").exists():
        cmd.append("--resume")
    print("$", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, check=True)


def run_trajectory(run: Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The run's per-step poses (T, 4, 4) (refined when it refined), its keyframes and their given poses."""
    _, config, ds = load_run(run)
    poses, steps = ds.trajectory.poses, ds.trajectory.steps
    state = load_checkpoint(run / "checkpoint.pt").get("poses")
    if state is None:
        return poses, None, None
    refiner = PoseRefiner(keyframes_of(ds, config.poses.keyframe_every))
    refiner.load_state_dict(state["refiner"])
    with torch.no_grad():
        refined = refiner(torch.as_tensor(poses, dtype=torch.float64).float(), steps).double().numpy()
    return refined, refiner.key_steps, poses


def score(run: Path, truth_dir: Path, fit_steps: int = 0, fit_lr: float = 2e-3) -> dict:
    """Test PSNR on the true held-out views mapped into the run's frame (and after fitting those poses to
    their images for ``fit_steps``, the field frozen), and keyframe rotation errors."""
    model, config, ds = load_run(run)
    truth = load_dataset(truth_dir)
    poses, keys, given = run_trajectory(run)
    s, rot, t = umeyama(poses[:, :3, 3], truth.trajectory.poses[:, :3, 3])
    views = eval_view_targets(truth, config.color)
    assert views is not None
    row = score_views(model, ds, views, (s, rot, t), (fit_steps, fit_lr))
    on_path = path_views(run, truth, config.color)
    if on_path is not None:  # views on the recorded path, where a single orbit constrains the geometry
        got = score_views(model, ds, on_path, (s, rot, t), (fit_steps, fit_lr))
        row.update({f"path_{k}": v for k, v in got.items() if k.startswith("psnr")})
        row["path_steps"] = on_path.steps.tolist()
    if keys is None:  # no refinement: the errors at the importer's keyframes
        keys = keyframes_of(ds, 20) if ds.config.get("imported") else None
        given = poses
    if keys is not None:
        before = trajectory_errors(given[keys], truth.trajectory.poses[keys])
        after = trajectory_errors(poses[keys], truth.trajectory.poses[keys])
        row.update({f"{k}_before": before[k] for k in ("rot_mean_deg", "rot_max_deg", "ate_rel")})
        row.update({f"{k}_after": after[k] for k in ("rot_mean_deg", "rot_max_deg", "ate_rel")})
    return row


def path_views(run: Path, truth: SpikeDataset, color: str) -> ImageTargets | None:
    """True sharp views on the recorded path at the run's held-out check steps (``RUN/holdout.json``): the
    simulation's ``gt/`` frame nearest each check step if it lies within half the band's radius of it, the
    first and last check step left out (their bands reach the ends of the stream, so training sees only one
    side). None without a hold-out record or without such frames."""
    record = read_record(run)
    gt_steps = np.asarray(truth.gt.steps, np.int64)
    if record is None or len(gt_steps) == 0:
        return None
    checks = np.asarray(record["check_steps"][1:-1], np.int64)
    if len(checks) == 0:
        return None
    nearest = np.abs(gt_steps[None, :] - checks[:, None]).argmin(1)
    nearest = nearest[
        np.abs(gt_steps[nearest] - checks) <= int(record["radius"]) // 2
    ]  # well inside the band
    if len(nearest) == 0:
        return None
    images = image_channels(np.asarray(truth.gt.images)[nearest], color)
    poses = torch.as_tensor(truth.trajectory.poses[gt_steps[nearest]], dtype=torch.float32)[:, None]
    return ImageTargets(poses, images, torch.as_tensor(gt_steps[nearest]))


def score_views(model: Any, ds: Any, views: ImageTargets, to_run: tuple, fit: tuple[int, float]) -> dict:
    """PSNR of ``views`` (true poses) mapped into the run's frame by the similarity ``to_run`` = (s, R, t)
    (truth = s·R·run + t), and after fitting the mapped poses to their images for ``fit[0]`` steps."""
    s, rot, t = to_run
    true = views.poses[:, 0].double().numpy()
    mapped = np.tile(np.eye(4), (len(true), 1, 1))
    mapped[:, :3, :3] = rot.T @ true[:, :3, :3]
    mapped[:, :3, 3] = ((true[:, :3, 3] - t) @ rot) / s
    views = dataclasses.replace(views, poses=torch.as_tensor(mapped, dtype=torch.float32)[:, None])
    row = {"psnr": evaluate_views(model, views, ds)}
    if fit[0] > 0:
        got = fit_view_poses(model, views.poses[:, 0], views.images.float(), ds.intrinsics, ds.near, ds.far,
                             steps=fit[0], lr=fit[1])  # fmt: skip
        row["psnr_pose_opt"] = evaluate_views(model, dataclasses.replace(views, poses=got.poses[:, None]), ds)
        row["fit_rot_deg"] = got.rotation_deg.tolist()
        row["fit_shift"] = got.translation.tolist()
    return row


def run_name(scene: str, condition: str, seed: int, holdout: bool) -> str:
    """The run folder's name: seed 0 without hold-out keeps the first measurements' names."""
    return f"run-{scene}-{condition}" + (f"-s{seed}" if seed else "") + ("-holdout" if holdout else "")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", type=Path, required=True, help="bench_import's --out")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scenes", default="analytic-orbs,analytic-blocks")
    p.add_argument("--imported", default="fov-w21", help="which import: imp-SCENE-THIS")
    p.add_argument("--method", default="nerf-recon")
    p.add_argument("--iters", type=int, default=600)
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--grid-init", type=int, default=32, help="initial grid resolution (cells per side)")
    p.add_argument("--grid", type=int, default=96, help="final grid resolution (cells per side)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--conditions", default=",".join(CONDITIONS))
    p.add_argument("--pose-lr", type=float, default=None, help="poses.lr of the refined runs (default: 1e-3)")
    p.add_argument("--fit-steps", type=int, default=100, help="test-time pose optimisation steps (0: off)")
    p.add_argument("--fit-lr", type=float, default=2e-3, help="its Adam rate")
    p.add_argument("--seed", type=int, default=0, help="train --seed of every run")
    p.add_argument("--window-poses", type=int, default=1, help="train --window-poses of every run")
    p.add_argument(
        "--holdout",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="hold steps out of training: an imported run its test keyframes, the exact run as "
        "many evenly spaced steps (default: off: every step trains, as first measured)",
    )
    a = p.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for scene in a.scenes.split(","):
        sim, imp = a.data / f"sim-{scene}", a.data / f"imp-{scene}-{a.imported}"
        for cond in a.conditions.split(","):
            run = a.out / run_name(scene, cond, a.seed, a.holdout)
            checks = len(
                yaml.safe_load((imp / "config.yaml").read_text())["imported"]["test_keyframes"] or []
            )
            train(sim if cond == "exact" else imp, run, a, cond == "refined", checks * (cond == "exact"))
            row = {"scene": scene, "condition": cond, "seed": a.seed, "holdout": a.holdout}
            rows.append({**row, **score(run, sim, a.fit_steps, a.fit_lr)})
            print(json.dumps(rows[-1]), flush=True)
            (a.out / "results.json").write_text(json.dumps(rows, indent=1))
    print(
        f"\n{a.method}, {a.iters} iterations, batch {a.batch}, grid {a.grid_init}³→{a.grid}³; "
        f"pose-optimised: {a.fit_steps} steps, rate {a.fit_lr}; seed {a.seed}, hold-out {a.holdout}"
    )
    print("| scene | poses | test PSNR | Δ vs exact | pose-optimised PSNR | Δ vs exact | fit mean° | "
          "rot mean° before → after | rot max° before → after | on path | Δ | "
          "on path, pose-optimised | Δ |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|---|---|---:|---:|---:|---:|")
    for r in rows:
        same = [x for x in rows if x["scene"] == r["scene"] and x["condition"] == "exact"]
        ref = same[0]["psnr"] if same else np.nan
        ref_opt = same[0].get("psnr_pose_opt", np.nan) if same else np.nan
        opt, fit = r.get("psnr_pose_opt", np.nan), np.mean(r.get("fit_rot_deg", [np.nan]))
        rot = (
            f"{r['rot_mean_deg_before']:.2f} → {r['rot_mean_deg_after']:.2f} | "
            f"{r['rot_max_deg_before']:.2f} → {r['rot_max_deg_after']:.2f}"
            if "rot_mean_deg_before" in r
            else "— | —"
        )
        path = [r.get(k, np.nan) for k in ("path_psnr", "path_psnr_pose_opt")]
        ref_path = [same[0].get(k, np.nan) if same else np.nan for k in ("path_psnr", "path_psnr_pose_opt")]
        print(f"| {r['scene']} | {r['condition']} | {r['psnr']:.2f} | {r['psnr'] - ref:+.2f} | {opt:.2f} | "
              f"{opt - ref_opt:+.2f} | {fit:.2f} | {rot} | {path[0]:.2f} | {path[0] - ref_path[0]:+.2f} | "
              f"{path[1]:.2f} | {path[1] - ref_path[1]:+.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()

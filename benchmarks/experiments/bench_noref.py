"""Do the no-reference checks of ``spikenerf eval`` see wrong poses? Real-data workflow, truth known.

Run: ``.venv/bin/python -m benchmarks.experiments.bench_noref --out /tmp/bench-noref`` (resumable: finished
steps in ``--out`` are reused). ``simulate --noise realistic --raw-width W+16`` writes a raw recording with a
SpikeCV ``config.yaml`` and no poses; it is imported with ``--poses orbit``: with the true orbit (30°, the
reference) and with each wrong elevation of ``--wrong-elevation`` (a misregistered trajectory). ``--method``
(spike-integral, train's default) trains on each for the same iterations, once per seed of ``--seeds``, then
``spikenerf eval`` reports the no-reference checks at the same check steps (the imported test keyframes).
Training holds those steps out (the default for imported datasets; ``--no-holdout`` trains on them, as before
the hold-out existed); the script prints the held-out steps and stops if the checks scored other steps.

Printed per wrong elevation: each metric's mean ± std over the (seed, check step) pairs for both pose sets,
the ratio wrong / true, the paired difference (same seed, same step) with its 95% t interval over those
pairs, each seed's mean difference, a stricter interval over the check steps alone (each step's
difference averaged over the seeds, N − 1 degrees of freedom), and how many pairs rank the true poses
first. The pairs' interval treats them as independent, but one step's scores in two seeds share the step's
content, and one run's steps share its field.
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
TRUE_ELEVATION = 30.0
METRICS = ("masked_psnr", "masked_ssim", "interval_violation_rate", "interval_violation_mean")
TEST_PSNR = "test psnr vs TFP keyframes"
HIGHER_IS_BETTER = ("masked_psnr", "masked_ssim", TEST_PSNR)


def spikenerf(*args: object) -> None:
    cmd = [sys.executable, "-m", "spikenerf", "--threads", "1", *map(str, args)]
    print("$", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, check=True)


def run_dir(out: Path, name: str, seed: int) -> Path:
    """``run-NAME`` for seed 0 (the layout of earlier runs, so they resume), ``run-NAME-sSEED`` after."""
    return out / (f"run-{name}" if seed == 0 else f"run-{name}-s{seed}")


def held_out_rows(run: Path, holdout: bool) -> tuple[list[dict], dict]:
    """The run's no-reference rows (one per check step) and per-view test scores, after checking that the
    checks scored exactly the held-out steps (or, with ``holdout`` False, that the run trained on them)."""
    metrics = json.loads((run / "metrics.json").read_text())
    nr = metrics["no_reference"]
    steps = [r["step"] for r in nr["per_step"]]
    record = run / "holdout.json"
    if holdout:
        held = json.loads(record.read_text()) if record.is_file() else None
        if held is None or nr["steps_trained_on"] or held["check_steps"] != steps:
            sys.exit(f"{run}: the checks scored steps {steps}, not the held-out ones ({held})")
        print(f"{run.name}: checks at steps {steps}, held out (radius {held['radius']}, "
              f"{held['excluded_steps']} of {held['total_steps']} steps never trained on)")  # fmt: skip
    else:
        if not nr["steps_trained_on"]:
            sys.exit(f"{run}: --no-holdout, but the run held its check steps out")
        print(f"{run.name}: checks at steps {steps}, trained on (no hold-out)")
    return nr["per_step"], {"psnr": [v["psnr"] for v in metrics["per_view"]]}


def interval(diff: np.ndarray) -> str:
    """Mean of ``diff`` (any shape, every entry one unit) with its 95% t interval."""
    d = diff.ravel()
    half = stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / np.sqrt(d.size)
    return f"{d.mean():+.4f} [{d.mean() - half:+.4f}, {d.mean() + half:+.4f}]"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scene", default="analytic-blocks")
    p.add_argument("--width", type=int, default=96)
    p.add_argument("--height", type=int, default=64)
    p.add_argument("--frames", type=int, default=400)
    p.add_argument("--iters", type=int, default=300)
    p.add_argument("--method", default="spike-integral", help="train's default; the first tables: spike-nerf")
    p.add_argument("--seeds", type=int, default=1, help="training seeds 0..N-1 per pose set")
    p.add_argument("--wrong-elevation", type=float, nargs="+", default=[36.0], help="degrees; truth 30")
    p.add_argument("--no-holdout", action="store_true", help="train on the check steps (the old setup)")
    p.add_argument(
        "--window-poses",
        type=int,
        default=None,
        help="train --window-poses (default: train's; the docs' tables used 1, before stop 12)",
    )
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
    # the first wrong elevation keeps the folder name "wrong" of earlier runs
    conds = {"true": TRUE_ELEVATION} | {("wrong" if i == 0 else f"wrong{e:g}"): e
                                         for i, e in enumerate(a.wrong_elevation)}  # fmt: skip
    rows: dict[str, list] = {n: [] for n in conds}
    views: dict[str, list] = {n: [] for n in conds}
    holdout = "--no-holdout" if a.no_holdout else "--holdout"
    for seed in range(a.seeds):
        for name, elevation in conds.items():
            ds, run = a.out / f"ds-{name}", run_dir(a.out, name, seed)
            if not ds.exists():
                spikenerf("import", rec, "--poses", "orbit", "--orbit", f"4,{elevation}", "--fov", FOV_DEG,
                          "--out", ds)  # fmt: skip
            if not (run / "metrics.json").exists():
                poses = () if a.window_poses is None else ("--window-poses", a.window_poses)
                spikenerf("train", ds, "--method", a.method, "--iters", a.iters, "--seed", seed, holdout,
                          *poses, "--eval-every", 0, "--quiet", "--out", run)  # fmt: skip
                spikenerf("eval", run, "--lpips", "none", "--quiet")
            per_step, per_view = held_out_rows(run, not a.no_holdout)
            rows[name].append(per_step)
            views[name].append(per_view["psnr"])
    steps = [r["step"] for r in rows["true"][0]]
    print(f"\n{a.scene} {a.width}×{a.height}, {a.frames} steps, {a.method} {a.iters} it, seeds "
          f"0..{a.seeds - 1}; check steps {steps} ({'trained on' if a.no_holdout else 'held out'}); "
          f"mean ± std over the {a.seeds}×{len(steps)} (seed, step) pairs")  # fmt: skip
    for name, elevation in conds.items():
        if name == "true":
            continue
        print(f"\n| metric | true orbit ({TRUE_ELEVATION:g}°) | wrong elevation ({elevation:g}°) | ratio "
              "wrong/true | paired wrong − true, 95% CI | per-seed mean difference | over steps, 95% CI "
              "| pairs ranking true first |")  # fmt: skip
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        table = {key: {n: [[r[key] for r in seed_rows] for seed_rows in rows[n]] for n in ("true", name)}
                 for key in METRICS}  # fmt: skip
        table[TEST_PSNR] = {n: views[n] for n in ("true", name)}
        for key, by_cond in table.items():
            vals = {n: np.array(v, dtype=float) for n, v in by_cond.items()}  # (seeds, steps)
            cells = [f"{v.mean():.4f} ± {v.std(ddof=1) if v.size > 1 else 0:.4f}" for v in vals.values()]
            diff = vals[name] - vals["true"]  # same seed, same check step
            ratio = vals[name].mean() / vals["true"].mean()
            seeds = ", ".join(f"{d:+.4f}" for d in diff.mean(axis=1))
            right = int(((diff < 0) if key in HIGHER_IS_BETTER else (diff > 0)).sum())
            print(f"| {key} | {cells[0]} | {cells[1]} | {ratio:.3f} | {interval(diff)} | {seeds} | "
                  f"{interval(diff.mean(axis=0))} | {right}/{diff.size} |")  # fmt: skip


if __name__ == "__main__":
    main()

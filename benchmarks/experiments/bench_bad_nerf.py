"""The BAD-NeRF-like baseline against the other blur baselines, in one run, on a small analytic scene.

``PYTHONPATH=src python -m benchmarks.experiments.bench_bad_nerf --out /tmp/bench-bad`` simulates one
``analytic-blocks`` dataset (gray, ideal camera; an orbit of ``--steps`` steps, ``--blur-views`` exposures of
``--exposure`` steps each, ``--test-views`` novel views; ``--shake A`` adds a fast look-at oscillation of
amplitude A scene units, a hand-shake-like rotation within each exposure) and trains, per seed, with the same
settings (a finished run's numbers are kept in its folder, so a second invocation with more ``--methods``
trains only the new ones):

* ``nerf-blur``: the blur views at their mid-exposure poses (the reference of the Δ column);
* ``nerf-bad``: learns each view's exposure start and end pose (``--set exposure.*`` defaults);
* ``nerf-bad (centre fixed)``: the same with ``exposure.learn_centre=false`` (only the half-motion);
* ``nerf-blur-aware``: the blur views at the true exposure poses (the upper bound of the blur methods);
* ``spike-nerf``: the spike stream of every step (a reference).

It prints each method's test PSNR (mean ± std over seeds), the paired difference to ``nerf-blur`` (mean ±
std; a 95% interval where there are ≥ 2 seeds) and, for nerf-bad, the exposure endpoints' errors against the
true ones before and after training (``train/exposure_poses.py:endpoint_errors``). ``results.json`` keeps
every number.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.data.dataset import load_dataset
from spikenerf.pipelines.benchmark.stats import summarize, t_interval
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.trajectory import novel_views, orbit
from spikenerf.train.config import TrainConfig
from spikenerf.train.exposure_poses import endpoint_errors, true_endpoints
from spikenerf.train.trainer import Trainer

#: name -> (method, exposure.learn_centre)
RUNS = {
    "nerf-blur": ("nerf-blur", True),
    "nerf-bad": ("nerf-bad", True),
    "nerf-bad (centre fixed)": ("nerf-bad", False),
    "nerf-blur-aware": ("nerf-blur-aware", True),
    "spike-nerf": ("spike-nerf", True),
}


def make_dataset(a: argparse.Namespace) -> Path:
    root = a.out / "dataset"
    if not (root / "transforms.json").exists():
        source = AnalyticSource(
            "analytic-blocks",
            a.size,
            a.size,
            orbit(4.0, 30.0, duration=a.steps / 40000, shake=a.shake),
            novel_views(4.0, a.test_views),
        )
        options = SimulateOptions(
            colors=("gray",), blur_fps=40000.0 / a.exposure, blur_views=a.blur_views, gt_every=10
        )
        simulate_dataset(source, root, options, progress=False)
    return root


def train_one(a: argparse.Namespace, root: Path, dataset, name: str, seed: int) -> dict:  # type: ignore[no-untyped-def]
    method, centre = RUNS[name]
    config = TrainConfig(dataset=str(root), method=method, iters=a.iters, batch=a.batch, seed=seed,
                         device="cpu", eval_every=0, eval_views=a.test_views, ckpt_every=a.iters)  # fmt: skip
    config.exposure.learn_centre = centre
    # the grid field's defaults when this was measured (docs/results.md section 5): they changed since, and
    # the exposure poses' gradients are sensitive to the marching step (tests/test_bad_nerf.py)
    config.field_config = {"step_ratio": 0.5, "decoder_bf16": False}
    out = a.out / "runs" / f"{name.replace(' ', '_').replace('(', '').replace(')', '')}-s{seed}"
    if (out / "bench_row.json").is_file():  # finished by an earlier invocation (e.g. with fewer methods)
        return json.loads((out / "bench_row.json").read_text())
    trainer = Trainer(config.validate(), out, dataset, resume=out.exists(), progress=False)
    learned = getattr(trainer.method, "exposures", None)
    truth = true_endpoints(dataset) if learned is not None else None
    before = None if learned is None else endpoint_errors(learned.poses.endpoints().cpu().numpy(), truth)
    t0 = time.perf_counter()
    summary = trainer.train()
    after = None if learned is None else endpoint_errors(learned.poses.endpoints().cpu().numpy(), truth)
    row = {"name": name, "seed": seed, "test_psnr": summary.test_psnr, "seconds": time.perf_counter() - t0,
           "endpoints_before": before, "endpoints_after": after}  # fmt: skip
    (out / "bench_row.json").write_text(json.dumps(row))
    print(json.dumps(row), flush=True)
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--size", type=int, default=48)
    p.add_argument("--steps", type=int, default=240)
    p.add_argument("--exposure", type=int, default=24, help="steps per exposure (24 of 240 = 36° of orbit)")
    p.add_argument("--blur-views", type=int, default=24)
    p.add_argument("--test-views", type=int, default=4)
    p.add_argument("--shake", type=float, default=0.0)
    p.add_argument("--iters", type=int, default=400)
    p.add_argument("--batch", type=int, default=512)
    p.add_argument("--seeds", default="0,1")
    p.add_argument("--methods", default=",".join(RUNS))
    a = p.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    fixed = {
        k: getattr(a, k)
        for k in ("size", "steps", "exposure", "blur_views", "test_views", "shake", "iters", "batch")
    }
    stamp = a.out / "args.json"  # the finished dataset and rows are reused: only for the same settings
    if stamp.is_file() and json.loads(stamp.read_text()) != fixed:
        sys.exit(f"{stamp}: this folder was made with {stamp.read_text().strip()}; use another --out")
    stamp.write_text(json.dumps(fixed))
    root = make_dataset(a)
    dataset = load_dataset(root)
    seeds = [int(s) for s in a.seeds.split(",")]
    names = [n.strip() for n in a.methods.split(",")]
    rows = [train_one(a, root, dataset, n, s) for s in seeds for n in names]
    (a.out / "results.json").write_text(json.dumps({"args": {k: str(v) for k, v in vars(a).items()},
                                                    "rows": rows}, indent=1))  # fmt: skip
    psnr = {n: np.array([r["test_psnr"] for r in rows if r["name"] == n]) for n in names}
    print(f"\n| method | test PSNR (dB, {len(seeds)} seeds) | Δ vs nerf-blur (paired) | s/run |")
    print("|---|---:|---:|---:|")
    for n in names:
        st = summarize(psnr[n].tolist())
        m, s = (st.mean, st.std or 0.0) if st else (float("nan"), 0.0)
        secs = np.mean([r["seconds"] for r in rows if r["name"] == n])
        diff = "–"
        if n != "nerf-blur" and "nerf-blur" in psnr:
            d = psnr[n] - psnr["nerf-blur"]
            ci = t_interval(d.tolist())
            diff = f"{d.mean():+.2f} ± {d.std(ddof=1) if len(d) > 1 else 0:.2f}"
            diff += f" [{ci[0]:+.2f}, {ci[1]:+.2f}]" if ci else ""
        print(f"| {n} | {m:.2f} ± {s:.2f} | {diff} | {secs:.0f} |")
    for n in names:
        errs = [(r["endpoints_before"], r["endpoints_after"]) for r in rows if r["name"] == n]
        if errs and errs[0][0] is not None:
            for key in ("rot_deg", "pos", "motion_deg", "spin_deg"):
                b, f = (np.mean([e[i][key] for e in errs]) for i in (0, 1))
                print(f"{n}: endpoint {key} {b:.3f} → {f:.3f} (mean over views and seeds)")


if __name__ == "__main__":
    main()

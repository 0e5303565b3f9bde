"""Which part of the realistic camera noise costs a method its test PSNR: an ablation in one run.

Simulates one scene several times with the same camera seed: noise-free (``ideal``), the ``realistic``
preset, and the preset with one group of its parameters switched off (``simulate --noise-param``):

- ``no-dark``: ``dark_mean=0 dark_std=0`` (no dark current);
- ``no-fixed``: ``threshold_std=0 capacitance_std=0 prnu_std=0`` (no per-pixel threshold or gain pattern);
- ``no-temporal``: ``jitter_std=0 photons_per_white=inf readout_delay=0`` (no per-step noise);
- ``dark-only``: everything off but the dark current;
- ``fixed-only``: everything off but the per-pixel threshold and gain patterns.

Then trains the method on each dataset once per training seed (with ``--set KEY=VALUE`` overrides of the
training config, as ``train --set``; ``--tag`` keeps such runs apart from the others) and prints each
variant's test PSNR (the trainer's own evaluation on the held-out views) and its difference from
``realistic``, paired over the seeds (mean and 95 % t interval).

Run (one thread per training; about a minute per training at 64×64 on the development CPU)::

    python -m benchmarks.experiments.bench_noise_ablation --out /tmp/ablation --scene analytic-blocks \\
        --size 64 --frames 1000 --iters 300 --seeds 0,1,2 --jobs 2
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy import stats

ALL_OFF = {"threshold_std": 0, "capacitance_std": 0, "prnu_std": 0, "jitter_std": 0,
           "photons_per_white": math.inf, "readout_delay": 0}  # fmt: skip
VARIANTS: dict[str, dict | None] = {
    "ideal": None,
    "realistic": {},
    "no-dark": {"dark_mean": 0, "dark_std": 0},
    "no-fixed": {"threshold_std": 0, "capacitance_std": 0, "prnu_std": 0},
    "no-temporal": {"jitter_std": 0, "photons_per_white": math.inf, "readout_delay": 0},
    "dark-only": ALL_OFF,
    "fixed-only": {
        "dark_mean": 0,
        "dark_std": 0,
        "jitter_std": 0,
        "photons_per_white": math.inf,
        "readout_delay": 0,
    },
}


def simulate(args: argparse.Namespace, name: str) -> Path:
    """The variant's dataset (simulated unless already there)."""
    out = args.out / f"data-{name}"
    if (out / "config.yaml").exists():
        return out
    params = VARIANTS[name]
    noise = ["--noise", "ideal"] if params is None else ["--noise", "realistic"]
    for key, value in (params or {}).items():
        noise += ["--noise-param", f"{key}={value}"]
    command = [sys.executable, "-m", "spikenerf", "--threads", "1", "simulate", "--scene", args.scene,
               "--width", str(args.size), "--height", str(args.size), "--frames", str(args.frames),
               "--test-views", str(args.test_views), "--blur-fps", "0", "--color", "gray", "--seed", "0",
               *noise, "--out", str(out), "--quiet"]  # fmt: skip
    subprocess.run(command, check=True)
    return out


def train(job: tuple[str, Path, int, argparse.Namespace]) -> tuple[str, int, float]:
    """(variant, seed, test PSNR) of one training (kept in ``run-<variant>-<seed>/result.json``)."""
    name, dataset, seed, args = job
    run = args.out / f"run-{name}{args.tag}-{seed}"
    done = run / "result.json"
    if done.exists():
        return name, seed, float(json.loads(done.read_text())["psnr"])
    import torch

    torch.set_num_threads(1)
    from spikenerf.core.atomic import write_text_atomic
    from spikenerf.train.config import TrainConfig
    from spikenerf.train.config_file import apply_overrides
    from spikenerf.train.trainer import Trainer

    cfg = TrainConfig(dataset=str(dataset), method=args.method, iters=args.iters, eval_every=0,
                      eval_views=args.test_views, seed=seed, device="cpu")  # fmt: skip
    cfg = TrainConfig.from_dict(apply_overrides(cfg.to_dict(), args.set)).validate()
    # a training stopped before its result.json was written continues from its checkpoint
    psnr = float(Trainer(cfg, run, resume=True, progress=False).train().test_psnr)
    write_text_atomic(done, json.dumps({"psnr": psnr}))
    return name, seed, psnr


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--scene", default="analytic-blocks")
    parser.add_argument("--method", default="spike-integral")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--test-views", type=int, default=4)
    parser.add_argument("--iters", type=int, default=300)
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--tag", default="", help="appended to the run folders' names (runs with --set)")
    args = parser.parse_args()
    names = args.variants.split(",")
    if unknown := [n for n in names if n not in VARIANTS]:
        parser.error(f"--variants: unknown {unknown}; known: {list(VARIANTS)}")
    seeds = [int(s) for s in args.seeds.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    datasets = {name: simulate(args, name) for name in ["realistic", *[n for n in names if n != "realistic"]]}
    jobs = [(name, path, seed, args) for name, path in datasets.items() for seed in seeds]
    with ProcessPoolExecutor(args.jobs) as pool:
        scores = {(n, s): p for n, s, p in pool.map(train, jobs)}
    base = np.array([scores["realistic", s] for s in seeds])
    print(
        f"{args.method} on {args.scene} {args.size}×{args.size}, {args.frames} steps, "
        f"{args.iters} iterations, seeds {args.seeds}: test PSNR (dB), and the difference from realistic "
        "paired over seeds (95 % CI)"
    )
    print("| noise | PSNR (mean ± std) | − realistic | 95 % CI |")
    print("|---|---:|---:|---:|")
    for name in datasets:
        values = np.array([scores[name, s] for s in seeds])
        diff = values - base
        half = (
            stats.t.ppf(0.975, len(seeds) - 1) * diff.std(ddof=1) / np.sqrt(len(seeds))
            if len(seeds) > 1
            else 0
        )
        spread = values.std(ddof=1) if len(seeds) > 1 else 0.0
        print(
            f"| {name} | {values.mean():.2f} ± {spread:.2f} | {diff.mean():+.2f} | "
            f"[{diff.mean() - half:+.2f}, {diff.mean() + half:+.2f}] |"
        )


if __name__ == "__main__":
    main()

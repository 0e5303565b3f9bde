"""CPU time per training iteration of several checkouts at the same checkpoint, interleaved (A/B).

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.tools.ab_train_step RUN before=OLD/src after=src [--rounds 3] [--steps 8]
        [--iters N] [--threads 1] [--clock cpu]

Each round runs ``benchmarks.tools.profile_train_step RUN --steps N --time-only`` once per build
(``NAME=SRC``, ``SRC`` first on ``PYTHONPATH``, ``--threads`` threads, one by default) in the order given,
so a load change on a shared machine hits every build. CPU time (``--clock wall``: wall time, for more than
one thread) per iteration after 2 warm-up iterations; the same checkpoint and samples for every build.
Printed: every run, each build's median and its ratio to the first build, and the per-round ratios of each
build to the first with their mean and 95 % t interval.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

from benchmarks._table import mean_and_interval

ROOT = Path(__file__).resolve().parents[2]  # the repository root


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("builds", nargs="+", help="NAME=SRC (a checkout's src folder)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--iters", type=int, help="the run's --iters (a finished run: more than it ran)")
    parser.add_argument("--threads", type=int, default=1, help="OMP_NUM_THREADS of each run")
    parser.add_argument("--clock", choices=("cpu", "wall"), default="cpu", help="process or wall time")
    args = parser.parse_args()
    builds = dict(b.split("=", 1) for b in args.builds)
    unit = f"{args.clock.upper() if args.clock == 'cpu' else 'wall'} ms/it"
    times: dict[str, list[float]] = {name: [] for name in builds}
    for r in range(args.rounds):
        for name, src in builds.items():
            env = {**os.environ, "PYTHONPATH": str(Path(src).resolve()), "OMP_NUM_THREADS": str(args.threads)}
            cmd = [sys.executable, "-m", "benchmarks.tools.profile_train_step", str(args.run)]
            cmd += ["--steps", str(args.steps), "--time-only", "--clock", args.clock]
            cmd += ["--iters", str(args.iters)] if args.iters else []
            out = subprocess.run(cmd, env=env, cwd=ROOT, check=True, capture_output=True, text=True).stdout
            times[name].append(float(out.split()[-1]))
            print(f"round {r} {name}: {times[name][-1]:.1f} {unit}", flush=True)
    base = next(iter(times.values()))
    for name, v in times.items():
        med = statistics.median(v)
        speed = statistics.median(base) / med
        print(f"{name}: median {med:.1f} {unit} ({speed:.2f}× the first build's speed)")
        if v is not base and len(v) > 1:
            ratios = [b / x for b, x in zip(base, v, strict=True)]
            print(f"  per round: {', '.join(f'{x:.2f}×' for x in ratios)}{mean_and_interval(ratios)}")


if __name__ == "__main__":
    main()

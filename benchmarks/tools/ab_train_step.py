"""CPU time per training iteration of several checkouts at the same checkpoint, interleaved (A/B).

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.tools.ab_train_step RUN before=OLD/src after=src [--rounds 3] [--steps 8]
        [--iters N]

Each round runs ``benchmarks.tools.profile_train_step RUN --steps N --time-only`` once per build
(``NAME=SRC``, ``SRC`` first on ``PYTHONPATH``, one thread) in the order given, so a load change on a shared
machine hits every build. CPU time (not wall time) per iteration after 2 warm-up iterations; the same
checkpoint and samples for every build. Printed: every run, each build's median and its ratio to the first
build.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the repository root


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("builds", nargs="+", help="NAME=SRC (a checkout's src folder)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--iters", type=int, help="the run's --iters (a finished run: more than it ran)")
    args = parser.parse_args()
    builds = dict(b.split("=", 1) for b in args.builds)
    times: dict[str, list[float]] = {name: [] for name in builds}
    for r in range(args.rounds):
        for name, src in builds.items():
            env = {**os.environ, "PYTHONPATH": str(Path(src).resolve()), "OMP_NUM_THREADS": "1"}
            cmd = [sys.executable, "-m", "benchmarks.tools.profile_train_step", str(args.run)]
            cmd += ["--steps", str(args.steps), "--time-only"]
            cmd += ["--iters", str(args.iters)] if args.iters else []
            out = subprocess.run(cmd, env=env, cwd=ROOT, check=True, capture_output=True, text=True).stdout
            times[name].append(float(out.split()[-1]))
            print(f"round {r} {name}: {times[name][-1]:.1f} CPU ms/it", flush=True)
    first = statistics.median(next(iter(times.values())))
    for name, v in times.items():
        med = statistics.median(v)
        print(f"{name}: median {med:.1f} CPU ms/it ({first / med:.2f}× the first build's speed)")


if __name__ == "__main__":
    main()

"""CPU time per training iteration of several finished runs (e.g. one per method), interleaved.

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.tools.bench_method_step REF_RUN RUN [RUN ...] [--rounds 3] [--steps 20]

Each round runs ``benchmarks.tools.profile_train_step RUN --steps N --iters I --time-only`` once per run, in
the order given (one thread, one process each), so a load change on a shared machine hits every run. Each run
resumes from its final checkpoint and trains ``--steps`` more iterations (``--iters`` extends its schedule
past the end), i.e. it measures a late step: full grid resolution, occupancy grid settled, spike loss on.
CPU time (not wall time) per iteration after 2 warm-up iterations. Printed: every measurement, each run's
median and its ratio to the first run's, measured in the same rounds.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

import yaml


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", help="finished run folders; the first is the reference")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=20)
    args = parser.parse_args()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    times: dict[Path, list[float]] = {run: [] for run in args.runs}
    for r in range(args.rounds):
        for run in args.runs:
            config = yaml.safe_load((run / "config.yaml").read_text())
            iters = int(config["iters"]) + 10 * args.steps
            cmd = [sys.executable, "-m", "benchmarks.tools.profile_train_step", str(run), "--time-only",
                   "--steps", str(args.steps), "--iters", str(iters)]  # fmt: skip
            done = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env)
            ms = float(done.stdout.split()[-1])
            times[run].append(ms)
            print(f"round {r + 1}: {run.name} ({config['method']}, batch {config['batch']}): {ms:.1f} ms/it",
                  flush=True)  # fmt: skip
    ref = statistics.median(times[args.runs[0]])
    print("\n| run | method | batch | CPU ms / iteration (median) | ÷ reference |\n|---|---|---:|---:|---:|")
    for run, values in times.items():
        config = yaml.safe_load((run / "config.yaml").read_text())
        med = statistics.median(values)
        print(f"| {run.name} | {config['method']} | {config['batch']} | {med:.1f} | {med / ref:.2f}× |")


if __name__ == "__main__":
    main()

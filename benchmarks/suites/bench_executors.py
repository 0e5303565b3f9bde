"""Cells per hour: the Ray executor with 1 and 2 workers against the local executor with ``--jobs 1`` and 2.

A tiny benchmark (analytic scene, 4 cells: nerf-gt, nerf-blur, nerf-recon, spike-nerf in gray) runs under each
executor in a fresh folder holding a copy of the same pre-simulated dataset, so only the cells are timed
(plus writing the tables, the same for all). Ray runs on a local cluster started in this process with
``num_cpus`` = the number of workers (each cell asks for 1 CPU) before the clock starts; every step runs with
``OMP_NUM_THREADS=1``. Repeats are interleaved (A B C D, A B C D, …) so that a change in the load hits
every configuration alike; the ratio is against ``--jobs 1`` measured in the same run.

    .venv/bin/python -m benchmarks.suites.bench_executors [--size 16] [--iters 30] [--repeats 2]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._table import Row, format_table
from spikenerf.pipelines.benchmark import BenchmarkConfig, run_benchmark

VARIANTS = ["nerf-gt", "nerf-blur", "nerf-recon", "spike-nerf"]
TRAIN = ["--batch", "256", "--eval-every", "1000", "--eval-views", "1"]
CONFIGS = {"local --jobs 1": ("local", 1), "local --jobs 2": ("local", 2), "ray, 1 worker": ("ray", 1),
           "ray, 2 workers": ("ray", 2)}  # fmt: skip


def config(out: Path, size: int, iters: int, executor: str, n: int) -> BenchmarkConfig:
    return BenchmarkConfig(["analytic-orbs"], VARIANTS, ["gray"], out, size=size, frames=100, iters=iters,
                           device="cpu", test_views=1, render=False, extra_train_args=TRAIN,
                           jobs=n if executor == "local" else 1, executor=executor)  # fmt: skip


def cells_per_hour(root: Path, dataset: Path, size: int, iters: int, executor: str, n: int) -> float:
    """One timed run of the 4 cells in a fresh folder (Ray: on a new local cluster of ``n`` CPUs)."""
    out = Path(tempfile.mkdtemp(dir=root))
    shutil.copytree(dataset, out / "datasets")
    if executor == "ray":
        import ray

        ray.init(address="local", num_cpus=n, include_dashboard=False, log_to_driver=False)
    try:
        start = time.perf_counter()
        run_benchmark(config(out, size, iters, executor, n))
        return len(VARIANTS) / (time.perf_counter() - start) * 3600
    finally:
        if executor == "ray":
            ray.shutdown()
        shutil.rmtree(out)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--size", type=int, default=16)
    parser.add_argument("--iters", type=int, default=30)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    os.environ["OMP_NUM_THREADS"] = "1"
    src = str(Path(__file__).resolve().parents[1] / "src")  # Ray workers import this checkout
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [src, os.environ.get("PYTHONPATH")]))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        seed = config(root / "seed", args.size, args.iters, "local", 1)
        seed.variants = VARIANTS[:1]
        run_benchmark(seed)  # simulates the dataset once
        rates: dict[str, list[float]] = {name: [] for name in CONFIGS}
        for r in range(args.repeats):
            for name, (executor, n) in CONFIGS.items():
                rates[name].append(cells_per_hour(root, root / "seed" / "datasets", args.size, args.iters,
                                                  executor, n))  # fmt: skip
                print(f"repeat {r + 1}: {name}: {rates[name][-1]:.0f} cells/h", file=sys.stderr, flush=True)
    reference = statistics.mean(rates["local --jobs 1"])
    rows = [
        Row(name, statistics.mean(v), reference, "cells/h", "local --jobs 1") for name, v in rates.items()
    ]
    print(format_table(rows))
    for name, v in rates.items():
        spread = f" ± {statistics.stdev(v):.0f} (std of {len(v)})" if len(v) > 1 else ""
        print(f"{name}: {statistics.mean(v):.0f}{spread} cells/h; runs: {', '.join(f'{x:.0f}' for x in v)}")


if __name__ == "__main__":
    main()

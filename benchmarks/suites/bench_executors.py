"""Cells per hour: the Ray executor with 1 and 2 workers against the local executor with ``--jobs 1`` and 2.

A tiny benchmark (analytic scene, 4 cells: nerf-gt, nerf-blur, nerf-recon, spike-nerf in gray) runs under each
executor in a fresh folder holding a copy of the same pre-simulated dataset, so only the cells are timed
(plus writing the tables, the same for all). Ray runs on a local cluster started in this process with
``num_cpus`` = the number of workers (each cell asks for 1 CPU) before the clock starts; every step runs with
``OMP_NUM_THREADS=1``. Repeats are interleaved (A B C D, A B C D, …) so that a change in the load hits
every configuration alike; the ratio is against ``--jobs 1`` measured in the same run.

    .venv/bin/python -m benchmarks.suites.bench_executors [--size 16] [--iters 30] [--repeats 2]
        [--device cpu] [--batch 256] [--configs local:1,local:2,ray:1,ray:2]

On a GPU host, ``--device cuda --size 200 --iters 500 --batch 4096 --configs local:1,local:4`` measures
what issue 27 asks of ``benchmark --jobs``: cells per hour of 4 cells at once on one GPU against one at a
time.
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
from spikenerf.core.marker import mark
from spikenerf.pipelines.benchmark import BenchmarkConfig, run_benchmark

VARIANTS = ["nerf-gt", "nerf-blur", "nerf-recon", "spike-nerf"]
TRAIN = ["--eval-every", "1000", "--eval-views", "1"]
DEFAULT_CONFIGS = "local:1,local:2,ray:1,ray:2"
#: this checkout's package folder, which Ray workers import
SRC = Path(__file__).resolve().parents[2] / "src"


def parse_configs(text: str) -> dict[str, tuple[str, int]]:
    """``EXECUTOR:N,…`` (local or ray) → {row name: (executor, N)}; the first is the reference."""
    out: dict[str, tuple[str, int]] = {}
    for item in text.split(","):
        executor, _, n = item.partition(":")
        if executor not in ("local", "ray") or not n.isdigit() or int(n) < 1:
            raise SystemExit(f"--configs: expected local:N or ray:N, found {item!r}")
        name = f"local --jobs {n}" if executor == "local" else f"ray, {n} worker{'s' * (int(n) > 1)}"
        out[name] = (executor, int(n))
    return out


def config(out: Path, args: argparse.Namespace, executor: str, n: int) -> BenchmarkConfig:
    return BenchmarkConfig(["analytic-orbs"], VARIANTS, ["gray"], out, size=args.size, frames=100,
                           iters=args.iters, device=args.device, test_views=1, render=False,
                           extra_train_args=[*TRAIN, "--batch", str(args.batch)],
                           jobs=n if executor == "local" else 1, executor=executor)  # fmt: skip


def cells_per_hour(root: Path, dataset: Path, args: argparse.Namespace, executor: str, n: int) -> float:
    """One timed run of the 4 cells in a fresh folder (Ray: on a new local cluster of ``n`` CPUs)."""
    out = Path(tempfile.mkdtemp(dir=root))
    mark(out, "benchmark")  # a benchmark folder of ours: run_benchmark refuses an unmarked one
    shutil.copytree(dataset, out / "datasets")
    if executor == "ray":
        import ray

        ray.init(address="local", num_cpus=n, include_dashboard=False, log_to_driver=False)
    try:
        start = time.perf_counter()
        run_benchmark(config(out, args, executor, n))
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
    parser.add_argument("--device", default="cpu", help="the cells' --device (cuda: many cells on one GPU)")
    parser.add_argument("--batch", type=int, default=256, help="the cells' --batch")
    parser.add_argument(
        "--configs", default=DEFAULT_CONFIGS, help="executors to compare, the first the reference"
    )
    args = parser.parse_args()
    configs = parse_configs(args.configs)
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(SRC), os.environ.get("PYTHONPATH")]))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        seed = config(root / "seed", args, "local", 1)
        seed.variants = VARIANTS[:1]
        run_benchmark(seed)  # simulates the dataset once
        rates: dict[str, list[float]] = {name: [] for name in configs}
        for r in range(args.repeats):
            for name, (executor, n) in configs.items():
                rates[name].append(cells_per_hour(root, root / "seed" / "datasets", args, executor, n))
                print(f"repeat {r + 1}: {name}: {rates[name][-1]:.0f} cells/h", file=sys.stderr, flush=True)
    first = next(iter(configs))
    reference = statistics.mean(rates[first])
    rows = [Row(name, statistics.mean(v), reference, "cells/h", first) for name, v in rates.items()]
    print(format_table(rows))
    for name, v in rates.items():
        spread = f" ± {statistics.stdev(v):.0f} (std of {len(v)})" if len(v) > 1 else ""
        print(f"{name}: {statistics.mean(v):.0f}{spread} cells/h; runs: {', '.join(f'{x:.0f}' for x in v)}")


if __name__ == "__main__":
    main()

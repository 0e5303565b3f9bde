"""Training throughput of this checkout against a reference commit, both run in one process tree, interleaved.

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.suites.bench_train_speed [--dataset DIR] [--ref 42328ae] [--iters 300]
                                                     [--rounds 2] [--threads 2] [--method spike-nerf]
                                                     [--ours-args "..."]

The reference commit is checked out with ``git worktree add`` into a temporary folder; both builds run the
same ``spikenerf train DATASET --method M --iters N --eval-views 8 --eval-every 0`` as subprocesses (the
reference with its own ``src`` first on ``PYTHONPATH``), alternating reference, ours, reference, ours, … so
that a load change on a shared machine hits both. Each run reports its own ``summary.json``: training rays/s
(rendered rays over the loop's time, evaluation and checkpoints excluded) and the test PSNR after the same
iterations on all held-out views, and the process's CPU time (``getrusage`` of the child: start-up and
evaluation included). Printed: every run, the per-round ratios ours / reference of rays/s and of CPU time,
and their medians, means and 95 % t intervals. ``--ours-args`` adds train options to this checkout's runs
only (e.g. ``--ours-args "--field-option step_ratio=0.5"`` to time the previous defaults). Ours trains with
``--window-poses 1`` (one pose per TFP target, as a reference before 8041e5c; ``--ref-window-poses`` pins
a later reference too), unless ``--ours-args`` says otherwise.
Without ``--dataset`` an ``analytic-orbs`` 100×100, 1000-step gray dataset is simulated first, by the
reference build (this checkout reads an older build's dataset; an older build may not read a newer one).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._table import mean_and_interval

ROOT = Path(__file__).resolve().parents[2]  # the repository root


def run_train(src: Path, dataset: Path, out: Path, args: argparse.Namespace, extra: list[str]) -> dict:
    """One ``spikenerf train`` (plus ``extra`` options) with ``src`` first on the path → its summary plus
    the wall seconds and the process's CPU seconds."""
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": str(args.threads)}
    cmd = [sys.executable, "-m", "spikenerf", "train", str(dataset), "--method", args.method]
    cmd += [
        "--iters",
        str(args.iters),
        "--eval-every",
        "0",
        "--eval-views",
        "8",
        "--quiet",
        "--out",
        str(out),
        *extra,
    ]
    start, cpu0 = time.perf_counter(), _children_cpu()
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
    summary = json.loads((out / "summary.json").read_text())
    summary["wall"], summary["cpu"] = time.perf_counter() - start, _children_cpu() - cpu0
    return summary


def _children_cpu() -> float:
    """CPU seconds (user + system) of all finished child processes so far."""
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, default=None)
    parser.add_argument("--ref", default="42328ae", help="reference commit")
    parser.add_argument("--iters", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--method", default="spike-nerf")
    parser.add_argument("--ours-args", default="", help="extra train options for this checkout only")
    parser.add_argument(
        "--ref-window-poses",
        action="store_true",
        help="the reference knows --window-poses (8041e5c or later): pin it to 1 there too",
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_train_speed_") as tmp_name:
        tmp = Path(tmp_name)
        ref = tmp / "ref"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(ref), args.ref], check=True
        )
        try:
            dataset = args.dataset
            if dataset is None:
                dataset = tmp / "orbs100"
                subprocess.run(
                    [sys.executable, "-m", "spikenerf", "simulate", "--scene", "analytic-orbs",
                     "--width", "100", "--height", "100", "--out", str(dataset), "--no-progress"],
                    env={**os.environ, "PYTHONPATH": str(ref / "src")},  # both builds read the older format
                    check=True,
                )  # fmt: skip
            builds = {"reference": ref / "src", "ours": ROOT / "src"}
            warm = "from spikenerf.fields import vm_kernel; print(vm_kernel.available())"  # build it untimed
            ours_env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
            kernel = subprocess.run(
                [sys.executable, "-c", warm], env=ours_env, capture_output=True, text=True, check=True
            ).stdout.strip()
            print(f"fused CPU kernel (ours) available: {kernel}")
            results: dict[str, list[dict]] = {name: [] for name in builds}
            print(
                f"dataset {dataset}, {args.method}, {args.iters} iterations, OMP_NUM_THREADS={args.threads}"
            )
            print("| round | build | rays/s | test PSNR (dB) | train s | wall s | process CPU s |")
            print("|---:|---|---:|---:|---:|---:|---:|")
            for r in range(args.rounds):
                for name, src in builds.items():
                    # the reference has one pose per TFP target; ours trains the same (--ours-args may differ)
                    extra = shlex.split(args.ours_args) if name == "ours" else []
                    if name == "ours" or args.ref_window_poses:
                        extra = ["--window-poses", "1", *extra]
                    s = run_train(src, dataset, tmp / f"{name}{r}", args, extra)
                    results[name].append(s)
                    print(
                        f"| {r} | {name} | {s['rays_per_second']:.0f} | {s['test_psnr']:.2f} | "
                        f"{s['seconds']:.1f} | {s['wall']:.1f} | {s['cpu']:.1f} |",
                        flush=True,
                    )
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(ref)], check=False)
    ratios = [
        o["rays_per_second"] / b["rays_per_second"]
        for o, b in zip(results["ours"], results["reference"], strict=True)
    ]
    dpsnr = [
        o["test_psnr"] - b["test_psnr"] for o, b in zip(results["ours"], results["reference"], strict=True)
    ]
    print(f"\nrays/s ratio ours / {args.ref} per round: {', '.join(f'{x:.2f}×' for x in ratios)}")
    print(f"median ratio: {statistics.median(ratios):.2f}×{mean_and_interval(ratios)}")
    cpu = [b["cpu"] / o["cpu"] for o, b in zip(results["ours"], results["reference"], strict=True)]
    print(f"process CPU time reference / ours per round: {', '.join(f'{x:.2f}×' for x in cpu)}")
    print(
        f"median CPU ratio: {statistics.median(cpu):.2f}×{mean_and_interval(cpu)} (whole processes: start-up"
        " and evaluation included)"
    )
    print(f"test PSNR ours − reference per round (dB): {', '.join(f'{x:+.2f}' for x in dpsnr)}")


if __name__ == "__main__":
    main()

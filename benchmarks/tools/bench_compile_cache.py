"""Seconds that ``train --compile`` spends compiling: one graph or two a run, with a cold and a warm cache.

Usage (from the repository root; on a GPU host ``PYTHONPATH=src python -m …``)::

    .venv/bin/python -m benchmarks.tools.bench_compile_cache [--dataset DIR] [--method nerf-gt]
        [--iters 200] [--batch 256] [--static-samples 48] [--threads 2] [--device auto]

Child processes train the same run (the compiled static step: ``--field-option static_samples=N
--field-option static_colors=16 --compile``, evaluation and checkpoints off), each with its steps timed one
by one and ``TORCHINDUCTOR_CACHE_DIR`` set to a temporary folder: (1) one graph a run (the sizes that
upsampling changes traced as symbols from the start, ``compiled_step.SYMBOLIC_FROM_START``, the default)
with an empty cache; (2) the same again, finding what (1) wrote there (warm: torch's FX-graph and
AOTAutograd caches); (3) two graphs a run (the first specialised to the first resolution, a recompile
after the first upsampling: before the change) with another empty cache. A child's compile seconds are its
steps' total less ``iters`` × its median step. Printed: each child's compile seconds, its steps over a
second (the compiles) and its median step; then (3) / (1) and (1) / (2). Without ``--dataset`` an
``analytic-orbs`` 64×64, 200-step gray dataset is simulated first.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def child(args: argparse.Namespace) -> None:
    """Train ``args.iters`` steps one at a time; print {"steps": [seconds, …]} as one JSON line."""
    import torch

    from spikenerf.train import compiled_step
    from spikenerf.train.config import TrainConfig
    from spikenerf.train.trainer import Trainer

    torch.set_num_threads(args.threads)
    compiled_step.SYMBOLIC_FROM_START = args.graphs == 1
    static = {"static_samples": args.static_samples, "static_colors": 16}
    cfg = TrainConfig(dataset=str(args.dataset), method=args.method, iters=args.iters, batch=args.batch,
                      eval_every=0, eval_views=1, ckpt_every=10**9, compile=True, device=args.device,
                      field_config=static)  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(cfg, Path(tmp) / "run", progress=False)
        trainer.evaluate = lambda *_a, **_k: float("nan")  # type: ignore[method-assign]
        trainer.checkpoint = lambda *_a, **_k: None  # type: ignore[method-assign]
        steps = []
        for _ in range(args.iters):
            start = time.perf_counter()
            trainer.train(stop_after=1)
            if trainer.device.type == "cuda":
                torch.cuda.synchronize(trainer.device)
            steps.append(time.perf_counter() - start)
    print(json.dumps({"steps": steps}))


def compile_seconds(steps: list[float]) -> float:
    """Seconds beyond ``len(steps)`` median steps: what compiling (and the first calls' warm-up) cost."""
    return sum(steps) - len(steps) * statistics.median(steps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, default=None)
    parser.add_argument("--method", default="nerf-gt")
    parser.add_argument("--iters", type=int, default=200)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--static-samples", type=int, default=48)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--graphs", type=int, choices=(1, 2), default=1, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args)
        return
    with tempfile.TemporaryDirectory() as tmp:
        if args.dataset is None:
            args.dataset = Path(tmp) / "orbs64"
            simulate = ["simulate", "--scene", "analytic-orbs", "--width", "64", "--height", "64", "--frames",
                        "200", "--out", str(args.dataset)]  # fmt: skip
            subprocess.run([sys.executable, "-m", "spikenerf", *simulate], check=True, capture_output=True)
        argv = [sys.executable, "-m", "benchmarks.tools.bench_compile_cache", "--child", "--dataset",
                str(args.dataset), "--method", args.method, "--iters", str(args.iters), "--batch",
                str(args.batch), "--static-samples", str(args.static_samples), "--threads", str(args.threads),
                "--device", args.device]  # fmt: skip
        print(f"{args.method}, {args.iters} steps of {args.batch} rays, static_samples "
              f"{args.static_samples}, {args.threads} thread(s), device {args.device}")  # fmt: skip
        cases = {"one graph, cold cache": (1, "one"), "one graph, warm cache": (1, "one"),
                 "two graphs, cold cache": (2, "two")}  # fmt: skip
        seconds = {}
        for case, (graphs, cache) in cases.items():
            env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": str(Path(tmp) / f"cache-{cache}")}
            done = subprocess.run([*argv, "--graphs", str(graphs)], env=env, capture_output=True, text=True)
            if done.returncode != 0:
                raise SystemExit(f"{case}: the child failed (exit {done.returncode}):\n{done.stderr[-3000:]}")
            steps = json.loads(done.stdout.strip().splitlines()[-1])["steps"]
            seconds[case] = compile_seconds(steps)
            slow = ", ".join(f"step {i}: {s:.1f} s" for i, s in enumerate(steps) if s > 1)
            print(f"{case}: compiling {seconds[case]:.1f} s ({slow or 'no step over 1 s'}), "
                  f"median step {1000 * statistics.median(steps):.1f} ms", flush=True)  # fmt: skip
        one, warm, two = seconds.values()
        print(f"compile seconds, two graphs / one graph (cold): {two / one:.2f}×; "
              f"one graph, cold / warm cache: {one / max(warm, 1e-9):.1f}×")  # fmt: skip


if __name__ == "__main__":
    main()

"""Where the time of a training step goes: ``torch.profiler`` over a few ``Trainer`` iterations, by category.

Usage (from the repository root; put another checkout's ``src`` first on ``PYTHONPATH`` to profile it)::

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.tools.profile_train_step RUN [--steps 10] [--iters 1500]

``RUN`` is a run folder with a checkpoint (e.g. ``spikenerf train … --iters 1500`` stopped part-way, or any
finished run with a larger ``--iters`` here); it is copied, resumed and trained for ``--steps`` more
iterations (evaluation and checkpoints switched off), so two builds can be profiled in the same state.
Printed: CPU ms per iteration (process time) and the profiler's self CPU time per category and per op.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import torch
from torch.profiler import profile

from spikenerf.train.config_file import load_config
from spikenerf.train.trainer import Trainer

#: op-name fragments → category (first match wins; everything else is "other tensor ops")
CATEGORIES = (
    ("vm_cpu_point_backward", "VM lookup points' gradient (fused kernel)"),  # pose refinement's samples
    ("_RowsBackward", "VM lookup backward (fused kernel)"),  # the bf16 rows' (both gradients)
    ("vm_cpu_backward", "VM lookup backward (fused kernel)"),
    ("vm_cpu_forward", "VM lookup forward (fused kernel)"),
    ("vm_cpu_until", "VM lookup forward (fused kernel)"),  # the density up to each ray's early stop
    ("grid_sampler_2d_backward", "grid_sample backward"),
    ("grid_sampler", "grid_sample forward"),
    ("embedding_bag", "gather (embedding_bag)"),
    ("index_add", "scatter (index_add)"),
    ("_fused_adam", "Adam"),
    ("lerp", "Adam"),
    ("addcdiv", "Adam"),
    ("sqrt", "Adam"),
    ("mm", "decoder MLP (mm)"),
    ("threshold", "decoder MLP (ReLU)"),
    ("sigmoid", "decoder MLP (sigmoid)"),
    ("index", "gathers (index)"),
    ("nonzero", "compaction (nonzero)"),
    ("repeat_interleave", "compaction (nonzero)"),
    ("cumsum", "compositing (cumsum/exp)"),
    ("exp", "compositing (cumsum/exp)"),
    ("mul", "elementwise mul"),
)


def category(name: str) -> str:
    return next((cat for frag, cat in CATEGORIES if frag in name), "other tensor ops")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--iters", type=int, default=None, help="the run's --iters (default: as stored)")
    parser.add_argument("--time-only", action="store_true", help="print only the ms per iteration (--clock)")
    parser.add_argument("--clock", choices=("cpu", "wall"), default="cpu", help="--time-only: process/wall")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        shutil.copytree(args.run, run)
        cfg = load_config(run / "config.yaml")
        cfg.iters, cfg.eval_every, cfg.ckpt_every = args.iters or cfg.iters, 0, 10**9
        trainer = Trainer(cfg, run, resume=True, progress=False)
        trainer.evaluate = lambda *_a, **_k: float("nan")  # type: ignore[method-assign]
        trainer.checkpoint = lambda *_a, **_k: None  # type: ignore[method-assign]
        trainer.train(stop_after=2)  # warm-up
        cpu0, wall0 = time.process_time(), time.perf_counter()
        trainer.train(stop_after=args.steps)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
        if args.time_only:
            print(f"{1000 * (cpu if args.clock == 'cpu' else wall) / args.steps:.1f}")
            return
        with profile() as prof:
            trainer.train(stop_after=args.steps)
    events = prof.key_averages()
    total = sum(e.self_cpu_time_total for e in events)
    by_cat: dict[str, float] = defaultdict(float)
    for e in events:
        by_cat[category(e.key)] += e.self_cpu_time_total
    print(f"iteration {trainer.iteration}, grid {getattr(trainer.model.field, 'resolution', '-')}, "
          f"{torch.get_num_threads()} thread(s): {1000 * cpu / args.steps:.0f} CPU ms/it, "
          f"{1000 * wall / args.steps:.0f} wall ms/it (unprofiled)")  # fmt: skip
    print("\n| category | share of op time |\n|---|---:|")
    for cat, us in sorted(by_cat.items(), key=lambda kv: -kv[1]):
        print(f"| {cat} | {100 * us / total:.1f} % |")
    print("\n" + events.table(sort_by="self_cpu_time_total", row_limit=15))


if __name__ == "__main__":
    main()

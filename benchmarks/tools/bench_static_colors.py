"""CPU time of a static-render training step with and without a colour budget (``static_colors``), A/B.

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.tools.bench_static_colors RUN [--samples 64] [--colors 16] [--steps 6]
        [--rounds 3]

``RUN`` is a finished grid run (any method); it is copied and resumed once, and the same trainer then runs
``--steps`` training steps (after 2 untimed ones) under each setting in turn, round after round, so both
see the same field and a load change on a shared machine hits both: the reference is
``--field-option static_samples=N`` (colour decoded in every slot), the other adds ``static_colors=C``.
One thread. Printed: CPU ms per step of every run, the medians and their ratio, and the slots above the
weight threshold that the budget left without colour a step (``RenderOutput.dropped_colors``).
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import torch

from spikenerf.train.config import load_config
from spikenerf.train.trainer import Trainer


def one_step(trainer: Trainer, it: int) -> None:
    """A training step's device part and optimiser update (no logging, schedules or checkpoints)."""
    step = trainer.method.losses(trainer, it)
    trainer.optimizer.zero_grad(set_to_none=True)
    step.total().backward()
    trainer.optimizer.step()


def timed(trainer: Trainer, samples: int, colors: int, steps: int) -> tuple[float, float]:
    """CPU ms per step under ``static_samples`` / ``static_colors``, and the slots left without colour."""
    field = trainer.model.field
    field.config = dataclasses.replace(field.config, static_samples=samples, static_colors=colors)
    it = trainer.iteration
    lost = 0.0
    render = trainer.model.render_rays

    def counting(*args, **kwargs):  # type: ignore[no-untyped-def]
        nonlocal lost
        out = render(*args, **kwargs)
        if out.dropped_colors is not None:
            lost += float(out.dropped_colors)
        return out

    trainer.model.render_rays = counting  # type: ignore[method-assign]
    try:
        for k in range(2):
            one_step(trainer, it + k)
        start = time.process_time()
        for k in range(steps):
            one_step(trainer, it + 2 + k)
        ms = 1000.0 * (time.process_time() - start) / steps
    finally:
        trainer.model.render_rays = render  # type: ignore[method-assign]
    return ms, lost


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--colors", type=int, default=16)
    parser.add_argument("--steps", type=int, default=6)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = load_config(args.run / "config.yaml")
    config.iters, config.eval_every = config.iters + 10_000, 0
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        shutil.copytree(args.run, run)
        trainer = Trainer(config, run, resume=True, progress=False)
        settings = {"every slot": 0, f"static_colors={args.colors}": args.colors}
        times: dict[str, list[float]] = {name: [] for name in settings}
        print(f"{args.run}: static_samples={args.samples}, batch {config.batch}, {args.steps} steps a run")
        for r in range(args.rounds):
            for name, colors in settings.items():
                ms, lost = timed(trainer, args.samples, colors, args.steps)
                times[name].append(ms)
                extra = f", {lost / args.steps:.0f} coloured slots left out a step" if colors else ""
                print(f"round {r}: {name}: {ms:.1f} ms/step{extra}", flush=True)
    ref, ours = (statistics.median(v) for v in times.values())
    print(f"median: every slot {ref:.1f} ms, static_colors={args.colors} {ours:.1f} ms: {ref / ours:.2f}×")


if __name__ == "__main__":
    main()

"""CPU time of a static-render training step with and without the colour and visible budgets, A/B.

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.tools.bench_static_budgets RUN [--samples 64] [--colors 16]
        [--visible V] [--steps 6] [--rounds 3]

``RUN`` is a finished grid run (any method); it is copied and resumed once, and the same trainer then runs
``--steps`` training steps (after 2 untimed ones) under each setting in turn, round after round, so all
see the same field and a load change on a shared machine hits all: the reference is
``--field-option static_samples=N`` (colour decoded in every slot), the next adds ``static_colors=C``
(with ``--colors`` > 0), the last ``static_visible=V`` too (with ``--visible`` > 0). One thread. Printed:
CPU ms per step of every run, the medians and their ratios to the reference, the slots above the weight
threshold that the colour budget left without colour a step (``RenderOutput.dropped_colors``) and the
samples the budgets cut a step (``dropped_samples``).
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

from spikenerf.train.config_file import load_config
from spikenerf.train.trainer import Trainer


def one_step(trainer: Trainer, it: int) -> None:
    """A training step's device part and optimiser update (no logging, schedules or checkpoints)."""
    step = trainer.method.losses(trainer, it)
    trainer.optimizer.zero_grad(set_to_none=True)
    step.total().backward()
    trainer.optimizer.step()


def timed(trainer: Trainer, options: dict[str, int], steps: int) -> tuple[float, float, float]:
    """CPU ms per step under the field ``options``, the slots left without colour and the samples cut."""
    field = trainer.model.field
    field.config = dataclasses.replace(field.config, **options)
    it = trainer.iteration
    lost, cut = 0.0, 0.0
    render = trainer.model.render_rays

    def counting(*args, **kwargs):  # type: ignore[no-untyped-def]
        nonlocal lost, cut
        out = render(*args, **kwargs)
        lost += 0.0 if out.dropped_colors is None else float(out.dropped_colors)
        cut += 0.0 if out.dropped_samples is None else float(out.dropped_samples)
        return out

    trainer.model.render_rays = counting  # type: ignore[method-assign]
    try:
        for k in range(2):
            one_step(trainer, it + k)
        lost, cut = 0.0, 0.0
        start = time.process_time()
        for k in range(steps):
            one_step(trainer, it + 2 + k)
        ms = 1000.0 * (time.process_time() - start) / steps
    finally:
        trainer.model.render_rays = render  # type: ignore[method-assign]
    return ms, lost / steps, cut / steps


def settings(samples: int, colors: int, visible: int) -> dict[str, dict[str, int]]:
    """The field options of each setting, by name: the reference first."""
    base = {"static_samples": samples, "static_colors": 0, "static_visible": 0}
    out = {"every slot": base}
    if colors:
        out[f"static_colors={colors}"] = {**base, "static_colors": colors}
    if visible:
        name = f"static_colors={colors} static_visible={visible}" if colors else f"static_visible={visible}"
        out[name] = {**base, "static_colors": colors, "static_visible": visible}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--colors", type=int, default=16)
    parser.add_argument("--visible", type=int, default=0)
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
        chosen = settings(args.samples, args.colors, args.visible)
        times: dict[str, list[float]] = {name: [] for name in chosen}
        print(f"{args.run}: static_samples={args.samples}, batch {config.batch}, {args.steps} steps a run")
        for r in range(args.rounds):
            for name, options in chosen.items():
                ms, lost, cut = timed(trainer, options, args.steps)
                times[name].append(ms)
                print(f"round {r}: {name}: {ms:.1f} ms/step, {lost:.0f} coloured slots left out and "
                      f"{cut:.0f} samples cut a step", flush=True)  # fmt: skip
    ref = statistics.median(times["every slot"])
    for name, values in times.items():
        print(f"median: {name} {statistics.median(values):.1f} ms: {ref / statistics.median(values):.2f}×")


if __name__ == "__main__":
    main()

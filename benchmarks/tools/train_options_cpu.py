"""CPU time of the training loop and test PSNR for several grid-field options, each against the first.

Usage (from the repository root)::

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.tools.train_options_cpu --dataset DIR \\
        old:step_ratio=0.5,decoder_bf16=false new: [--iters 150] [--method spike-nerf]

Each ``NAME:KEY=VALUE,…`` (``--field-option`` values, read as YAML; nothing after the colon = the defaults;
the key ``compile=true`` is ``train --compile`` instead) trains one run from scratch in this process, one
after the other, with ``Trainer`` (one thread, seed 0, evaluation only at the end on 8 views). Printed per
run: the loop's CPU time (process time; evaluation and checkpoints excluded, so the load of a shared
machine changes it far less than wall time; compiling included), per iteration, the wall time of a step
over the second half of the run (after any compiling) and the test PSNR; then each run's ratios first /
this of the CPU time and of that late step, and its PSNR minus the first's.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch
import yaml

from spikenerf.train.config import TrainConfig
from spikenerf.train.trainer import Trainer


def parse(spec: str) -> tuple[str, dict]:
    """``NAME:KEY=VALUE,KEY=VALUE`` → (name, field options)."""
    name, _, rest = spec.partition(":")
    options = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        options[key] = yaml.safe_load(value)
    return name, options


def train_config(dataset: Path, method: str, iters: int, options: dict) -> TrainConfig:
    """The run's config: ``options`` as field options, but ``compile`` as ``train --compile``."""
    field = {k: v for k, v in options.items() if k != "compile"}
    return TrainConfig(dataset=str(dataset), method=method, iters=iters, eval_every=0, eval_views=8,
                       field_config=field, compile=bool(options.get("compile", False)))  # fmt: skip


def run(dataset: Path, out: Path, method: str, iters: int, options: dict) -> tuple[float, float, float]:
    """One run → (loop CPU seconds, wall seconds a step over the second half, test PSNR)."""
    cfg = train_config(dataset, method, iters, options)
    trainer = Trainer(cfg, out, progress=False)
    aside = [0.0]
    for name in ("evaluate", "checkpoint"):
        inner = getattr(trainer, name)

        def timed(*args, inner=inner, **kwargs):  # type: ignore[no-untyped-def]
            start = time.process_time()
            result = inner(*args, **kwargs)
            aside[0] += time.process_time() - start
            return result

        setattr(trainer, name, timed)
    start = time.process_time()
    trainer.train(stop_after=iters // 2)
    half = trainer.elapsed  # the loop's wall seconds so far (Trainer.elapsed: steps only)
    summary = trainer.train()
    late = (trainer.elapsed - half) / max(1, iters - iters // 2)
    return time.process_time() - start - aside[0], late, summary.test_psnr


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("runs", nargs="+", help="NAME:KEY=VALUE,… (the first is the reference)")
    parser.add_argument("--iters", type=int, default=150)
    parser.add_argument("--method", default="spike-nerf")
    args = parser.parse_args()
    torch.set_num_threads(1)
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, spec in enumerate(args.runs):
            name, options = parse(spec)
            cpu, late, psnr = run(args.dataset, Path(tmp) / str(i), args.method, args.iters, options)
            results.append((name, cpu, late, psnr))
            print(f"{name} {options}: loop CPU {cpu:.1f} s ({1000 * cpu / args.iters:.0f} ms/it), late step "
                  f"{1000 * late:.0f} ms, test PSNR {psnr:.4f} dB", flush=True)  # fmt: skip
    first, cpu0, late0, psnr0 = results[0]
    for name, cpu, late, psnr in results[1:]:
        print(f"{name}: CPU time {cpu0 / cpu:.2f}× less than {first}, late step {late0 / late:.2f}× faster, "
              f"test PSNR {psnr - psnr0:+.3f} dB")  # fmt: skip


if __name__ == "__main__":
    main()

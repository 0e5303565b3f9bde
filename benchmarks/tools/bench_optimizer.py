"""Time of one Adam update of the grid model, ``train``'s eager optimiser against ``--compile-optimizer``'s
compiled one (``train/compiled_optim.py``), in the same run.

Usage (from the repository root; on a GPU host ``PYTHONPATH=src python -m …``)::

    .venv/bin/python -m benchmarks.tools.bench_optimizer [--device auto] [--resolution 300] [--channels 1]
        [--steps 50] [--rounds 3] [--threads 0]

The model is the default grid field at ``--resolution``³ voxels (its final size; factors, basis matrix and
decoder), with random gradients in each parameter's layout. Each round times ``--steps`` updates of each
optimiser after 3 untimed ones, the two alternated; the learning rates change every step, as the decay does
in ``train``. Printed: the seconds the first compiled call took (compiling), the median ms an update of each,
their ratio (above 1: the compiled update is faster) and the largest parameter difference after the run
(both started from the same values and saw the same gradients).
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from spikenerf.core.device import resolve_device
from spikenerf.render import build_model
from spikenerf.train.compiled_optim import CompiledAdamStep, set_lr
from spikenerf.train.config import TrainConfig
from spikenerf.train.optimizer import make_optimizer
from spikenerf.train.preflight import model_config


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _model(resolution: int, channels: int, device: torch.device):  # type: ignore[no-untyped-def]
    voxels = resolution**3
    config = TrainConfig(
        field_config={"n_voxels_init": voxels, "n_voxels_final": voxels, "upsample_steps": []}
    )
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    return config, build_model("grid", channels, box, model_config(config)).to(device)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="auto")
    parser.add_argument("--resolution", type=int, default=300)
    parser.add_argument("--channels", type=int, default=1, choices=(1, 3))
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = resolve_device(args.device)
    config, eager_model = _model(args.resolution, args.channels, device)
    _, compiled_model = _model(args.resolution, args.channels, device)
    compiled_model.load_state_dict(eager_model.state_dict())
    eager_opt = make_optimizer(eager_model, config)
    compiled_opt = make_optimizer(compiled_model, TrainConfig(compile_optimizer=True))
    compiled = CompiledAdamStep(compiled_opt, lambda line: print("warning:", line), compiles=2)
    pairs = list(zip(eager_model.parameters(), compiled_model.parameters(), strict=True))
    size = sum(p.numel() for p, _ in pairs)
    print(f"grid R {args.resolution}: {len(pairs)} tensors, {size / 1e6:.1f} M parameters, {device}")
    g = torch.Generator(device=device).manual_seed(0)
    optimizers = {"eager": eager_opt, "compiled": compiled_opt}
    count = dict.fromkeys(optimizers, 0)

    def update(which: str) -> None:  # each optimiser's own decay: both see the same rates in turn
        count[which] += 1
        for group in optimizers[which].param_groups:
            set_lr(group, group["base_lr"] * 0.999 ** count[which])
        if which == "eager":
            eager_opt.step()
        else:
            compiled()

    # the same gradients for both, in each parameter's layout, kept for the whole run
    for p, q in pairs:
        grad = torch.empty_like(p).copy_(torch.randn(p.shape, generator=g, device=device) * 1e-2)
        p.grad, q.grad = grad, grad.clone()
    start = time.perf_counter()
    update("compiled")
    _sync(device)
    print(f"first compiled call (compiling): {time.perf_counter() - start:.1f} s")
    update("eager")
    for _ in range(2):
        update("compiled")
        update("eager")
    times: dict[str, list[float]] = {"eager": [], "compiled": []}
    for _ in range(args.rounds):
        for which in times:
            _sync(device)
            start = time.perf_counter()
            for _ in range(args.steps):
                update(which)
            _sync(device)
            times[which].append(1e3 * (time.perf_counter() - start) / args.steps)
    eager, fast = statistics.median(times["eager"]), statistics.median(times["compiled"])
    diff = max(float((p - q).detach().abs().max()) for p, q in pairs)
    print(f"eager (train's fused Adam): {eager:.3f} ms an update   compiled: {fast:.3f} ms")
    print(f"compiled / eager speed: {eager / fast:.2f}x   largest parameter difference {diff:.2e}")
    if compiled.failed:
        print(f"the compiled update failed and ran eagerly: {compiled.failed}")


if __name__ == "__main__":
    main()

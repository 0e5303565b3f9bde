"""Where a training step's wall time goes on a GPU: rays/s, GPU-busy share, launches and host syncs per step.

Usage (from the repository root; meant for a CUDA host, runs on a CPU too)::

    PYTHONPATH=src python -m benchmarks.tools.profile_cuda_step DATASET [--device cuda]
        [--methods nerf-gt,spike-integral] [--batches 4096,16384] [--warmup 100] [--steps 100]
        [--profile-steps 10] [--compile] [--compile-optimizer] [--field-option KEY=VALUE ...]
        [--start METHOD=RUN ...] [--json OUT.json]

For each method × batch a fresh ``Trainer`` (evaluation and checkpoints off; with ``--start``, one
resumed from a copy of a finished run, so that the step is the one at the end of training) trains ``--warmup``
iterations, then ``--steps`` more are timed with the device synchronised before and after (ms per step,
rays per second), then ``--profile-steps`` more run under ``torch.profiler`` (CPU and CUDA activities).
Printed per case: wall ms per step; GPU time per step (kernels and copies, each counted once) and its
share of the wall time (the rest is the GPU waiting on the host); kernel launches, host-device copies and
synchronisations per step; and the ops with the most host time and the most device time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import tempfile
import time
from pathlib import Path

import torch
import yaml
from torch.autograd import DeviceType
from torch.profiler import ProfilerActivity, profile

from spikenerf.train.checkpoint import load_checkpoint, save_checkpoint
from spikenerf.train.compiled_step import CompiledStep, static_samples
from spikenerf.train.config import TrainConfig
from spikenerf.train.config_file import load_config, save_config
from spikenerf.train.trainer import Trainer

#: runtime calls counted per step (host side of the CUDA API)
API_CALLS = {
    "launches": ("cudaLaunchKernel", "cuLaunchKernel", "cudaLaunchKernelExC", "cuLaunchKernelEx"),
    "copies": ("cudaMemcpyAsync", "cudaMemcpy"),
    "syncs": ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize"),
}


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _device_us(event: object) -> float:
    """Self device time (µs) of a profiler event, across torch versions (an op's counts its kernels')."""
    for name in ("self_device_time_total", "self_cuda_time_total"):
        value = getattr(event, name, None)
        if value is not None:
            return float(value)
    return 0.0


def gpu_us(events: list) -> float:
    """Device time (µs) of the kernels and copies in ``events``, each counted once: a host op's device time
    repeats that of the kernels it launched, so only device-side events are summed."""
    return sum(_device_us(e) for e in events if e.device_type != DeviceType.CPU)


def profile_case(dataset: Path, method: str, batch: int, args: argparse.Namespace, root: Path) -> dict:
    """Time and profile one method × batch; returns the figures printed."""
    device = torch.device(args.device)
    out, start = root / f"{method}-{batch}", dict(args.start).get(method)
    if start is None:
        cfg = TrainConfig(dataset=str(dataset), method=method, batch=batch, iters=10**6, eval_every=0,  # type: ignore[arg-type]
                          eval_views=1, device=args.device, compile=args.compile,
                          compile_optimizer=args.compile_optimizer,
                          field_config=dict(args.field_option))  # fmt: skip
        trainer = Trainer(cfg, out, progress=False)
    else:
        trainer = resumed(Path(start), method, out, batch, args)
    trainer.evaluate = lambda *_a, **_k: float("nan")  # type: ignore[method-assign]
    trainer.checkpoint = lambda *_a, **_k: None  # type: ignore[method-assign]
    trainer.train(stop_after=args.warmup)
    _sync(device)
    rays0, t0 = trainer.rays, time.perf_counter()
    trainer.train(stop_after=args.steps)
    _sync(device)
    wall = time.perf_counter() - t0
    rays = trainer.rays - rays0
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with profile(activities=activities) as prof:
        trainer.train(stop_after=args.profile_steps)
        _sync(device)
    events = prof.key_averages()
    step = trainer.method.step_losses
    n = args.profile_steps
    counts = {key: sum(e.count for e in events if e.key in names) / n for key, names in API_CALLS.items()}
    kernel_us = gpu_us(list(events)) / n
    ms = 1000 * wall / args.steps
    out = {
        "method": method,
        "batch": batch,
        "compile": args.compile,
        "compile_optimizer": args.compile_optimizer,
        "field_options": dict(args.field_option),
        "static_samples": static_samples(trainer.model),  # as rendered (a resumed model's own config)
        "compiled_step": isinstance(step, CompiledStep) and step.failed is None,
        "ms_per_step": ms,
        "rays_per_second": rays / wall,
        "gpu_kernel_ms_per_step": kernel_us / 1000,
        "gpu_busy_share": kernel_us / 1000 / ms if ms > 0 else 0.0,
        **{f"{k}_per_step": v for k, v in counts.items()},
        "top_host_ops": [
            (e.key, e.self_cpu_time_total / n / 1000, e.count / n)
            for e in sorted(events, key=lambda e: -e.self_cpu_time_total)[:12]
        ],
        "top_device_ops": [
            (e.key, _device_us(e) / n / 1000, e.count / n)
            for e in sorted(events, key=lambda e: -_device_us(e))[:12]
            if _device_us(e) > 0
        ],
    }
    gpu, busy = out["gpu_kernel_ms_per_step"], 100 * out["gpu_busy_share"]
    calls = ", ".join(f"{v:.0f} {k}" for k, v in counts.items())
    rate = out["rays_per_second"] / 1e3
    opts = "".join(f" {k}={v}" for k, v in args.field_option) + (" --compile" if args.compile else "")
    opts += " --compile-optimizer" if args.compile_optimizer else ""
    opts += " (compiled step)" if out["compiled_step"] else ""
    print(f"{method} batch {batch}{opts}: {ms:.2f} ms/step, {rate:.1f} k rays/s, GPU {gpu:.2f} ms/step "
          f"({busy:.0f} % busy), {calls} per step", flush=True)  # fmt: skip
    for title, key in (("host", "top_host_ops"), ("device", "top_device_ops")):
        print(f"  most {title} time (ms/step, calls/step):")
        for name, t, c in out[key]:
            print(f"    {t:8.3f} {c:7.1f}  {name[:90]}")
    return out


def resumed(run: Path, method: str, out: Path, batch: int, args: argparse.Namespace) -> Trainer:
    """A trainer continuing a copy (at ``out``) of the finished ``method`` run ``run``: its grid resolution
    and occupancy, with ``batch`` rays, ``--compile`` and the ``--field-option`` entries added to its field
    config."""
    cfg = load_config(run / "config.yaml")
    if cfg.method != method:
        raise SystemExit(f"--start {method}={run}: that run trained {cfg.method}")
    shutil.copytree(run, out)
    field = {**cfg.field_config, **dict(args.field_option)}
    cfg = dataclasses.replace(cfg, batch=batch, iters=cfg.iters + 10**5, eval_every=0, device=args.device,
                              compile=args.compile, compile_optimizer=args.compile_optimizer,
                              field_config=field)  # fmt: skip
    save_config(cfg, out / "config.yaml")  # the copy's options are the ones asked: nothing to refuse
    ckpt = load_checkpoint(out / "checkpoint.pt")
    ckpt["hparams"]["config"].update(dict(args.field_option))  # a resumed model is built from these
    save_checkpoint(out / "checkpoint.pt", ckpt)
    return Trainer(cfg, out, resume=True, progress=False)


def method_run(item: str) -> tuple[str, str]:
    """``METHOD=RUN`` for ``--start``."""
    method, sep, run = item.partition("=")
    if not sep or not method or not Path(run, "checkpoint.pt").is_file():
        raise argparse.ArgumentTypeError(f"expected METHOD=RUN with a finished run, found {item!r}")
    return method, run


def field_option(item: str) -> tuple[str, object]:
    """``KEY=VALUE`` as (key, YAML-parsed value), for ``--field-option``."""
    key, sep, value = item.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, found {item!r}")
    return key, yaml.safe_load(value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--methods", default="nerf-gt,spike-integral")
    parser.add_argument("--batches", default="4096,16384")
    parser.add_argument("--warmup", type=int, default=100)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--profile-steps", type=int, default=10)
    parser.add_argument("--compile", action="store_true", help="train with --compile")
    parser.add_argument("--compile-optimizer", action="store_true", help="train with --compile-optimizer")
    parser.add_argument("--field-option", type=field_option, action="append", default=[], metavar="KEY=VALUE",
                        help="a field config entry (e.g. static_samples=64); repeatable")  # fmt: skip
    parser.add_argument("--start", type=method_run, action="append", default=[], metavar="METHOD=RUN",
                        help="profile METHOD from a copy of the finished RUN (its final grid and occupancy) "
                        "instead of a fresh field; repeatable")  # fmt: skip
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    if args.device != "cpu":
        print(f"device: {torch.cuda.get_device_name(torch.device(args.device))}, torch {torch.__version__}")
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for method in args.methods.split(","):
            for batch in (int(b) for b in args.batches.split(",")):
                results.append(profile_case(args.dataset, method, batch, args, Path(tmp)))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()

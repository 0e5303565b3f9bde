"""Time of the grid's factor lookup, forward and backward, by implementation, against ``grid_sample`` in the
same run.

Usage (from the repository root; on a GPU host ``PYTHONPATH=src python -m …``)::

    .venv/bin/python -m benchmarks.tools.bench_lookup [--device auto] [--points 1048576] [--resolution 300]
        [--channels 16,24] [--repeats 20] [--rounds 3] [--triton-launch 64x4,32x4,64x8,128x8]

Points lie along random rays through the box, 64 consecutive samples a ray a cell apart (as a march lays
them out, so neighbouring points share texels, as they do in training). For each channel count C (16: the
density factors, summed over pairs and channels as the density is; 24: the appearance factors, (M, 3, C)
out) every lookup that runs on the device (``grid_sample``; ``gather``; ``triton`` on CUDA; the fused CPU
kernel on a CPU) does forwards alone, then forwards and backwards with a random output gradient,
interleaved, ``--rounds`` rounds of ``--repeats`` each (after 3 untimed). ``--triton-launch`` times the
Triton kernels once per launch shape, points a program × warps a program (``vm_triton.LAUNCH``), to pick
the fastest for each kernel. Printed: the median ms of the forward and of the pair, the pair's ratio to
``grid_sample`` (above 1: faster) and the largest difference of values and gradients from ``grid_sample``'s.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext

import torch
from torch import Tensor

from spikenerf.core.device import resolve_device
from spikenerf.fields import vm_kernel, vm_triton
from spikenerf.fields.grid import _factor
from spikenerf.fields.vm_gather import gather_vm
from spikenerf.fields.vm_sample import sample_vm, vm_splits

Lookup = Callable[[Tensor, Tensor, Tensor], Tensor]


def ray_points(m: int, resolution: int, device: torch.device, per_ray: int = 64) -> Tensor:
    """(m, 3) points in [−1, 1]: ``per_ray`` consecutive samples a cell apart along random rays."""
    g = torch.Generator().manual_seed(0)
    rays = -(-m // per_ray)
    origin = torch.rand(rays, 1, 3, generator=g) * 1.6 - 0.8
    direction = torch.nn.functional.normalize(torch.randn(rays, 1, 3, generator=g), dim=-1)
    t = torch.arange(per_ray).view(1, -1, 1) * (2.0 / (resolution - 1))
    return (origin + t * direction).reshape(-1, 3)[:m].clamp(-1, 1).contiguous().to(device)


def launch_shapes(text: str) -> list[tuple[int, int]]:
    """``"64x4,32x8"`` → [(64, 4), (32, 8)]: points a program (a power of 2) × warps a program (1–32)."""
    shapes = []
    for item in text.split(","):
        block, _, warps = item.strip().partition("x")
        if not (block.isdigit() and warps.isdigit()):
            raise argparse.ArgumentTypeError(f"{item!r} is not POINTSxWARPS, e.g. 64x4")
        b, w = int(block), int(warps)
        if b < 1 or b & (b - 1) or w not in (1, 2, 4, 8, 16, 32):
            raise argparse.ArgumentTypeError(
                f"{item!r}: points a power of 2, warps one of 1, 2, 4, 8, 16, 32"
            )
        shapes.append((b, w))
    return shapes


@contextmanager
def launched(block: int, warps: int) -> Iterator[None]:
    """Both Triton kernels launched with ``block`` points and ``warps`` warps a program, within."""
    before = dict(vm_triton.LAUNCH)
    vm_triton.LAUNCH.update(forward=(block, warps), backward=(block, warps))
    try:
        yield
    finally:
        vm_triton.LAUNCH.update(before)


def launch_of(name: str) -> AbstractContextManager:
    """Where the lookup ``name`` runs the Triton kernels ("triton PxW"), its launch shape for a whole step,
    the backward included (autograd launches that kernel after the forward has returned); else nothing."""
    if not name.startswith("triton "):
        return nullcontext()
    return launched(*launch_shapes(name.split()[1])[0])


def lookups(device: torch.device, launches: list[tuple[int, int]] | None = None) -> dict[str, Lookup]:
    """The implementations that run on ``device``, by name (each returns (M, 3, C)); the Triton kernels
    once per launch shape in ``launches`` (default: as ``vm_triton.LAUNCH`` has them)."""
    found: dict[str, Lookup] = {
        "grid_sample": lambda p, ln, x: sample_vm(p, ln, x, vm_splits(x.device)).permute(2, 0, 1),
        "gather": gather_vm,
    }
    probe = torch.zeros(1, device=device)
    if vm_triton.applies(probe, probe) and not vm_triton.interpreted():
        for block, warps in launches or [vm_triton.LAUNCH["backward"]]:
            found[f"triton {block}x{warps}"] = vm_triton.triton_vm  # at that shape: launch_of(name)
    if vm_kernel.usable(probe, probe):
        found["cpu kernel"] = vm_kernel.vm_lookup
    return found


def step(
    fn: Lookup, planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor, summed: bool, backward: bool = True
) -> list[Tensor]:
    """One forward and (``backward``) its backward → [output, plane gradient, line gradient] ([output])."""
    out = fn(planes, lines, xyz)
    out = out.sum(dim=(1, 2)) if summed else out
    if not backward:
        return [out]
    gp, gl = torch.autograd.grad(out, [planes, lines], grad)
    return [out.detach(), gp, gl]


def summed_lookup(name: str, fn: Lookup) -> Lookup:
    """The density's form of a lookup: the kernels sum inside (no (M, 3, C) tensor), the others after."""
    if name.startswith("triton "):
        return lambda p, ln, x: vm_triton.triton_vm(p, ln, x, summed=True)[:, None, None]
    if name == "cpu kernel":
        return lambda p, ln, x: vm_kernel.vm_lookup(p, ln, x, summed=True)[:, None, None]
    return fn


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="auto")
    parser.add_argument("--points", type=int, default=1 << 20)
    parser.add_argument("--resolution", type=int, default=300)
    parser.add_argument("--channels", default="16,24")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--triton-launch", type=launch_shapes, default=None, metavar="PxW,...",
                        help="Triton launch shapes to time, points x warps a program")  # fmt: skip
    args = parser.parse_args()
    device = resolve_device(args.device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    xyz = ray_points(args.points, args.resolution, device)
    found = lookups(device, args.triton_launch)
    print(f"device {device}, {args.points} points along rays, R {args.resolution}, "
          f"{torch.get_num_threads()} CPU thread(s); lookups: {', '.join(found)}")  # fmt: skip
    for channels in (int(c) for c in args.channels.split(",")):
        summed = channels == 16
        torch.manual_seed(channels)
        r = args.resolution
        planes = _factor((0.1 * torch.randn(3, channels, r, r)).to(device))
        lines = _factor((0.1 * torch.randn(3, channels, r, 1)).to(device))
        shape = (args.points,) if summed else (args.points, 3, channels)
        grad = torch.randn(shape, device=device)
        fns = {name: summed_lookup(name, fn) if summed else fn for name, fn in found.items()}
        reference = step(fns["grid_sample"], planes, lines, xyz, grad, summed)
        times: dict[tuple[str, bool], list[float]] = {(n, b): [] for n in fns for b in (False, True)}
        for _ in range(args.rounds):
            for (name, backward), spent in times.items():
                with launch_of(name):
                    for _ in range(3):
                        step(fns[name], planes, lines, xyz, grad, summed, backward)
                    sync()
                    start = time.perf_counter()
                    for _ in range(args.repeats):
                        step(fns[name], planes, lines, xyz, grad, summed, backward)
                    sync()
                spent.append(1000 * (time.perf_counter() - start) / args.repeats)
        base = statistics.median(times["grid_sample", True])
        print(f"\nC = {channels} ({'summed, as the density' if summed else '(M, 3, C), as the appearance'})")
        print("| lookup | forward ms | forward + backward ms | ratio to grid_sample | largest difference: "
              "value, plane grad, line grad |")  # fmt: skip
        print("|---|---:|---:|---:|---|")
        for name, fn in fns.items():
            ms, forward = statistics.median(times[name, True]), statistics.median(times[name, False])
            with launch_of(name):
                got = step(fn, planes, lines, xyz, grad, summed)
            diffs = [(a - b).abs().max().item() for a, b in zip(got, reference, strict=True)]
            differences = ", ".join(f"{d:.1e}" for d in diffs)
            print(f"| {name} | {forward:.2f} | {ms:.2f} | {base / ms:.2f}× | {differences} |")


if __name__ == "__main__":
    main()

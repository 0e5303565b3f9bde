"""Time of the grid renderer's march (which samples a batch of rays gets), by implementation, against the
packed torch march in the same run.

Usage (from the repository root; on a GPU host ``PYTHONPATH=src python -m …``)::

    .venv/bin/python -m benchmarks.tools.bench_march [--device auto] [--rays 16384] [--resolution 300]
        [--samples 64] [--repeats 10] [--rounds 3] [--threads N]

A grid model of ``--resolution`` cells a side (marching step 0.75 cell) whose occupancy grid (128 cells a
side) holds a spherical shell, as a trained object's surface would, and ``--rays`` rays from random points
on a sphere of radius 3 through random points of the box (no gradient: the march has none). Timed,
interleaved, ``--rounds`` rounds of ``--repeats`` (after 2 untimed):

- ``packed``: ``GridModel._march`` in torch ops, the reference (every candidate step laid out, tested,
  compacted; its host sync for the length included);
- ``static``: the static budget of ``--samples`` slots a ray (``_march_static`` over ``MARCH_SLOTS`` × the
  budget candidates, then ``compact_slots``), what a ``static_samples`` training step marches;
- ``triton packed``, ``triton static``: the same with ``march=triton`` (``render/march_triton.py``), where
  its kernels run compiled (CUDA; not in Triton's CPU interpreter, whose time means nothing).

Printed: the median ms of each, its speed against ``packed`` (above 1: faster), the kept samples a ray, and
whether each gives the packed march's samples (the static ones: its first ones, as many as the budget
holds). The static marches are timed as a training step calls them: slots of the budget, no compaction.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
from collections.abc import Callable

import torch
from torch import Tensor

from benchmarks._table import interleaved_ms, kernel_timing_args
from spikenerf.data.rays import ray_box_bounds
from spikenerf.fields.grid_config import GridFieldConfig
from spikenerf.fields.vm_triton import why_not
from spikenerf.render import build_model, volume_triton
from spikenerf.render.grid_model import MARCH_SLOTS, GridModel, compact_slots

BOX = torch.tensor([[-1.0] * 3, [1.0] * 3])


def scene(resolution: int, rays: int, device: torch.device, seed: int = 0) -> tuple[GridModel, tuple]:
    """A grid model with a shell of occupied cells (radius 0.45–0.6 of the box) and the march's inputs for
    ``rays`` rays: normalised origins and directions (N, 3), near and far (N,) shortened to the occupied
    box as ``render_rays`` does, and the step."""
    cfg = GridFieldConfig(n_voxels_init=resolution**3, n_voxels_final=resolution**3, decoder_bf16=False)
    model = build_model("grid", 3, BOX, cfg).to(device)
    field = model.field
    radius = field.occupancy.cell_centres().norm(dim=-1).reshape(field.occupancy.grid.shape)
    field.occupancy.grid.copy_((radius > 0.45) & (radius < 0.6))
    field.occupancy.bounds.copy_(torch.tensor([[-0.6] * 3, [0.6] * 3]))
    gen = torch.Generator().manual_seed(seed)
    eye = torch.randn(rays, 3, generator=gen)
    eye = 3.0 * eye / eye.norm(dim=-1, keepdim=True)
    dirs = torch.rand(rays, 3, generator=gen) * 1.6 - 0.8 - eye
    dirs = (dirs / dirs.norm(dim=-1, keepdim=True)).to(device)
    origins, step = eye.to(device), field.step_size
    near, far = ray_box_bounds(origins, dirs, BOX.to(device), min_near=0.0)
    near, far = model._shorten(origins, dirs, near, torch.maximum(far, near), step)
    d_n = dirs * (2.0 / (field.scene_box[1] - field.scene_box[0]))
    return model, (field.normalize(origins), d_n, near, far, step)


def marches(model: GridModel, inputs: tuple, samples: int, fused: bool) -> dict[str, Callable[[], tuple]]:
    """The march functions to time, as a training render calls them: packed, (ray, k) of the kept samples;
    static, (ray, k, keep) of the budget's slots (no compaction, no host sync)."""
    n = len(inputs[0])
    budget = n * samples

    def static() -> tuple[Tensor, Tensor, Tensor]:
        if model.marched(inputs[0]):
            ray, _, k, keep, _ = model._march_fused(*inputs, budget)
        else:
            ray, _, k, keep, _ = compact_slots(*model._march_static(*inputs, MARCH_SLOTS * budget), n, budget)
        return ray, k, keep

    def packed() -> tuple[Tensor, Tensor]:
        return model._march(*inputs)

    prefix = "triton " if fused else ""
    return {f"{prefix}packed": packed, f"{prefix}static": static}


def agreement(out: tuple, reference: tuple[Tensor, Tensor], budget: int) -> str:
    """ "yes" where a march's kept samples are the packed march's (a static one's: its first ones, as many
    as the budget holds), "first N of M" where they are a shorter run of its first ones (the torch static
    layout ends before the kept steps on a sparse grid), "NO" otherwise."""
    ray, k = (out[0][out[2]], out[1][out[2]]) if len(out) == 3 else out
    want = len(reference[0]) if len(out) == 2 else min(len(reference[0]), budget)
    m = len(ray)
    if m > want or not (torch.equal(ray, reference[0][:m]) and torch.equal(k, reference[1][:m])):
        return "NO"
    return "yes" if m == want else f"first {m} of {want}"


def compiled(x: Tensor) -> bool:
    """Whether the Triton kernels run compiled on ``x``'s device (timed there; in Triton's CPU interpreter
    their time means nothing)."""
    return x.device.type != "cpu" and volume_triton.applies(x)


@torch.no_grad()
def main() -> None:
    def extra(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--resolution", type=int, default=300, help="grid cells a side")
        parser.add_argument("--samples", type=int, default=64, help="static budget: slots a ray")

    args = kernel_timing_args(__doc__, extra)
    device = args.device
    model, inputs = scene(args.resolution, args.rays, device)
    impls = marches(model, inputs, args.samples, fused=False)
    with_kernels = compiled(inputs[0])
    if with_kernels:
        kernel_model = copy.deepcopy(model)
        kernel_model.field.config = dataclasses.replace(model.field.config, march="triton")
        impls |= marches(kernel_model, inputs, args.samples, fused=True)
    reference = impls["packed"]()
    kept = len(reference[0])
    same = {name: agreement(f(), reference, args.rays * args.samples) for name, f in impls.items()}
    times = interleaved_ms(impls, device.type == "cuda", args.rounds, args.repeats)
    base = times["packed"]
    candidates = int(model._counts(*inputs[2:]).sum())
    print(f"device {device}, {args.rays} rays, R {args.resolution}, {kept / args.rays:.1f} kept samples a "
          f"ray of {candidates / args.rays:.1f} steps, budget {args.samples} a ray, threads "
          f"{torch.get_num_threads()}; median of {args.rounds} rounds")  # fmt: skip
    print("| march | ms | speed vs packed | same samples |")
    print("|---|---:|---:|---|")
    for name, ms in times.items():
        print(f"| {name} | {ms:.3f} | {base / ms:.2f}× | {same[name]} |")
    if not with_kernels:
        print(f"triton: not timed here ({why_not(device) or 'only in the CPU interpreter'})")


if __name__ == "__main__":
    main()

"""The grid renderer's march as Triton kernels, for CUDA (opt-in: ``GridFieldConfig.march = "triton"``).

The torch march (``GridModel._march``, ``_march_static`` with ``compact_slots``) lays out every candidate
step of every ray (a prefix sum, ``repeat_interleave`` or ``searchsorted`` over ``MARCH_SLOTS`` × the
budget), tests each against the ray's end and the occupancy grid, and compacts the kept ones: a dozen
kernels over arrays several times the size of the result. Here (``march_triton_kernels.py``) one program
per ray tests its steps where they are made, twice: once to count the kept ones, and, after a running sum
of the counts gives each ray its first slot, once to write their ray and step number into their slots.
Nothing but the result is stored.

- :func:`packed`: ``GridModel._march``'s result (one host sync for its length, as there);
- :func:`static`: the kept steps in a fixed budget of slots (:func:`~spikenerf.render.grid_model.
  compact_slots`'s layout: spare slots after the last kept one), no host sync. Unlike the torch layout,
  which tests at most ``MARCH_SLOTS`` × budget candidate steps, every step of every ray is tested, so
  ``dropped`` is the exact number of kept steps past the budget.

Both are ``torch.library`` custom ops with fake implementations (integer outputs: no gradient), so
``torch.compile(fullgraph=True)`` keeps them in its graph. Where Triton runs is
:func:`~spikenerf.render.volume_triton.applies`. Not timed on a GPU yet (docs/performance.md).
"""

from __future__ import annotations

import contextlib
from typing import Any

import torch
from torch import Tensor

from spikenerf.core.tracing import custom_op

#: steps a program tests at a time, and warps a program: a guess, not tuned on a GPU yet
LAUNCH: dict[str, int] = {"BLOCK": 128, "num_warps": 4}


def _launch(name: str, rays: int, *args: Any, **constexprs: Any) -> None:
    """Run kernel ``name`` of ``march_triton_kernels`` with one program per ray."""
    from spikenerf.render import march_triton_kernels as kernels

    device = args[0].device
    on = torch.cuda.device(device) if device.type == "cuda" else contextlib.nullcontext()
    with on:  # Triton launches on the current device, not the tensors'; no contraction: torch's rounding
        getattr(kernels, name)[(rays,)](*args, **constexprs, **LAUNCH, enable_fp_fusion=False)


def _grid_args(grid: Tensor) -> tuple[Tensor, int]:
    return grid.reshape(-1).view(torch.uint8), grid.shape[0]


@custom_op("spikenerf::march_count")
def _march_count(
    o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, counts: Tensor, grid: Tensor, step: float,
    occupancy: bool,
) -> Tensor:  # fmt: skip
    kept = torch.empty_like(counts)  # every ray's count is written
    if len(counts):
        cells, res = _grid_args(grid)
        _launch("count_kernel", len(counts), o_n, d_n, near, far, counts, cells, kept, step, res,
                OCC=occupancy)  # fmt: skip
    return kept


@_march_count.register_fake
def _(
    o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, counts: Tensor, grid: Tensor, step: float,
    occupancy: bool,
) -> Tensor:  # fmt: skip
    return torch.empty_like(counts)


@custom_op("spikenerf::march_write")
def _march_write(
    o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, counts: Tensor, grid: Tensor, first: Tensor,
    budget: int, step: float, occupancy: bool,
) -> tuple[Tensor, Tensor]:  # fmt: skip
    ray = counts.new_zeros(budget)
    k = counts.new_zeros(budget)
    if len(counts) and budget:
        cells, res = _grid_args(grid)
        _launch("write_kernel", len(counts), o_n, d_n, near, far, counts, cells, first, ray, k, budget,
                step, res, OCC=occupancy)  # fmt: skip
    return ray, k


@_march_write.register_fake
def _(
    o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, counts: Tensor, grid: Tensor, first: Tensor,
    budget: int, step: float, occupancy: bool,
) -> tuple[Tensor, Tensor]:  # fmt: skip
    return counts.new_empty(budget), counts.new_empty(budget)


def _inputs(o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, counts: Tensor) -> tuple[Tensor, ...]:
    return (o_n.float().contiguous(), d_n.float().contiguous(), near.float().contiguous(),
            far.float().contiguous(), counts.long().contiguous())  # fmt: skip


def kept_counts(
    o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, counts: Tensor, grid: Tensor | None, step: float
) -> Tensor:
    """The kept steps (N,) int64 of each ray (check :func:`~spikenerf.render.volume_triton.applies` first).

    Args:
        o_n, d_n: (N, 3) normalised origins and directions. near, far: (N,). counts: (N,) int64 steps of
            each ray (``GridModel._counts``). grid: (R, R, R) bool occupancy, or None (no occupancy test).
        step: the marching step.
    Returns:
        (N,) int64: the steps k < counts[r] that start before ``far`` and whose midpoint's cell is set.
    """
    args = _inputs(o_n, d_n, near, far, counts)
    cells = grid if grid is not None else counts.new_ones(1, 1, 1, dtype=torch.bool)
    return _march_count(*args, cells.contiguous(), float(step), grid is not None)


def write(
    o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, counts: Tensor, grid: Tensor | None, step: float,
    kept: Tensor, budget: int,
) -> tuple[Tensor, Tensor, Tensor]:  # fmt: skip
    """The kept steps laid out ray after ray in ``budget`` B slots.

    Args:
        as :func:`kept_counts`, and kept: (N,) its result. budget: B.
    Returns:
        ray (B,) int64 and step number k (B,) int64 of slot i for i < min(B, Σ kept) (the later slots 0),
        and () int64: Σ kept.
    """
    args = _inputs(o_n, d_n, near, far, counts)
    cells = grid if grid is not None else counts.new_ones(1, 1, 1, dtype=torch.bool)
    ends = torch.cumsum(kept, dim=0)
    ray, k = _march_write(*args, cells.contiguous(), ends - kept, budget, float(step), grid is not None)
    return ray, k, ends[-1] if len(ends) else kept.new_zeros(())

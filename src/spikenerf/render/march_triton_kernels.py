"""The Triton kernels of ``render/march_triton.py`` (imported by it on first use: it needs ``triton``).

One program per ray walks the ray's ``COUNT[r]`` marching steps in blocks of ``BLOCK`` and tests each as
``GridModel._kept`` does, in the same float32 operations in the same order: the step starts before ``far``
and (with ``OCC``) the occupancy cell of its midpoint is set. ``march_triton`` launches them without
floating-point contraction (no fused multiply-adds), so each operation rounds as torch's separate kernels
do: the same steps are kept on a GPU as on a CPU. :func:`count_kernel` writes the number of
kept steps of each ray; :func:`write_kernel`, given each ray's first slot (the exclusive running sum of
those counts), writes the ray and step number of every kept step into its slot, slots at or past
``budget`` left out. No two programs write the same address (no atomics).
"""

import triton
import triton.language as tl


@triton.jit
def kept_steps(O, D, NEAR, FAR, GRID, r, k, count, step, res, OCC: tl.constexpr):
    # which steps k (BLOCK,) of ray r are kept: k < count, the step starts before far, and (OCC) the cell
    # of the step's midpoint is occupied (cells as OccupancyGrid.cell_index: clamped, truncated)
    near = tl.load(NEAR + r)
    far = tl.load(FAR + r)
    t_start = near + step * k.to(tl.float32)
    kept = (k < count) & (t_start < far)
    if OCC:
        t_mid = t_start + 0.5 * tl.minimum(far - t_start, step)
        half = 0.5 * res.to(tl.float32)
        top = (res - 1).to(tl.float32)
        cell = tl.zeros_like(k)
        for axis in tl.static_range(3):
            x = tl.load(O + r * 3 + axis) + t_mid * tl.load(D + r * 3 + axis)
            i = tl.minimum(tl.maximum((x + 1.0) * half, 0.0), top).to(tl.int64)
            # clamped again as an integer: a NaN point still gets a cell of the grid (no stray read)
            cell = cell * res + tl.minimum(tl.maximum(i, 0), res - 1)
        kept &= tl.load(GRID + cell, mask=kept, other=0) != 0
    return kept


@triton.jit(do_not_specialize=["res"])  # (an int argument of 1 would become a constant without .to)
def count_kernel(O, D, NEAR, FAR, COUNT, GRID, KEPT, step, res, OCC: tl.constexpr, BLOCK: tl.constexpr):
    # KEPT[r] = the kept steps of ray r's COUNT[r]
    r = tl.program_id(0).to(tl.int64)
    count = tl.load(COUNT + r)
    lane = tl.arange(0, BLOCK).to(tl.int64)
    total = tl.full([], 0, tl.int64)
    for s in range(0, count, BLOCK):
        kept = kept_steps(O, D, NEAR, FAR, GRID, r, s + lane, count, step, res, OCC)
        total += tl.sum(kept.to(tl.int64), axis=0)
    tl.store(KEPT + r, total)


@triton.jit(do_not_specialize=["res"])
def write_kernel(
    O, D, NEAR, FAR, COUNT, GRID, FIRST, RAY, K, budget, step, res, OCC: tl.constexpr, BLOCK: tl.constexpr
):
    # the j-th kept step k of ray r goes to slot FIRST[r] + j: RAY[slot] = r, K[slot] = k (slot < budget)
    r = tl.program_id(0).to(tl.int64)
    slot = tl.load(FIRST + r)
    count = tl.where(slot < budget, tl.load(COUNT + r), 0)  # a ray wholly past the budget: nothing to write
    lane = tl.arange(0, BLOCK).to(tl.int64)
    for s in range(0, count, BLOCK):
        k = s + lane
        kept = kept_steps(O, D, NEAR, FAR, GRID, r, k, count, step, res, OCC)
        seen = tl.cumsum(kept.to(tl.int64), axis=0)
        at = slot + seen - 1
        live = kept & (at < budget)
        tl.store(RAY + at, tl.zeros_like(k) + r, mask=live)
        tl.store(K + at, k, mask=live)
        slot += tl.sum(kept.to(tl.int64), axis=0)

"""The Triton kernels of ``render/volume_triton.py`` (imported by it on first use: it needs ``triton``).

One program per ray: ray r's samples are ``OFF[r]:OFF[r + 1]`` of the packed arrays (``render/volume.py:
ray_offsets``), walked in blocks of ``BLOCK`` samples with a running carry, so a ray of any length takes
``ceil(n / BLOCK)`` passes, an empty one none, and no two programs write the same address (no atomics).
Sums are float32 and per ray (the torch path sums every ray's optical depth in one float64 running sum and
subtracts; per ray, float32 keeps the same precision).
"""

import triton
import triton.language as tl


@triton.jit
def clamped(tau, max_tau):
    # τ clamped to ≤ max_tau, NaN → max_tau (as volume.packed_depth_before's running sum sees it)
    return tl.where(tau == tau, tl.minimum(tau, max_tau), max_tau)


@triton.jit
def depth_before_kernel(TAU, OFF, OUT, max_tau, BLOCK: tl.constexpr):
    # OUT[i] = Σ τⱼ over the same ray's earlier samples j < i, each τ clamped to ≤ max_tau (NaN → max_tau)
    r = tl.program_id(0).to(tl.int64)
    start = tl.load(OFF + r)
    end = tl.load(OFF + r + 1)
    lane = tl.arange(0, BLOCK)
    carry = tl.full([], 0.0, tl.float32)
    for s in range(start, end, BLOCK):
        i = s + lane
        live = i < end
        # the block's exclusive scan as an inclusive one of the samples shifted by one (not the inclusive
        # scan minus τ, which loses a small depth next to a large τ)
        before = clamped(tl.load(TAU + i - 1, mask=live & (lane > 0), other=0.0), max_tau)
        tl.store(OUT + i, carry + tl.cumsum(before, axis=0), mask=live)
        carry += tl.sum(clamped(tl.load(TAU + i, mask=live, other=0.0), max_tau), axis=0)


@triton.jit
def depth_before_backward_kernel(TAU, OFF, G, OUT, max_tau, BLOCK: tl.constexpr):
    # OUT[j] = Σ G[i] over the same ray's later samples i > j (the clamp passes no gradient above max_tau,
    # nor for a NaN τ): the ray walked from its end, so the running sum is the suffix sum
    r = tl.program_id(0).to(tl.int64)
    start = tl.load(OFF + r)
    end = tl.load(OFF + r + 1)
    lane = tl.arange(0, BLOCK)
    carry = tl.full([], 0.0, tl.float32)
    for s in range(0, end - start, BLOCK):
        i = end - 1 - s - lane  # descending
        live = i >= start
        after = carry + tl.cumsum(tl.load(G + i + 1, mask=live & (lane > 0), other=0.0), axis=0)
        tau = tl.load(TAU + i, mask=live, other=0.0)
        tl.store(OUT + i, tl.where(tau <= max_tau, after, 0.0), mask=live)
        carry += tl.sum(tl.load(G + i, mask=live, other=0.0), axis=0)


@triton.jit
def segment_sum_kernel(VAL, OFF, OUT, K: tl.constexpr, KP: tl.constexpr, BLOCK: tl.constexpr):
    # OUT[r, :] = Σ VAL[i, :] over ray r's samples (K columns, padded to the power of two KP)
    r = tl.program_id(0).to(tl.int64)
    start = tl.load(OFF + r)
    end = tl.load(OFF + r + 1)
    cols = tl.arange(0, KP)
    acc = tl.zeros([KP], dtype=tl.float32)
    for s in range(start, end, BLOCK):
        i = s + tl.arange(0, BLOCK)
        mask = (i < end)[:, None] & (cols < K)[None, :]
        acc += tl.sum(tl.load(VAL + i[:, None] * K + cols[None, :], mask=mask, other=0.0), axis=0)
    tl.store(OUT + r * K + cols, acc, mask=cols < K)

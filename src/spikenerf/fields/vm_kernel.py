"""A fused CPU kernel for the VM lookup (bilinear planes × linear lines) and its backward, built on first use.

``grid_sample`` on a CPU spends most of a training step in its backward (a strided scatter per channel). This
kernel reads the factors channels-last and does one pass over the points: forward ``P_m(x)·L_m(x)`` for the
three axis pairs; backward the scatter of ``∂/∂P`` and ``∂/∂L`` into channels-last gradients (≈ 11 M
multiply-adds for a 58 k-point, 16-channel batch). No races and no per-thread copy of the plane gradients:
each thread owns a band of plane rows, balanced by a sample of the points' rows, and scatters only there (so
the plane gradients have the same bits on any number of threads); the small line gradients are per-thread
buffers, summed at the end.
For the density (``summed``) it adds the products up itself, so that no (M, 3, C) tensor is written,
summed by torch and, in the backward, expanded back into a contiguous copy. A training render's density
(:func:`vm_sum_until`) is looked up along each ray only up to its early stop: the samples behind it, about
half of them late in training, have density 0 and no gradient either way.
The lookups are random reads of a grid larger than the L2 cache, so each loop prefetches the texels of the
point 8 ahead. Its C++ source is ``vm_cpu.cpp``; ``vm_build.py`` compiles it (cached; 20–90 s the first
time on a machine) and loads it. Where that is not possible (no
compiler, a CUDA tensor, float64, ``SPIKENERF_VM_KERNEL=0``, inside :func:`suspended`) callers fall back
to ``grid_sample``; :func:`available` says which path is used. Points that want a gradient (pose refinement
moves them) get it from the kernel too (``point_backward``: one pass over the points, each its own; before,
such a step fell back to ``grid_sample``: about 3× slower on the real-data demo path, docs/performance.md).
The forward and the backward are ``torch.library`` custom ops, so ``torch.compile(fullgraph=True)`` keeps them
in its graph (``train --compile`` on a CPU; before, the compiled step fell back to ``grid_sample``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import torch
from torch import Tensor

from spikenerf.core.errors import InputError, is_integer
from spikenerf.core.tracing import constant_result, custom_op
from spikenerf.fields.vm_build import load
from spikenerf.fields.vm_ops import channels_last, check_factors, register_pair


def parallel_threads(n: int = 64) -> int:
    """How many threads the kernel's ``at::parallel_for`` uses over ``n`` items (1 without OpenMP).

    Raises:
        RuntimeError: the kernel cannot be built or is disabled.
    """
    module = load()
    if module is None:
        raise RuntimeError("parallel_threads: the fused VM CPU kernel is unavailable")
    return int(module.parallel_threads(n))


@constant_result  # builds or imports on the first call: a constant to a trace
def available() -> bool:
    """Whether the fused CPU kernel can be used in this process (builds it on the first call)."""
    return load() is not None


#: set within :func:`suspended`: :func:`usable` says no (read by ``torch.compile`` as a guarded constant)
_SUSPENDED = False


@contextlib.contextmanager
def suspended() -> Iterator[None]:
    """Within: the kernel is not used (:func:`usable` is False), so callers take the ``grid_sample`` path (to
    compare the two). Outside it, nothing changes."""
    global _SUSPENDED
    before, _SUSPENDED = _SUSPENDED, True
    try:
        yield
    finally:
        _SUSPENDED = before


def usable(planes: Tensor, xyz: Tensor) -> bool:
    """The kernel applies: not :func:`suspended`, CPU float32 tensors, and it builds."""
    return (
        not _SUSPENDED
        and planes.device.type == "cpu"
        and planes.dtype == torch.float32
        and xyz.dtype == torch.float32
        and available()
    )


def _backward(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> tuple[Tensor, Tensor]:
    gp, gl = load().backward(planes, lines, xyz, grad)  # (M,) grad after a summed forward
    return gp, gl


def _point_backward(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> Tensor:
    return load().point_backward(planes, lines, xyz, grad)  # (M, 3)


#: ``spikenerf::vm_cpu_forward`` (``_backward``, ``_point_backward``): the kernel as custom ops, so compiled
#: graphs keep it
_OP = register_pair(
    "vm_cpu", lambda p, ln, x, summed: load().forward(p, ln, x, summed), _backward, _point_backward
)


def vm_lookup(planes: Tensor, lines: Tensor, xyz: Tensor, summed: bool = False) -> Tensor:
    """``P_m(xyz)·L_m(xyz)`` per axis pair with the fused kernel (check :func:`usable` first).

    Args:
        planes: (3, C, R, R). lines: (3, C, R, 1). xyz: (M, 3), normally in [−1, 1]; outside, zeros padding
            as ``grid_sample`` (a NaN coordinate gives NaN).
        summed: return the sum over axis pairs and channels instead, computed in the kernel (the density:
            no (M, 3, C) tensor is written forward or materialised for the backward).
    Returns:
        (M, 3, C), the same values as :func:`spikenerf.fields.vm_sample.sample_vm` transposed; (M,) when
        ``summed``. Its gradient goes to the planes, the lines and, where they want one, the points.
    Raises:
        RuntimeError: the kernel cannot be built or is disabled (:func:`usable` is False). InputError:
            factors or points not of these shapes, or not float32 (:func:`~.vm_ops.check_factors`).
    """
    if load() is None:
        raise RuntimeError("vm_lookup: the fused VM CPU kernel is unavailable (check vm_kernel.usable first)")
    check_factors(planes, lines, xyz)
    return _OP(*channels_last(planes, lines), xyz.contiguous(), summed)


class _Rows(torch.autograd.Function):
    """:func:`vm_rows` on the channels-last views (3, R, R, C) and (3, R, C): the kernel's ``forward_rows``,
    and its ``backward`` reading the bfloat16 gradient."""

    @staticmethod
    def forward(ctx: Any, planes: Tensor, lines: Tensor, xyz: Tensor, rows: int) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(planes, lines, xyz)
        return load().forward_rows(planes, lines, xyz, rows)

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:  # type: ignore[override]
        planes, lines, xyz = ctx.saved_tensors
        m = xyz.shape[0]
        grad = grad[:m].reshape(m, 3, planes.shape[-1]).contiguous()
        gp = gl = gx = None
        if ctx.needs_input_grad[0] or ctx.needs_input_grad[1]:  # (frozen factors, eval's pose fit: none)
            gp, gl = load().backward(planes, lines, xyz, grad)
        if ctx.needs_input_grad[2]:
            gx = load().point_backward(planes, lines, xyz, grad)
        return gp, gl, gx, None


def vm_rows(planes: Tensor, lines: Tensor, xyz: Tensor, rows: int) -> Tensor:
    """:func:`vm_lookup`'s (M, 3, C) products as (rows, 3·C) bfloat16 rows, the first M the products (rounded
    to nearest even, as ``Tensor.to``), the rest zeros: ``row_buckets.pad_rows`` of the lookup, written by
    the kernel itself, whose backward reads the bfloat16 gradient (no float32 copy either way; the grid
    decoder's bf16 input on a CPU). Eager only (``row_buckets.bucketing``); check :func:`usable` first.

    Args:
        planes: (3, C, R, R). lines: (3, C, R, 1). xyz: (M, 3). rows: ≥ M.
    Returns:
        (rows, 3·C) bfloat16; its gradient goes to the planes, lines and points as :func:`vm_lookup`'s.
    Raises:
        RuntimeError: the kernel cannot be built or is disabled (:func:`usable` is False). InputError:
            factors or points as :func:`vm_lookup` refuses them, or ``rows`` not an integer ≥ M.
    """
    if load() is None:
        raise RuntimeError("vm_rows: the fused VM CPU kernel is unavailable (check vm_kernel.usable first)")
    check_factors(planes, lines, xyz)
    if not is_integer(rows) or rows < xyz.shape[0]:  # (the kernel's own check said neither which nor why)
        raise InputError(f"rows must be an integer ≥ the {xyz.shape[0]} points, found {rows!r}", param="rows")
    return _Rows.apply(*channels_last(planes, lines), xyz.contiguous(), rows)


@custom_op("spikenerf::vm_cpu_until")
def _until_op(
    planes: Tensor, lines: Tensor, xyz: Tensor, offsets: Tensor, deltas: Tensor, shift: float, scale: float,
    limit: float,
) -> Tensor:  # fmt: skip
    return load().forward_until(planes, lines, xyz, offsets, deltas, shift, scale, limit)


@_until_op.register_fake
def _(
    planes: Tensor, lines: Tensor, xyz: Tensor, offsets: Tensor, deltas: Tensor, shift: float, scale: float,
    limit: float,
) -> Tensor:  # fmt: skip
    return xyz.new_empty((xyz.shape[0],))


def _until_setup(ctx: Any, inputs: tuple, output: Tensor) -> None:
    ctx.save_for_backward(*inputs[:3])


def _until_grad(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:
    planes, lines, xyz = ctx.saved_tensors  # the summed lookup's backward: a sample left out has gradient 0
    grad = grad.contiguous()
    gp = gl = gx = None
    if ctx.needs_input_grad[0] or ctx.needs_input_grad[1]:  # (frozen factors, eval's pose fit: none)
        gp, gl = torch.ops.spikenerf.vm_cpu_backward(planes, lines, xyz, grad)
    if ctx.needs_input_grad[2]:
        gx = torch.ops.spikenerf.vm_cpu_point_backward(planes, lines, xyz, grad)
    return gp, gl, gx, None, None, None, None, None


_until_op.register_autograd(_until_grad, setup_context=_until_setup)

#: looked up past ``limit`` by this much (relative and absolute): the kernel's bound of the optical depth
#: rounds otherwise than ``render.volume.early_stop_mask``'s depth; with the margin every sample that the
#: mask keeps is looked up
UNTIL_MARGIN = 1e-4


def vm_sum_until(
    planes: Tensor, lines: Tensor, xyz: Tensor, offsets: Tensor, deltas: Tensor, shift: float, scale: float,
    limit: float,
) -> Tensor:  # fmt: skip
    """:func:`vm_lookup` ``summed`` of samples packed ray after ray, each ray's only up to its early stop
    (check :func:`usable` first).

    Args:
        planes: (3, C, R, R). lines: (3, C, R, 1). xyz: (M, 3) the samples, ray after ray and in order along
            each. offsets: (N + 1,) int64, ray i's samples at ``offsets[i]:offsets[i + 1]``
            (``render.volume.ray_offsets``). deltas: (M,) their interval lengths.
        shift, scale: the density ``scale · softplus(raw + shift)`` of a summed value ``raw``
            (``GridField._density_of``). limit: the optical depth ``Σ σ δ`` of a ray's earlier samples past
            which a sample is not looked up (by :data:`UNTIL_MARGIN` more, relative and absolute). The kernel
            adds up a lower bound of each ``σ δ`` (softplus under its tangents: no exp or log1p per sample),
            so it may look up a few samples more than needed, never fewer.
    Returns:
        (M,): the summed products where looked up (the values of :func:`vm_lookup`), −inf after (a density of
        exactly 0, with gradient 0). Its gradient flows to the planes, lines and points as
        :func:`vm_lookup`'s.
    Raises:
        InputError: factors or points as :func:`vm_lookup` refuses them, ``offsets`` not (N + 1,) or
            ``deltas`` not (M,). RuntimeError (the kernel's check, which reads no value back on the Python
            side): ``offsets`` not from 0 to M or decreasing.
    """
    if load() is None:
        raise RuntimeError("vm_sum_until: the fused VM CPU kernel is unavailable (check usable first)")
    check_factors(planes, lines, xyz)
    m = xyz.shape[0]
    if offsets.dim() != 1 or len(offsets) == 0 or deltas.shape != (m,):
        raise InputError(
            f"vm_sum_until: offsets must be (N + 1,) and deltas (M,) of the {m} samples, found "
            f"{tuple(offsets.shape)} and {tuple(deltas.shape)}",
            param=("offsets", "deltas"),
        )
    stop = limit * (1.0 + UNTIL_MARGIN) + UNTIL_MARGIN
    p, ln = channels_last(planes, lines)
    args = (p, ln, xyz.contiguous(), offsets.long().contiguous(), deltas.float().contiguous())
    wants = p.requires_grad or ln.requires_grad or xyz.requires_grad
    if torch.compiler.is_compiling() or (torch.is_grad_enabled() and wants):
        return _until_op(*args, float(shift), float(scale), float(stop))
    return load().forward_until(*args, float(shift), float(scale), float(stop))  # no gradient: no dispatch

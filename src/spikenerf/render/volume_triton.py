"""Fused per-ray compositing as Triton kernels, for CUDA (opt-in: ``GridFieldConfig.composite = "triton"``).

The torch path of ``render/volume.py`` makes a ray's transmittance from one float64 running sum over every
packed sample (a cast, a scan, two gathers and a subtraction, each a kernel, and as many again in the
backward) and its colour, depth and opacity with scatters (``index_add``) that add each sample into its
ray's row (on a GPU, atomics on the same address for all of a ray's samples). Here one program walks one
ray's samples (``volume_triton_kernels.py``):

- :func:`depth_before`: the optical depth of the ray's earlier samples (an exclusive scan), whose backward
  is the suffix sum of the gradient (the ray walked from its end);
- :func:`segment_sum`: each ray's sum of its rows (no atomics), whose backward is a gather.

Both are ``torch.library`` custom ops with fake implementations and autograd formulas, so
``torch.compile(fullgraph=True)`` keeps them in its graph as opaque calls. Where Triton runs (``triton``
importable and a CUDA tensor, or ``TRITON_INTERPRET=1`` with CPU tensors, which the tests use) is
:func:`applies`. Not timed on a GPU yet (docs/performance.md).
"""

from __future__ import annotations

import contextlib
from typing import Any

import torch
from torch import Tensor

from spikenerf.core.tracing import custom_op
from spikenerf.fields.vm_triton import installed, interpreted

#: samples a program reads at a time, and warps a program: a guess, not tuned on a GPU yet
LAUNCH: dict[str, int] = {"BLOCK": 64, "num_warps": 2}


def applies(tensor: Tensor) -> bool:
    """The kernels can run on ``tensor``: a float32 tensor on CUDA (on the CPU under the interpreter) and
    Triton installed."""
    on = tensor.device.type == "cuda" or (tensor.device.type == "cpu" and interpreted())
    return on and tensor.dtype == torch.float32 and installed()


def _launch(name: str, rays: int, *args: Any, **constexprs: int) -> None:
    """Run kernel ``name`` of ``volume_triton_kernels`` with one program per ray."""
    from spikenerf.render import volume_triton_kernels as kernels

    device = args[0].device
    on = torch.cuda.device(device) if device.type == "cuda" else contextlib.nullcontext()
    with on:  # Triton launches on the current device, not the tensors'
        getattr(kernels, name)[(rays,)](*args, **constexprs, **LAUNCH)


@custom_op("spikenerf::depth_before")
def _depth_before(tau: Tensor, offsets: Tensor, max_tau: float) -> Tensor:
    out = torch.zeros_like(tau)
    if len(offsets) > 1 and len(tau):
        _launch("depth_before_kernel", len(offsets) - 1, tau, offsets, out, max_tau)
    return out


@_depth_before.register_fake
def _(tau: Tensor, offsets: Tensor, max_tau: float) -> Tensor:
    return torch.empty_like(tau)


@custom_op("spikenerf::depth_before_backward")
def _depth_before_backward(tau: Tensor, offsets: Tensor, grad: Tensor, max_tau: float) -> Tensor:
    out = torch.zeros_like(tau)
    if len(offsets) > 1 and len(tau):
        _launch("depth_before_backward_kernel", len(offsets) - 1, tau, offsets, grad, out, max_tau)
    return out


@_depth_before_backward.register_fake
def _(tau: Tensor, offsets: Tensor, grad: Tensor, max_tau: float) -> Tensor:
    return torch.empty_like(tau)


def _depth_before_context(ctx: Any, inputs: tuple, output: Tensor) -> None:
    tau, offsets, max_tau = inputs
    ctx.save_for_backward(tau, offsets)
    ctx.max_tau = max_tau


def _depth_before_grad(ctx: Any, grad: Tensor) -> tuple[Tensor, None, None]:
    tau, offsets = ctx.saved_tensors
    return _depth_before_backward(tau, offsets, grad.contiguous(), ctx.max_tau), None, None


_depth_before.register_autograd(_depth_before_grad, setup_context=_depth_before_context)


@custom_op("spikenerf::segment_sum")
def _segment_sum(values: Tensor, ray: Tensor, offsets: Tensor) -> Tensor:
    rays, k = len(offsets) - 1, values.shape[1]
    out = values.new_zeros(rays, k)
    if rays and len(values) and k:
        _launch("segment_sum_kernel", rays, values, offsets, out, K=k, KP=_pow2(k))
    return out


@_segment_sum.register_fake
def _(values: Tensor, ray: Tensor, offsets: Tensor) -> Tensor:
    return values.new_empty(offsets.shape[0] - 1, values.shape[1])


def _segment_sum_context(ctx: Any, inputs: tuple, output: Tensor) -> None:
    ctx.save_for_backward(inputs[1])


def _segment_sum_grad(ctx: Any, grad: Tensor) -> tuple[Tensor, None, None]:
    (ray,) = ctx.saved_tensors
    return grad.index_select(0, ray), None, None


_segment_sum.register_autograd(_segment_sum_grad, setup_context=_segment_sum_context)


def _pow2(k: int) -> int:
    return 1 << max(0, k - 1).bit_length()


def depth_before(tau: Tensor, offsets: Tensor, max_tau: float) -> Tensor:
    """``volume.packed_depth_before`` with the kernels (check :func:`applies` first).

    Args:
        tau: (M,) optical depth of packed samples (summed in float32). offsets: (N + 1,) int64
            ``volume.ray_offsets``.
        max_tau: the clamp of each τ in the sum (NaN counts as it); above it no gradient flows.
    Returns:
        (M,) float32 ``Σ_{j<i} τⱼ`` over the same ray's earlier samples; differentiable in ``tau``.
    """
    return _depth_before(tau.float().contiguous(), offsets.contiguous(), float(max_tau))


def segment_sum(values: Tensor, ray: Tensor, offsets: Tensor) -> Tensor:
    """``volume.segment_sum`` with the kernels (check :func:`applies` first).

    Args:
        values: (M,) or (M, K). ray: (M,) non-decreasing ray of each row. offsets: (N + 1,).
    Returns:
        (N,) or (N, K) float32 per-ray sums, 0 for a ray without rows; differentiable in ``values``.
    """
    flat = values.dim() == 1
    rows = values[:, None] if flat else values
    out = _segment_sum(rows.float().contiguous(), ray.contiguous(), offsets.contiguous())
    return out[:, 0] if flat else out

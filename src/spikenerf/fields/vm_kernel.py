"""A fused CPU kernel for the VM lookup (bilinear planes × linear lines) and its backward, built on first use.

``grid_sample`` on a CPU spends most of a training step in its backward (a strided scatter per channel). This
kernel reads the factors channels-last and does one pass over the points: forward ``P_m(x)·L_m(x)`` for the
three axis pairs; backward the scatter of ``∂/∂P`` and ``∂/∂L`` into channels-last gradients (≈ 11 M
multiply-adds for a 58 k-point, 16-channel batch). No races and no per-thread copy of the plane gradients:
each thread owns a band of plane rows, balanced by a sample of the points' rows, and scatters only there (so
the plane gradients have the same bits on any number of threads); the small line gradients are per-thread
buffers, summed at the end.
For the density (``summed``) it adds the products up itself, so that no (M, 3, C) tensor is written,
summed by torch and, in the backward, expanded back into a contiguous copy.
The lookups are random reads of a grid larger than the L2 cache, so each loop prefetches the texels of the
point 8 ahead. Its C++ source is ``vm_cpu_source.py``; ``vm_build.py`` compiles it (cached; 20–90 s the first
time on a machine) and loads it. Where that is not possible (no
compiler, a CUDA tensor, float64, gradients wanted for the points, ``SPIKENERF_VM_KERNEL=0``, inside
:func:`suspended`) callers fall back to ``grid_sample``; :func:`available` says which path is used.
The forward and the backward are ``torch.library`` custom ops, so ``torch.compile(fullgraph=True)`` keeps them
in its graph (``train --compile`` on a CPU; before, the compiled step fell back to ``grid_sample``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from torch import Tensor

from spikenerf.core.tracing import constant_result
from spikenerf.fields.vm_build import load
from spikenerf.fields.vm_ops import channels_last, register_pair


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
    """The kernel applies: not :func:`suspended`, CPU float32 tensors, no gradient wanted for the points, and
    it builds."""
    return (
        not _SUSPENDED
        and planes.device.type == "cpu"
        and planes.dtype == torch.float32
        and xyz.dtype == torch.float32
        and not xyz.requires_grad
        and available()
    )


def _backward(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> tuple[Tensor, Tensor]:
    gp, gl = load().backward(planes, lines, xyz, grad)  # (M,) grad after a summed forward
    return gp, gl


#: ``spikenerf::vm_cpu_forward`` (and ``_backward``): the kernel as custom ops, so compiled graphs keep it
_OP = register_pair("vm_cpu", lambda p, ln, x, summed: load().forward(p, ln, x, summed), _backward)


def vm_lookup(planes: Tensor, lines: Tensor, xyz: Tensor, summed: bool = False) -> Tensor:
    """``P_m(xyz)·L_m(xyz)`` per axis pair with the fused kernel (check :func:`usable` first).

    Args:
        planes: (3, C, R, R). lines: (3, C, R, 1). xyz: (M, 3), normally in [−1, 1]; outside, zeros padding
            as ``grid_sample`` (a NaN coordinate gives NaN).
        summed: return the sum over axis pairs and channels instead, computed in the kernel (the density:
            no (M, 3, C) tensor is written forward or materialised for the backward).
    Returns:
        (M, 3, C), the same values as :func:`spikenerf.fields.vm_sample.sample_vm` transposed; (M,) when
        ``summed``.
    Raises:
        RuntimeError: the kernel cannot be built or is disabled (:func:`usable` is False).
    """
    if load() is None:
        raise RuntimeError("vm_lookup: the fused VM CPU kernel is unavailable (check vm_kernel.usable first)")
    return _OP(*channels_last(planes, lines), xyz.contiguous(), summed)

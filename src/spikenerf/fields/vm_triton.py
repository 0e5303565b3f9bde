"""The VM lookup and its backward as Triton kernels, for CUDA (opt-in: ``GridFieldConfig.lookup = "triton"``).

On a GPU ``grid_sample``'s backward was the largest part of the compiled training step (5.0 of 8.75 ms on an
H200 at 16384 rays, docs/performance.md): it adds each point's gradient into the factors one channel at a
time, at addresses a plane apart. These kernels do what the fused CPU kernel (``fields/vm_kernel.py``) does,
one block of points per program: read the channels-last factors (memory order 3, R, R, C) a whole channel
row at a time, form ``P_m(x)·L_m(x)`` for the three axis pairs (summed over pairs and channels in the kernel
for the density, so no (M, 3, C) tensor is written), and in the backward add each point's row of gradients
into the four plane texels and two line texels with atomic adds (one buffer, no per-thread copies). Points
whose (summed) gradient is 0, such as those behind a ray's early stop, add nothing.

The kernels are ``torch.library`` custom ops with a fake implementation and an autograd formula, so
``torch.compile(fullgraph=True)`` keeps them in one graph as opaque calls. Points that want a gradient (pose
refinement moves them) get it from a third kernel, one block of points a program, no atomics (its launch
shape is the backward's, not tuned on a GPU). Where Triton runs (``triton`` importable and a CUDA tensor, or
``TRITON_INTERPRET=1`` with CPU tensors, which the tests use) is :func:`applies`. On an H200 a forward and
backward is 5–7× ``grid_sample``'s (docs/performance.md, "Factor lookups for the GPU").
"""

from __future__ import annotations

import contextlib
import importlib.util
import os

import torch
from torch import Tensor

from spikenerf.core.tracing import constant_result
from spikenerf.fields.vm_ops import channels_last, check_factors, register_pair

#: kernel → (points a program, warps a program): the fastest forward + backward of four shapes on an H200
#: (2²⁰ points, R 300, C 16 and 24; ``benchmarks/tools/bench_lookup.py --triton-launch``,
#: docs/performance.md); the points' gradient ("point") takes the backward's, untimed
LAUNCH: dict[str, tuple[int, int]] = {"forward": (32, 4), "backward": (32, 4), "point": (32, 4)}


@constant_result  # a host query: fixed per process, traced as a constant
def installed() -> bool:
    """Whether the ``triton`` package can be imported (it comes with CUDA builds of torch)."""
    return importlib.util.find_spec("triton") is not None


def interpreted() -> bool:
    """Whether Triton runs kernels in its CPU interpreter (``TRITON_INTERPRET=1``; Triton itself reads it as
    it is imported, so it must be set before anything imports triton: ``tests/conftest.py``)."""
    return os.environ.get("TRITON_INTERPRET", "0") == "1"


def applies(planes: Tensor, xyz: Tensor) -> bool:
    """The kernels can run here: Triton installed, float32 factors and points on CUDA (on the CPU under the
    interpreter)."""
    on = planes.device.type == "cuda" or (planes.device.type == "cpu" and interpreted())
    return on and planes.dtype == torch.float32 and xyz.dtype == torch.float32 and installed()


def why_not(device: torch.device) -> str:
    """The reason, in a few words, why the kernels cannot run on ``device`` ("" where they can)."""
    if not installed():
        return "the triton package is not installed (pip install triton; CUDA builds of torch include it)"
    if device.type != "cuda" and not (device.type == "cpu" and interpreted()):
        return f"Triton kernels need a CUDA device, not {device.type}"
    return ""


def _launch(kernel_name: str, planes: Tensor, *args: Tensor, summed: bool) -> None:
    """Run one of the kernels over the points (``args[1]``, (M, 3)) as :data:`LAUNCH` says; imports triton
    and the kernels module (which Triton compiles, or interprets, on first use)."""
    import triton

    from spikenerf.fields.vm_triton_kernels import backward_kernel, forward_kernel, point_kernel

    m, c = args[1].shape[0], planes.shape[-1]
    kernel = {"forward": forward_kernel, "backward": backward_kernel, "point": point_kernel}[kernel_name]
    block, warps = LAUNCH[kernel_name]
    on = torch.cuda.device(planes.device) if planes.is_cuda else contextlib.nullcontext()
    with on:  # Triton launches on the current device, not the tensors'
        shape = {"BLOCK": block, "CP": triton.next_power_of_2(c), "num_warps": warps}
        kernel[(triton.cdiv(m, block),)](
            planes, *args, m, planes.shape[1], channels=c, SUMMED=summed, **shape
        )


def _forward(planes: Tensor, lines: Tensor, xyz: Tensor, summed: bool) -> Tensor:
    m, c = xyz.shape[0], planes.shape[-1]
    out = xyz.new_empty((m,) if summed else (m, 3, c))
    if m:
        _launch("forward", planes, lines, xyz, out, summed=summed)
    return out


def _backward(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> tuple[Tensor, Tensor]:
    gp, gl = torch.zeros_like(planes), torch.zeros_like(lines)
    if xyz.shape[0]:
        _launch("backward", planes, lines, xyz, grad, gp, gl, summed=grad.dim() == 1)
    return gp, gl


def _point_backward(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> Tensor:
    gx = torch.empty_like(xyz)
    if xyz.shape[0]:
        _launch("point", planes, lines, xyz, grad, gx, summed=grad.dim() == 1)
    return gx


#: ``spikenerf::vm_triton_forward`` (``_backward``, ``_point_backward``): the kernels as custom ops, opaque
#: to torch.compile
_OP = register_pair("vm_triton", _forward, _backward, _point_backward)


def triton_vm(planes: Tensor, lines: Tensor, xyz: Tensor, summed: bool = False) -> Tensor:
    """``P_m(xyz)·L_m(xyz)`` per axis pair with the Triton kernels (check :func:`applies` first).

    Args:
        planes: (3, C, R, R), best stored channels-last (then no copy is made). lines: (3, C, R, 1).
        xyz: (M, 3), normally in [−1, 1]; outside, zeros padding as ``grid_sample`` (NaN gives NaN).
        summed: return the sum over axis pairs and channels instead (the density), computed in the kernel.
    Returns:
        (M, 3, C), the values of :func:`spikenerf.fields.vm_sample.sample_vm` transposed; (M,) when
        ``summed``. Gradients flow to ``planes``, ``lines`` and, where it wants one, ``xyz``.
    Raises:
        RuntimeError: Triton cannot run here (:func:`applies` is False), naming why. InputError: factors or
            points not of these shapes, or not float32 (:func:`~.vm_ops.check_factors`).
    """
    check_factors(planes, lines, xyz)
    if not applies(planes, xyz):
        reason = why_not(planes.device) or "float32 factors and points are needed"
        raise RuntimeError(f"triton_vm: {reason}")
    return _OP(*channels_last(planes, lines), xyz.contiguous(), summed)

"""A VM lookup kernel pair as ``torch.library`` custom ops: one registration for the fused CPU kernel
(``vm_kernel.py``) and the Triton kernels (``vm_triton.py``).

Each pair is a forward op and a backward op over channels-last factors, with fake implementations (shapes
only) and an autograd formula, so that ``torch.compile(fullgraph=True)`` keeps them in its graph as opaque
calls (a bare C++ or Triton launch would break the graph). A pair registered with a point backward (both
kernels' are) also gives the points their gradient (pose refinement moves them); one without refuses points
that want one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from spikenerf.core.errors import InputError
from spikenerf.core.tracing import custom_op

#: forward(planes (3, R, R, C), lines (3, R, C), xyz (M, 3), summed) → (M, 3, C), or (M,) when summed
Forward = Callable[[Tensor, Tensor, Tensor, bool], Tensor]
#: backward(planes, lines, xyz, grad (M, 3, C) or (M,)) → (∂/∂planes (3, R, R, C), ∂/∂lines (3, R, C))
Backward = Callable[[Tensor, Tensor, Tensor, Tensor], tuple[Tensor, Tensor]]
#: point_backward(planes, lines, xyz, grad (M, 3, C) or (M,)) → ∂/∂xyz (M, 3)
PointBackward = Callable[[Tensor, Tensor, Tensor, Tensor], Tensor]


def check_factors(planes: Tensor, lines: Tensor, xyz: Tensor) -> None:
    """InputError naming the first bad argument unless planes are (3, C, R, R), lines (3, C, R, 1) of the
    same C and R, points (M, 3), all float32: the kernels read them with these sizes and do not check them
    (a (M, 2) ``xyz`` or a line of another length was read past its end). Sizes only: no sync."""
    if planes.dim() != 4 or planes.shape[0] != 3 or planes.shape[2] != planes.shape[3]:
        raise InputError(f"planes must be (3, C, R, R), found {tuple(planes.shape)}", param="planes")
    want = (3, planes.shape[1], planes.shape[2], 1)
    if tuple(lines.shape) != want:
        raise InputError(f"lines must be (3, C, R, 1) = {want}, found {tuple(lines.shape)}", param="lines")
    if xyz.dim() != 2 or xyz.shape[1] != 3:
        raise InputError(f"xyz must be (M, 3) points, found {tuple(xyz.shape)}", param="xyz")
    for name, x in (("planes", planes), ("lines", lines), ("xyz", xyz)):
        if x.dtype != torch.float32:
            raise InputError(f"{name} must be float32 for the fused kernels, found {x.dtype}", param=name)


def channels_last(planes: Tensor, lines: Tensor) -> tuple[Tensor, Tensor]:
    """Planes (3, C, R, R) and lines (3, C, R, 1) → (3, R, R, C) and (3, R, C): views of channels-last
    factors (no copy), copies otherwise; gradients flow back through them."""
    return planes.permute(0, 2, 3, 1).contiguous(), lines[..., 0].permute(0, 2, 1).contiguous()


def register_pair(
    name: str, forward: Forward, backward: Backward, point_backward: PointBackward | None = None
) -> Any:
    """Register ``spikenerf::{name}_forward`` and ``spikenerf::{name}_backward`` calling ``forward`` and
    ``backward`` (which must return new tensors), and ``spikenerf::{name}_point_backward`` where
    ``point_backward`` is given; returns a function of the forward's arguments that calls the forward op
    (``.default`` overload; its gradient goes to the planes and lines, and to the points where they want one
    and ``point_backward`` is given) when a trace or a gradient needs it, and ``forward`` itself otherwise
    (renders without gradient: no dispatch, and no import of Dynamo, which a custom op's first call costs,
    2–3 s).

    Raises (from the returned function): InputError, points that want a gradient without ``point_backward``.
    """

    @custom_op(f"spikenerf::{name}_forward")
    def forward_op(planes: Tensor, lines: Tensor, xyz: Tensor, summed: bool) -> Tensor:
        return forward(planes, lines, xyz, summed)

    @forward_op.register_fake
    def _(planes: Tensor, lines: Tensor, xyz: Tensor, summed: bool) -> Tensor:
        m, c = xyz.shape[0], planes.shape[-1]
        return xyz.new_empty((m,) if summed else (m, 3, c))

    @custom_op(f"spikenerf::{name}_backward")
    def backward_op(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> tuple[Tensor, Tensor]:
        return backward(planes, lines, xyz, grad)

    @backward_op.register_fake
    def _(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> tuple[Tensor, Tensor]:
        return torch.empty_like(planes), torch.empty_like(lines)

    point_op = None
    if point_backward is not None:

        @custom_op(f"spikenerf::{name}_point_backward")
        def point_op(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> Tensor:
            return point_backward(planes, lines, xyz, grad)

        @point_op.register_fake
        def _(planes: Tensor, lines: Tensor, xyz: Tensor, grad: Tensor) -> Tensor:
            return torch.empty_like(xyz)

    def setup_context(ctx: Any, inputs: tuple, output: Tensor) -> None:
        planes, lines, xyz, _ = inputs
        ctx.save_for_backward(planes, lines, xyz)

    def grad_of(ctx: Any, grad: Tensor) -> tuple[Tensor | None, Tensor | None, Tensor | None, None]:
        planes, lines, xyz = ctx.saved_tensors
        grad = grad.contiguous()
        gp = gl = gx = None
        if ctx.needs_input_grad[0] or ctx.needs_input_grad[1]:  # (frozen factors, eval's pose fit: none)
            gp, gl = backward_op(planes, lines, xyz, grad)
        if point_op is not None and ctx.needs_input_grad[2]:
            gx = point_op(planes, lines, xyz, grad)
        return gp, gl, gx, None

    forward_op.register_autograd(grad_of, setup_context=setup_context)
    op = getattr(torch.ops.spikenerf, f"{name}_forward").default

    def call(planes: Tensor, lines: Tensor, xyz: Tensor, summed: bool) -> Tensor:
        points = torch.is_grad_enabled() and xyz.requires_grad
        if points and point_op is None:  # (its gradient would be None: silently wrong)
            raise InputError(f"{name}: no gradient for the points xyz; use grid_sample", param="xyz")
        if torch.compiler.is_compiling() or (
            torch.is_grad_enabled() and (planes.requires_grad or lines.requires_grad or points)
        ):
            return op(planes, lines, xyz, summed)
        return forward(planes, lines, xyz, summed)  # no graph, no gradient: the kernel without the dispatch

    return call

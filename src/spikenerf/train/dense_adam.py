"""Adam whose fused CPU kernel sees every parameter in row-major order: the grid's channels-last factors
without a copy.

torch's fused Adam on a CPU copies a parameter that is not row-major contiguous (the grid's factors are
stored channels-last for the fused VM kernel, ``fields/grid.py: _factor``), its gradient and its moments to
row-major buffers and back at every step: a 3 × 24 × 200 × 200 factor took 7.1 ms a step against 1.9 ms
for the same tensor row-major (one thread). Adam is elementwise, so :class:`DenseAdam` runs the step on
views of the same memory whose dimensions are permuted into row-major order, then puts the views back:
the same values, no copy. A parameter whose gradient or state has other strides is left as it is.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor


def dense_order(t: Tensor) -> list[int] | None:
    """The permutation of ``t``'s dimensions that views it row-major contiguous, for a dense tensor that is
    not row-major already (e.g. channels-last); None otherwise."""
    if t.is_contiguous() or t.dim() < 2:
        return None
    order = sorted(range(t.dim()), key=lambda d: (-t.stride(d), d))
    return order if t.permute(order).is_contiguous() else None


def inverse(order: list[int]) -> list[int]:
    """The permutation that undoes ``order``."""
    back = [0] * len(order)
    for i, d in enumerate(order):
        back[d] = i
    return back


class DenseAdam(torch.optim.Adam):
    """:class:`torch.optim.Adam` that steps each dense non-row-major parameter (with its gradient and
    moments) through row-major views of the same memory (see the module doc); otherwise the same optimiser,
    state dict included."""

    def _permute_all(self, p: Tensor, order: list[int]) -> None:
        """Permute ``p``, its gradient and its per-parameter state tensors of ``p``'s shape by ``order``."""
        shape = p.shape
        grad = p.grad
        p.data = p.data.permute(order)
        if grad is not None:
            p.grad = grad.permute(order)
        state = self.state.get(p, {})
        for key, value in state.items():
            if torch.is_tensor(value) and value.shape == shape:
                state[key] = value.permute(order)

    def _swappable(self, p: Tensor) -> list[int] | None:
        """The permutation that views ``p`` row-major, where it views its gradient and state row-major too
        (strides of size-1 dimensions may differ: autograd keeps a line factor's gradient as it comes)."""
        order = dense_order(p)
        if order is None:
            return None
        others = [p.grad] if p.grad is not None else []
        others += [v for v in self.state.get(p, {}).values() if torch.is_tensor(v) and v.shape == p.shape]
        return order if all(t.permute(order).is_contiguous() for t in others) else None

    def step(self, closure: Callable[[], Any] | None = None) -> Any:  # type: ignore[override]
        # (hooks registered on this optimiser would run twice, once on the permuted views, where torch has
        # hooked Adam.step too; none are registered)
        swapped = []
        for group in self.param_groups:
            for p in group["params"]:
                order = self._swappable(p)
                if order is not None:
                    self._permute_all(p, order)
                    swapped.append((p, order))
        try:
            return super().step(closure)
        finally:  # the state Adam created in this step has the row-major view's shape: permuted back too
            for p, order in swapped:
                self._permute_all(p, inverse(order))

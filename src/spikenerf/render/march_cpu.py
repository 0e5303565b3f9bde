"""The grid renderer's packed march on a CPU as one C++ loop, built with the fused VM kernel (vm_build.py).

The torch march (``GridModel._march``) lays out every candidate step of every ray (a ``repeat_interleave``
of the step counts), gathers each step's ray origin, direction, near and far, tests it against the ray's end
and the occupancy grid, and compacts the kept ones: a dozen passes over arrays several times the size of
the result (late in training about 2.5 candidates a kept step). The kernel (``march`` in
``fields/vm_cpu.cpp``) walks each ray's steps and tests each where it is made, in the same float32
operations in the same order (built without contraction), so it keeps the same steps in the same order
(``tests/test_cpu_render_kernels.py``); only the result is stored. Where the kernel is not built
(``SPIKENERF_VM_KERNEL=0``, no compiler), off the CPU, for other dtypes or inside a ``torch.compile`` trace
the torch march runs.
"""

from __future__ import annotations

import torch
from torch import Tensor

from spikenerf.fields.vm_build import load
from spikenerf.fields.vm_kernel import available


def applies(o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor) -> bool:
    """Whether :func:`march` runs for normalised origins and directions ``o_n``, ``d_n`` (N, 3) and ``near``,
    ``far`` (N,): CPU float32 tensors, all four (the torch march tests a float64 one in float64), eager,
    and the fused kernel built."""
    return (
        all(x.device.type == "cpu" and x.dtype == torch.float32 for x in (o_n, d_n, near, far))
        and not torch.compiler.is_compiling()
        and available()
    )


@torch.no_grad()
def march(
    o_n: Tensor, d_n: Tensor, near: Tensor, far: Tensor, counts: Tensor, grid: Tensor | None, step: float
) -> tuple[Tensor, Tensor]:
    """``GridModel._march``'s kept steps (check :func:`applies` first).

    Args:
        o_n, d_n: (N, 3) normalised origins and directions. near, far: (N,) float32. counts: (N,) int64
            steps of each ray (``GridModel._counts``). grid: (G, G, G) bool occupancy, or None (no
            occupancy test). step: the marching step.
    Returns:
        ray (M,) and step number k (M,) int64 of the kept steps, ray after ray and in order within a ray:
        the steps k < counts[r] that start before ``far`` and whose midpoint's cell is set.
    """
    cells = grid if grid is not None else torch.ones(1, 1, 1, dtype=torch.bool)
    ray, k = load().march(
        o_n.float().contiguous(), d_n.float().contiguous(), near.float().contiguous(),
        far.float().contiguous(), counts.long().contiguous(), cells.contiguous(), float(step),
        grid is not None,
    )  # fmt: skip
    return ray, k

"""The grid's factor lookup through ``grid_sample``: the reference path (:func:`sample_vm`) that the fused CPU
kernel (``vm_kernel.py``), the index gathers (``vm_gather.py``) and the Triton kernels (``vm_triton.py``)
equal, taken where none of them applies, and :func:`vm_splits`, its point chunks per plane on a CPU.

Conventions are ``grid.py``'s: planes (3, C, R, R) and lines (3, C, R, 1) over coordinates normalised to
[−1, 1], ``align_corners=True``.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from spikenerf.core.tracing import constant_result
from spikenerf.fields.vm_gather import MAT, VEC


@constant_result  # a host query: fixed per device, traced as a constant
def vm_splits(device: torch.device) -> int:
    """Point chunks per plane so that the CPU kernel's batch threads balance (1 off the CPU).

    The CPU ``grid_sample`` threads only over the batch; three planes on an even thread count leave a thread
    idle, so each plane is repeated ``k`` times (3k divisible by the thread count, k ≤ 4).
    """
    if device.type != "cpu":
        return 1
    threads = torch.get_num_threads()
    return max(1, min(4, threads // math.gcd(3, threads)))


def sample_vm(planes: Tensor, lines: Tensor, xyz: Tensor, splits: int = 1) -> Tensor:
    """Per-axis-pair VM products at normalised points, with two batched 2-D ``grid_sample`` calls.

    Args:
        planes: (3, C, R, R). lines: (3, C, R, 1). xyz: (M, 3) in [−1, 1].
        splits: point chunks per plane along the batch (see :func:`vm_splits`); the result is the same.
    Returns:
        (3, C, M) ``P_m(xyz) · L_m(xyz)``.
    """
    m, c = xyz.shape[0], planes.shape[1]
    k = splits if splits > 1 and m >= 4096 * splits else 1  # splits 1 (CUDA): no guard on m under compile
    pad = (-m) % k
    if pad:
        xyz = torch.cat([xyz, xyz.new_zeros(pad, 3)])
    mat = torch.tensor(MAT, device=xyz.device)
    plane_grid = xyz[:, mat].transpose(0, 1).reshape(3 * k, 1, -1, 2)
    line_coord = xyz[:, list(VEC)].T
    line_grid = torch.stack([torch.zeros_like(line_coord), line_coord], dim=-1).reshape(3 * k, 1, -1, 2)
    if k > 1:
        planes = planes[:, None].expand(3, k, *planes.shape[1:]).reshape(3 * k, *planes.shape[1:])
        lines = lines[:, None].expand(3, k, *lines.shape[1:]).reshape(3 * k, *lines.shape[1:])
    p = F.grid_sample(planes, plane_grid, mode="bilinear", align_corners=True)
    l = F.grid_sample(lines, line_grid, mode="bilinear", align_corners=True)
    out = (p * l).view(3, k, c, -1)
    out = out[:, 0] if k == 1 else out.transpose(1, 2).reshape(3, c, -1)
    return out[..., :m] if pad else out

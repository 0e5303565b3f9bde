"""VM products by index gathers: ``grid_sample``'s values from plain indexing, for compiled GPU steps.

``F.grid_sample`` is one opaque op to ``torch.compile``: its backward runs torch's own kernel, which adds each
point's gradient into the factors one channel at a time, at scattered addresses (on an H200 that kernel was
5.0 of the compiled step's 8.75 ms at 16384 rays, ``docs/performance.md``). Written as gathers of whole
channel rows of the channels-last factors (memory order 3, R, R, C) times bilinear weights, the lookup and
its backward (an indexed accumulation of rows) are ordinary ops that the compiler can fuse with their
neighbours. Opt-in (``GridFieldConfig.lookup = "gather"``): its GPU speed is not measured yet.

Conventions are :func:`~spikenerf.fields.vm_sample.sample_vm`'s: ``align_corners=True`` (−1 and 1 are the
first and last texel centres), zeros outside the grid, planes indexed by ``(coord[MAT[m][0]] ↔ w,
coord[MAT[m][1]] ↔ h)`` and lines by ``coord[VEC[m]] ↔ h``.
"""

from __future__ import annotations

import torch
from torch import Tensor

#: the coordinate axes of each plane (w, h) and of each line (``fields/grid.py`` and the CPU kernel use them)
MAT = ((0, 1), (0, 2), (1, 2))
VEC = (2, 1, 0)


def corners(coord: Tensor, size: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The two texels either side of ``coord`` (...) in [−1, 1] over ``size`` texels (``align_corners=True``):
    lower and upper indices (...) int64, clamped into the grid, and their linear weights (...), 0 for a texel
    outside it (zeros padding). The weights carry the gradient with respect to ``coord``."""
    pos = (coord + 1.0) * (0.5 * (size - 1))
    low = torch.floor(pos).detach()
    frac = pos - low
    lo = low.long()
    hi = lo + 1
    w_lo = (1.0 - frac) * ((lo >= 0) & (lo < size))
    w_hi = frac * ((hi >= 0) & (hi < size))
    return lo.clamp(0, size - 1), hi.clamp(0, size - 1), w_lo, w_hi


def gather_vm(planes: Tensor, lines: Tensor, xyz: Tensor) -> Tensor:
    """Per-axis-pair VM products at normalised points by index gathers.

    Args:
        planes: (3, C, R, R). lines: (3, C, R, 1). xyz: (M, 3) in [−1, 1] (outside: zeros padding).
    Returns:
        (M, 3, C) ``P_m(xyz) · L_m(xyz)``: ``sample_vm(planes, lines, xyz).permute(2, 0, 1)``.
    """
    c, r = planes.shape[1], planes.shape[-1]
    plane_rows = planes.permute(0, 2, 3, 1).reshape(-1, c)  # (3·R·R, C): a view of channels-last factors
    line_rows = lines.permute(0, 2, 3, 1).reshape(-1, c)  # (3·R, C)
    coords = xyz[:, torch.tensor(MAT, device=xyz.device)]  # (M, 3, 2): (w, h) coordinates of each plane
    x0, x1, wx0, wx1 = corners(coords[..., 0], r)
    y0, y1, wy0, wy1 = corners(coords[..., 1], r)
    start = torch.arange(3, device=xyz.device) * r  # each plane's first row, in rows of R texels
    row0, row1 = (start + y0) * r, (start + y1) * r
    plane = (
        plane_rows[row0 + x0] * (wy0 * wx0)[..., None]
        + plane_rows[row0 + x1] * (wy0 * wx1)[..., None]
        + plane_rows[row1 + x0] * (wy1 * wx0)[..., None]
        + plane_rows[row1 + x1] * (wy1 * wx1)[..., None]
    )
    length = lines.shape[2]
    z0, z1, wz0, wz1 = corners(xyz[:, list(VEC)], length)
    first = torch.arange(3, device=xyz.device) * length  # each line's first row
    line = line_rows[first + z0] * wz0[..., None] + line_rows[first + z1] * wz1[..., None]
    return plane * line

"""VM sums on a regular lattice of points by separable interpolation: the occupancy grid's density pass.

An occupancy update evaluates the density at the centre of every one of G³ cells (G = 128 by default: 2.1 M
points). Looked up point by point that is 2.1 M random reads of each plane (on the 2-core development box,
210–270 ms a call with the fused CPU kernel). On a lattice, bilinear interpolation is separable: the value of
a plane at every lattice point is ``W · P · Wᵀ``, where ``W`` (G, R) holds each lattice coordinate's two
linear weights over the R texels, and a line's values are ``W · L``. The sum over channels of a plane times a
line is then a matrix product per axis pair, (G², C) × (C, G). Same conventions as
:func:`~spikenerf.fields.vm_gather.gather_vm` (``align_corners=True``, zeros outside the grid, planes indexed
by ``(coord[MAT[m][0]] ↔ w, coord[MAT[m][1]] ↔ h)``), whose :func:`~spikenerf.fields.vm_gather.corners` gives
the weights, so the values equal the point-by-point lookups up to float rounding.
"""

from __future__ import annotations

import torch
from torch import Tensor

from spikenerf.fields.vm_gather import MAT, VEC, corners

_AXES = "xyz"  # the output's index order (the occupancy grid's: x, y, z)


def lattice_weights(coords: Tensor, size: int) -> Tensor:
    """Linear interpolation matrix (G, size): row i has the weights of ``coords[i]`` (G,) in [−1, 1] over
    ``size`` texels (``align_corners=True``, 0 for a texel outside), so ``W @ values`` samples ``values``
    (size, ...) at every coordinate."""
    lo, hi, w_lo, w_hi = corners(coords, size)
    weights = coords.new_zeros(coords.shape[0], size)
    weights.scatter_add_(1, lo[:, None], w_lo[:, None])
    return weights.scatter_add_(1, hi[:, None], w_hi[:, None])


def vm_lattice_sum(planes: Tensor, lines: Tensor, coords: Tensor) -> Tensor:
    """``Σ_m Σ_c P_m·L_m`` at every point of the lattice ``coords × coords × coords``.

    Args:
        planes: (3, C, R, R). lines: (3, C, R, 1). coords: (G,) normalised coordinates, the same on each axis.
    Returns:
        (G, G, G), index order x, y, z: at ``[i, j, k]`` the summed VM lookup of the point
        ``(coords[i], coords[j], coords[k])``, as ``gather_vm(...).sum(dim=(1, 2))`` would give it.
    """
    if planes.dim() != 4 or lines.dim() != 4 or planes.shape[:2] != lines.shape[:2]:
        raise ValueError(f"planes/lines: expected (3, C, R, R) and (3, C, R, 1), got {tuple(planes.shape)} "
                         f"and {tuple(lines.shape)}")  # fmt: skip
    g = coords.shape[0]
    w_plane = lattice_weights(coords, planes.shape[-1]).to(planes.dtype)  # (G, R)
    w_line = lattice_weights(coords, lines.shape[2]).to(lines.dtype)
    out = planes.new_zeros(g, g, g)
    for m in range(3):
        (w_axis, h_axis), v_axis = MAT[m], VEC[m]
        plane = torch.einsum("ha,cab,wb->chw", w_plane, planes[m], w_plane)  # (C, G_h, G_w)
        line = lines[m, :, :, 0] @ w_line.T  # (C, G_v)
        subs = f"c{_AXES[h_axis]}{_AXES[w_axis]},c{_AXES[v_axis]}->{_AXES}"
        out += torch.einsum(subs, plane, line)
    return out

"""A boolean occupancy grid over the scene box for empty-space skipping."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor, nn

from spikenerf.core.errors import InputError, is_integer


def dilate(occupied: Tensor, radius: int) -> Tensor:
    """Boolean (X, Y, Z) ``occupied`` grown by ``radius`` cells: a cell is set where any cell of the
    (2·radius + 1)³ cube around it is (cells past the edge count as empty). The same as a 3-D max-pool of
    that size, stride 1, done as a logical or of shifted slices along each axis in turn (a 128³ grid, radius
    1, 2 CPU threads: 1.7 ms against ``F.max_pool3d``'s 135 ms; ``benchmarks/tools/bench_occupancy.py``)."""
    if radius < 0:
        raise ValueError(f"radius: expected ≥ 0, got {radius}")
    out = occupied
    for axis in range(3):
        n, grown = out.shape[axis], out.clone()
        for shift in range(1, min(radius, n - 1) + 1):
            grown.narrow(axis, shift, n - shift).logical_or_(out.narrow(axis, 0, n - shift))
            grown.narrow(axis, 0, n - shift).logical_or_(out.narrow(axis, shift, n - shift))
        out = grown
    return out


class OccupancyGrid(nn.Module):
    """A (R, R, R) boolean grid over the normalised box ``[−1, 1]³`` (index order x, y, z).

    Starts fully occupied; :meth:`update` marks a cell occupied where the density at its centre gives an
    opacity above a threshold over one marching step, dilated by ``dilation`` cells so that thin surfaces
    between cell centres are kept. An update that would leave no cell occupied (a field that has not learnt
    any density yet) is refused: culling everything would also stop every gradient, for good.
    Queries are one integer gather per point. ``bounds`` (2, 3) is the normalised box around the occupied
    cells, so renderers can also shorten the rays.
    """

    def __init__(self, resolution: int) -> None:
        if not is_integer(resolution) or resolution < 1:  # (0 made an empty grid, -2 a torch error)
            raise InputError(f"resolution must be an integer ≥ 1, found {resolution!r}", param="resolution")
        super().__init__()
        self.register_buffer("grid", torch.ones(resolution, resolution, resolution, dtype=torch.bool))
        self.register_buffer("bounds", torch.tensor([[-1.0] * 3, [1.0] * 3]))

    @property
    def resolution(self) -> int:
        return int(self.grid.shape[0])

    def occupied_fraction(self) -> float:
        """Share of occupied cells in [0, 1]."""
        return float(self.grid.float().mean())

    def cell_index(self, xyz_norm: Tensor) -> Tensor:
        """Flat cell index of normalised points (M, 3) in [−1, 1] → (M,) int64 (clamped to the grid)."""
        r = self.resolution  # int32 cells where R³ fits (half the bytes of the (M, 3) int64 ones)
        cells = torch.int32 if r**3 < 2**31 else torch.int64
        ijk = ((xyz_norm + 1.0) * (0.5 * r)).clamp_(0, r - 1).to(cells)  # clamped first: no int overflow
        return ((ijk[:, 0] * r + ijk[:, 1]) * r + ijk[:, 2]).long()

    def lookup(self, xyz_norm: Tensor) -> Tensor:
        """Occupancy of the cells of normalised points (M, 3) → (M,) bool (outside: the nearest cell)."""
        return self.grid.reshape(-1).index_select(0, self.cell_index(xyz_norm))

    def query(self, xyz_norm: Tensor) -> Tensor:
        """Occupancy of normalised points (M, 3) → (M,) bool (points outside ``[−1, 1]³`` are False)."""
        return self.lookup(xyz_norm) & (xyz_norm.abs() <= 1.0).all(dim=-1)

    def axis_centres(self) -> Tensor:
        """Normalised centres (R,) of the cells along an axis (the same on all three), ``(i + ½)·2/R − 1``."""
        r = self.resolution
        return (torch.arange(r, device=self.grid.device, dtype=torch.float32) + 0.5) * (2.0 / r) - 1.0

    def cell_centres(self) -> Tensor:
        """Normalised centres of all cells, (R³, 3) in flat-index order."""
        c = self.axis_centres()
        return torch.stack(torch.meshgrid(c, c, c, indexing="ij"), dim=-1).reshape(-1, 3)

    @torch.no_grad()
    def update(
        self,
        density_fn: Callable[[Tensor], Tensor],
        step_size: float,
        threshold: float = 1e-4,
        dilation: int = 1,
        chunk: int = 1 << 18,
    ) -> float:
        """Recompute the grid from ``density_fn`` at every cell centre (:meth:`update_from`).

        Args:
            density_fn: normalised points (M, 3) → density (M,) per world unit, called on chunks of
                ``chunk`` cell centres.
            step_size, threshold, dilation: as :meth:`update_from`.
        """
        centres = self.cell_centres()
        sigma = torch.cat([density_fn(centres[i : i + chunk]) for i in range(0, len(centres), chunk)])
        return self.update_from(sigma.reshape(self.grid.shape), step_size, threshold, dilation)

    @torch.no_grad()
    def update_from(
        self, sigma: Tensor, step_size: float, threshold: float = 1e-4, dilation: int = 1
    ) -> float:
        """Recompute the grid from the density at the cell centres; returns the occupied fraction (unchanged,
        and the grid too, if no cell would be occupied).

        Args:
            sigma: (R, R, R) density per world unit at the centres (index order x, y, z).
            step_size: marching step in world units; a cell is occupied where
                ``1 − exp(−σ·step) > threshold``.
            dilation: cells added around every occupied cell (a cube of radius ``dilation``).
        """
        if sigma.shape != self.grid.shape:
            raise ValueError(
                f"sigma: expected the grid's shape {tuple(self.grid.shape)}, got {tuple(sigma.shape)}"
            )
        alpha = 1.0 - torch.exp(-sigma * step_size)
        occ = dilate(alpha > threshold, dilation)
        if not bool(occ.any()):
            return self.occupied_fraction()
        self.grid.copy_(occ)  # in place: a CUDA graph that reads the grid keeps its address
        self.bounds.copy_(self._occupied_bounds())
        return self.occupied_fraction()

    def _occupied_bounds(self) -> Tensor:
        """(2, 3) normalised corners of the box around all occupied cells (a point at 0 when none)."""
        r = self.resolution
        lo, hi = [], []
        for axis in range(3):
            other = tuple(a for a in range(3) if a != axis)
            idx = self.grid.any(dim=other).nonzero().squeeze(1)
            lo.append(idx.min() if len(idx) else r // 2)
            hi.append(idx.max() + 1 if len(idx) else r // 2)
        cells = torch.tensor([[float(v) for v in lo], [float(v) for v in hi]], device=self.grid.device)
        return cells * (2.0 / r) - 1.0

    def resize(self, resolution: int) -> None:
        """Start over at a new resolution, fully occupied."""
        self.grid = torch.ones(resolution, resolution, resolution, dtype=torch.bool, device=self.grid.device)
        self.bounds = torch.tensor([[-1.0] * 3, [1.0] * 3], device=self.grid.device)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        saved = state_dict.get(prefix + "grid")
        if torch.is_tensor(saved) and (saved.dim() != 3 or len(set(saved.shape)) != 1 or saved.shape[0] < 1):
            raise InputError(
                f"occupancy grid {prefix}grid has shape {tuple(saved.shape)}, expected (G, G, G)"
            )
        if saved is not None and saved.shape != self.grid.shape:
            self.grid = torch.ones(saved.shape, dtype=torch.bool, device=self.grid.device)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

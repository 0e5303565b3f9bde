"""A model's geometry as points: rendered views back-projected, its density on a lattice, surface colours.

The pieces of ``spikenerf export`` (``eval/export.py``) that read the model: :func:`view_points` renders a
view as ``render`` does (:func:`~spikenerf.render.model.render_image`) and puts each opaque pixel's expected
termination depth back on its ray; :func:`density_grid` samples the field's density over the scene box on a
regular lattice (skipping the empty space of the run's occupancy grid, where it has one);
:func:`lattice_normals` gives outward unit normals from that density's gradient; :func:`surface_colors`
asks the field the colour of surface points seen head-on.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from spikenerf.data.rays import image_rays
from spikenerf.fields.occupancy import OccupancyGrid, dilate
from spikenerf.render.base import RadianceModel
from spikenerf.render.inference import inference_chunk
from spikenerf.render.model import render_image
from spikenerf.scenes.trajectory import Intrinsics


def backproject(origins: Tensor, dirs: Tensor, depth: Tensor, opacity: Tensor, min_opacity: float) -> Tensor:
    """World points (K, 3) ``origin + depth · dir`` of the rays whose opacity exceeds ``min_opacity``.

    Args:
        origins: (N, 3). dirs: (N, 3) unit directions, so that ``depth`` is a distance.
        depth: (N,) expected termination distance (``RenderOutput.depth``: normalised by the opacity).
        opacity: (N,) accumulated opacity in [0, 1].
    Returns:
        (K, 3) points of the K kept rays, in ray order (:func:`kept_rays` gives their mask).
    """
    keep = kept_rays(opacity, min_opacity)
    return origins[keep] + depth[keep, None] * dirs[keep]


def kept_rays(opacity: Tensor, min_opacity: float) -> Tensor:
    """Bool mask (N,) of the rays whose opacity (N,) exceeds ``min_opacity`` (and whose depth means
    something: an empty ray's depth is 0)."""
    return opacity > min_opacity


@torch.no_grad()
def view_points(
    model: RadianceModel, c2w: Tensor | np.ndarray, intrinsics: Intrinsics, near: float | None = None,
    far: float | None = None, min_opacity: float = 0.5, chunk: int = 0, precision: str = "fp32",
) -> tuple[Tensor, Tensor]:  # fmt: skip
    """One view's opaque pixels as coloured world points.

    Args:
        c2w: (4, 4) camera-to-world of the view; ``intrinsics``, ``near``/``far``, ``chunk``, ``precision``:
            as :func:`~spikenerf.render.model.render_image`.
        min_opacity: keep pixels whose accumulated opacity exceeds it.
    Returns:
        points (K, 3) float32 on the CPU, in pixel order, and their linear colours (K, C) in [0, 1].
    """
    r = render_image(model, c2w, intrinsics, near, far, chunk, precision)
    origins, dirs = image_rays(torch.as_tensor(np.asarray(c2w), dtype=torch.float32), intrinsics)
    depth, opacity = r.depth.reshape(-1).float().cpu(), r.opacity.reshape(-1).float().cpu()
    keep = kept_rays(opacity, min_opacity)
    points = backproject(origins.cpu().float(), dirs.cpu().float(), depth, opacity, min_opacity)
    colors = r.color.reshape(-1, r.color.shape[-1]).float().cpu()[keep]
    return points, colors


def lattice_axes(model: RadianceModel, resolution: int) -> tuple[Tensor, Tensor]:
    """The lattice of :func:`density_grid`: ``resolution`` (G,) normalised coordinates from −1 to 1 (the
    box's faces included) and the world spacing (3,) between neighbours along x, y, z."""
    coords = torch.linspace(-1.0, 1.0, resolution, device=model.device)
    box = model.scene_box.float().cpu()
    return coords, (box[1] - box[0]) / (resolution - 1)


#: lattice steps past the lattice points in occupied cells at which :func:`density_grid` still asks the field:
#: one for the lattice cubes that cross a level, one more for the central differences of
#: :func:`lattice_normals` at their corners
OCCUPANCY_MARGIN = 2


def occupancy_of(model: RadianceModel) -> OccupancyGrid | None:
    """The occupancy grid the model's renders skip empty space with (the grid model's, while its
    ``use_occupancy`` is on), else None."""
    grid = getattr(model.field, "occupancy", None)
    return grid if isinstance(grid, OccupancyGrid) and getattr(model, "use_occupancy", False) else None


def lattice_occupied(grid: OccupancyGrid, coords: Tensor) -> Tensor:
    """Bool (G, G, G) on the CPU: which points of the lattice ``coords``³ ((G,) normalised coordinates,
    index order x, y, z) lie in an occupied cell of ``grid`` (cells as
    :meth:`~spikenerf.fields.occupancy.OccupancyGrid.cell_index` finds them: clamped, truncated)."""
    r = grid.resolution
    idx = ((coords.to(grid.grid.device, torch.float32) + 1.0) * (0.5 * r)).clamp(0, r - 1).long().cpu()
    cells = grid.grid.cpu().numpy()  # (numpy's outer indexing: 20× torch's index_select on bools)
    return torch.from_numpy(np.ascontiguousarray(cells[np.ix_(idx.numpy(), idx.numpy(), idx.numpy())]))


@torch.no_grad()
def density_grid(model: RadianceModel, resolution: int, occupancy: bool = True) -> Tensor:
    """The field's density per world unit (G, G, G) float32 on the CPU, G = ``resolution`` ≥ 2, at the
    points ``box_min + (i, j, k) · spacing`` of a regular lattice over the scene box (index order x, y, z;
    :func:`lattice_axes` gives the spacing). The field evaluates it at once (the grid field by separable
    interpolation; the others in chunks of points, :meth:`~spikenerf.fields.base.Field.density_lattice`).

    With ``occupancy`` and a run that skips empty space (:func:`occupancy_of`), the field is asked only on
    the smallest sub-cube of the lattice that holds every point within :data:`OCCUPANCY_MARGIN` lattice
    steps of an occupied cell's points; every other point is empty (0), as the renderer takes it. Where the
    grid is conservative (the density is below the level outside its occupied cells) a marching-cubes
    surface and its :func:`lattice_normals` are those of the whole lattice.
    """
    coords, _ = lattice_axes(model, resolution)
    grid = occupancy_of(model) if occupancy else None
    if grid is None:
        return model.field.density_lattice(coords).float().cpu()
    keep = dilate(lattice_occupied(grid, coords), OCCUPANCY_MARGIN)
    out = torch.zeros(resolution, resolution, resolution)
    spans = [keep.any(dim=tuple(a for a in range(3) if a != axis)).nonzero() for axis in range(3)]
    if not len(spans[0]):
        return out
    lo, hi = min(int(s[0]) for s in spans), max(int(s[-1]) for s in spans) + 1
    sub = model.field.density_lattice(coords[lo:hi]).float().cpu()
    out[lo:hi, lo:hi, lo:hi] = torch.where(keep[lo:hi, lo:hi, lo:hi], sub, 0.0)
    return out


def lattice_normals(volume: np.ndarray, points: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """Outward unit normals (V, 3) float32 at ``points`` (V, 3) of a density ``volume`` (G, G, G) sampled
    with world ``spacing`` (3,): minus its gradient (central differences, one-sided at the faces, each
    component interpolated trilinearly), normalised; a density higher inside has them pointing out.
    ``points`` are in world units from the lattice's first point (marching cubes' vertices); a point where
    the gradient vanishes gets (0, 0, 0)."""
    v = np.asarray(volume, dtype=np.float32)
    at = np.asarray(points, dtype=np.float64) / np.asarray(spacing, dtype=np.float64)
    size = np.asarray(v.shape)
    base = np.clip(np.floor(at).astype(np.int64), 0, size - 2)
    frac = np.clip(at - base, 0.0, 1.0)
    grad = np.zeros((len(at), 3))
    for axis in range(3):
        part = np.gradient(v, float(spacing[axis]), axis=axis)  # (G, G, G), one axis at a time
        for corner in range(8):
            bits = [(corner >> a) & 1 for a in range(3)]
            weight = np.prod([frac[:, a] if b else 1.0 - frac[:, a] for a, b in enumerate(bits)], axis=0)
            idx = base + np.asarray(bits)
            grad[:, axis] += weight * part[idx[:, 0], idx[:, 1], idx[:, 2]]
    length = np.linalg.norm(grad, axis=-1, keepdims=True)
    return np.where(length > 0, -grad / np.where(length > 0, length, 1.0), 0.0).astype(np.float32)


@torch.no_grad()
def surface_colors(model: RadianceModel, points: Tensor, normals: Tensor, chunk: int = 0) -> Tensor:
    """Linear colour (M, C) in [0, 1] of the field at world ``points`` (M, 3), seen head-on from outside:
    along the view direction ``−normal`` (``normals`` (M, 3) unit, pointing out of the surface, as
    ``skimage.measure.marching_cubes`` gives them for a density that is higher inside), as a camera ray
    hitting the surface square on would see it. ``chunk``: points a call (0 = automatic)."""
    chunk = inference_chunk(model, chunk)
    dirs = -torch.nn.functional.normalize(normals.float(), dim=-1, eps=1e-12)
    parts = []
    for i in range(0, len(points), chunk):
        p = points[i : i + chunk].to(model.device, torch.float32)
        parts.append(model.field(p, dirs[i : i + chunk].to(model.device))[1].float().cpu())
    if not parts:
        return torch.zeros(0, model.channels)
    return torch.cat(parts)

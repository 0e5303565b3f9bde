"""What ``spikenerf export`` writes: a trained run's geometry as a coloured point cloud or mesh (PLY).

``export_run(run, out, kind)`` writes one binary little-endian PLY file (:mod:`spikenerf.core.ply`),
atomically, refusing an existing file unless ``overwrite``:

- ``kind="pointcloud"``: every view of ``trajectory`` (``test``, ``orbit``, ``spiral``, ``interpolate``, a
  transforms.json or a nerfstudio camera_path.json, resolved as ``render`` resolves it,
  :func:`~spikenerf.eval.trajectories.resolve_trajectory`) is rendered as ``render`` renders it; each pixel
  whose accumulated opacity exceeds ``min_opacity`` becomes the point at its expected termination depth along
  its ray, coloured with the pixel's rendered colour. ``max_points`` keeps that many of them, drawn without
  replacement with a fixed seed (the same file every time).
- ``kind="mesh"``: the field's density is sampled on a ``resolution``³ lattice over the scene box (the box's
  faces included; where the run has an occupancy grid, only around its occupied cells,
  :func:`~spikenerf.render.geometry.density_grid`) and ``skimage.measure.marching_cubes`` (the ``mesh``
  extra: scikit-image) extracts the surface where it equals ``density_level``. Each vertex carries its
  outward unit normal, minus the density's gradient (:func:`~spikenerf.render.geometry.lattice_normals`,
  written as the PLY's ``nx, ny, nz`` so that viewers shade the mesh smoothly), and the field's colour
  there, seen along ``−normal``: a camera looking square on at the surface from outside.

**Choosing ``density_level``.** Density σ is per world unit: a layer of thickness d is half opaque where
σ·d = ln 2. The default, 25, makes the surface where 3 % of the box's edge (for the analytic scenes' box of
edge 2: 0.06) of such density would hide about 80 % of what is behind it. Raise it when the mesh is bloated
or carries fog and floaters; lower it when it has holes where the renders look solid. A level outside the
density's range is refused with the range found, so a first try shows where to look.

Colours are written as 8-bit sRGB (as ``render``'s PNGs; a gray run's gray repeated over red, green, blue).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spikenerf.core.color import display_uint8, srgb_encode
from spikenerf.core.errors import InputError, check_choice, is_finite, is_integer
from spikenerf.core.limits import check_memory, check_resources
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import check_file_output
from spikenerf.core.ply import write_ply
from spikenerf.core.progress import bar as progress_bar
from spikenerf.eval.choices import (
    DEFAULT_DENSITY_LEVEL,
    DEFAULT_MIN_OPACITY,
    DEFAULT_RESOLUTION,
    EXPORT_KINDS,
)
from spikenerf.eval.trajectories import DEFAULT_ORBIT_FRAMES, RenderPath, refined_poses, resolve_trajectory
from spikenerf.render.base import RadianceModel
from spikenerf.render.geometry import (
    density_grid,
    lattice_axes,
    lattice_normals,
    surface_colors,
    view_points,
)
from spikenerf.render.inference import inference_chunk, resolve_precision
from spikenerf.scenes.render_paths import GENERATED_PATHS
from spikenerf.scenes.trajectory import ORBIT_STEP_BYTES
from spikenerf.train.run import open_run

INSTALL_HINT = "kind mesh needs scikit-image (marching cubes): pip install 'spikenerf[mesh]'"
#: the seed of ``max_points``'s draw
SEED = 0
#: the largest ``resolution`` (1024³ float32 densities are 4 GiB)
MAX_RESOLUTION = 1024
#: memory a pixel of a point cloud's views holds (its point, linear and 8-bit colour, the render's
#: depth, opacity and rays), and a lattice point of a mesh (its density, marching cubes' work arrays, one
#: component of the density's gradient and the occupancy mask)
PIXEL_BYTES, LATTICE_BYTES = 64, 32
#: bytes a point takes in the PLY (3 float32 + 3 uint8)
POINT_BYTES = 15


def require_marching_cubes() -> Callable[..., Any]:
    """``skimage.measure.marching_cubes``, or an InputError (naming ``kind``) with the install hint."""
    try:
        from skimage.measure import marching_cubes
    except ImportError:
        raise InputError(INSTALL_HINT, param="kind") from None
    return marching_cubes


def ply_colors(linear: np.ndarray) -> np.ndarray:
    """Linear colours (N, C), C = 1 or 3, in [0, 1] → 8-bit sRGB (N, 3) (gray repeated)."""
    encoded = display_uint8(srgb_encode(np.asarray(linear, dtype=np.float32)))
    return np.repeat(encoded, 3, axis=1) if encoded.shape[1] == 1 else encoded


def subsample(count: int, max_points: int | None, seed: int = SEED) -> np.ndarray:
    """Indices (K,), increasing, of ``min(count, max_points)`` of ``count`` items drawn without
    replacement with ``seed`` (all of them when ``max_points`` is None or not below ``count``)."""
    if max_points is None or max_points >= count:
        return np.arange(count)
    return np.sort(np.random.default_rng(seed).choice(count, size=max_points, replace=False))


def point_cloud(
    model: RadianceModel, path: RenderPath, min_opacity: float = DEFAULT_MIN_OPACITY,
    max_points: int | None = None, chunk: int = 0, precision: str = "fp32", progress: bool = False,
) -> tuple[np.ndarray, np.ndarray, int]:  # fmt: skip
    """The opaque pixels of every view of ``path`` as world points: (points float32 (K, 3), 8-bit sRGB
    colours (K, 3), the number of opaque pixels before ``max_points`` kept K of them)."""
    points, colors = [], []
    for pose in progress_bar(path.poses, desc=f"points {path.name}", unit="view", show=progress):
        p, c = view_points(model, pose, path.intrinsics, path.near, path.far, min_opacity, chunk, precision)
        points.append(p.numpy())
        colors.append(c.numpy())
    found = sum(len(p) for p in points)
    if found == 0:
        raise InputError(
            f"no pixel of the {len(path.poses)} view(s) has an opacity above min_opacity {min_opacity:g}: "
            "lower it, or check that the run has learnt the scene",
            param="min_opacity",
        )
    keep = subsample(found, max_points)
    all_points = np.concatenate(points)[keep]
    return all_points.astype(np.float32), ply_colors(np.concatenate(colors)[keep]), found


def mesh(
    model: RadianceModel, resolution: int = DEFAULT_RESOLUTION, density_level: float = DEFAULT_DENSITY_LEVEL,
    chunk: int = 0, occupancy: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The surface where the field's density equals ``density_level``: (vertices float32 (V, 3) in world
    units, triangles int64 (F, 3), 8-bit sRGB vertex colours (V, 3), outward unit vertex normals float32
    (V, 3)). ``occupancy``: skip the empty space of the run's occupancy grid (:func:`density_grid`)."""
    marching_cubes = require_marching_cubes()
    volume = density_grid(model, resolution, occupancy).numpy()
    lo, hi = float(volume.min()), float(volume.max())
    if not lo < density_level < hi:
        raise InputError(
            f"density_level {density_level:g} lies outside the density's range [{lo:.4g}, {hi:.4g}] on the "
            f"{resolution}³ lattice: no surface there; choose a level inside it",
            param="density_level",
        )
    _, spacing = lattice_axes(model, resolution)
    verts, faces, rough, _ = marching_cubes(volume, density_level, spacing=tuple(spacing.tolist()))
    normals = lattice_normals(volume, verts, spacing.numpy())
    flat = ~normals.any(axis=1)  # (a vanishing gradient: marching cubes' own estimate)
    normals[flat] = rough[flat]
    verts = verts + model.scene_box[0].float().cpu().numpy()
    # marching cubes winds a density that is higher inside clockwise seen from outside (its normals point
    # out, its right-hand face normals in): reversed, so that viewers (Blender, MeshLab, Open3D) see the
    # outside as the front faces, as the PLY convention (counter-clockwise from the front) has it
    faces = faces[:, ::-1]
    linear = surface_colors(
        model,
        torch.as_tensor(verts, dtype=torch.float32),
        torch.as_tensor(np.ascontiguousarray(normals)),
        chunk,
    )
    return verts.astype(np.float32), faces.astype(np.int64), ply_colors(linear.numpy()), normals


def check_export_args(
    kind: str, min_opacity: float, max_points: int | None, resolution: int, density_level: float,
    orbit_frames: int,
) -> None:  # fmt: skip
    """InputError naming the first bad parameter (each in its documented range)."""
    check_choice(kind, EXPORT_KINDS, "kind")
    if not (is_finite(min_opacity) and 0 <= min_opacity < 1):
        raise InputError(f"min_opacity must lie in [0, 1), found {min_opacity!r}", param="min_opacity")
    if max_points is not None and not (is_integer(max_points) and max_points >= 1):
        raise InputError(f"max_points must be an integer ≥ 1, found {max_points!r}", param="max_points")
    if not (is_integer(resolution) and 2 <= resolution <= MAX_RESOLUTION):
        raise InputError(
            f"resolution must be an integer in [2, {MAX_RESOLUTION}], found {resolution!r}",
            param="resolution",
        )
    if not (is_finite(density_level) and density_level > 0):
        raise InputError(
            f"density_level must be a number > 0, found {density_level!r}", param="density_level"
        )
    if not (is_integer(orbit_frames) and orbit_frames >= 1):
        raise InputError(f"orbit_frames must be an integer ≥ 1, found {orbit_frames!r}", param="orbit_frames")


def export_run(
    run_dir: str | Path,
    out: str | Path,
    kind: str = "pointcloud",
    trajectory: str = "test",
    orbit_frames: int = DEFAULT_ORBIT_FRAMES,
    min_opacity: float = DEFAULT_MIN_OPACITY,
    max_points: int | None = None,
    resolution: int = DEFAULT_RESOLUTION,
    density_level: float = DEFAULT_DENSITY_LEVEL,
    device: str = "cpu",
    dataset_root: str | Path | None = None,
    chunk: int = 0,
    precision: str = "auto",
    overwrite: bool = False,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Write a run's point cloud or mesh to the PLY file ``out`` (see the module doc); returns what was
    written (``kind``, ``points``/``vertices``, ``faces``, the settings, the run's iteration). Bad input
    raises an InputError naming the parameter before anything is written."""
    t0 = time.perf_counter()
    check_export_args(kind, min_opacity, max_points, resolution, density_level, orbit_frames)
    if kind == "mesh":
        require_marching_cubes()  # before any work
        check_memory(float(resolution) ** 3 * LATTICE_BYTES, "resolution")
    out = Path(out)
    check_file_output(out, "out", overwrite, within=("run",))  # (RUN/cloud.ply, as RUN/render)
    with output_lock(out), output_lock(run_dir, "RUN"):  # no train may write the run meanwhile
        model, config, dataset, ckpt = open_run(run_dir, dataset_root, device, train_images=False)
        chunk = inference_chunk(model, chunk)
        summary: dict[str, Any] = {
            "kind": kind,
            "iteration": int(ckpt["iteration"]),
            "run_iterations": config.iters,
        }
        if kind == "pointcloud":
            dataset = refined_poses(ckpt, config, dataset)
            if trajectory in GENERATED_PATHS:  # checked before its poses are made (1e7 frames: minutes)
                k = dataset.intrinsics
                pixels = float(orbit_frames) * k.width * k.height
                memory = pixels * PIXEL_BYTES + float(orbit_frames) * ORBIT_STEP_BYTES
                disk = min(pixels, max_points or pixels) * POINT_BYTES
                check_resources(memory, disk, out.parent, "trajectory/orbit_frames")
            path = resolve_trajectory(trajectory, dataset, orbit_frames)
            k = path.intrinsics
            pixels = float(len(path.poses)) * k.width * k.height
            disk = min(pixels, max_points or pixels) * POINT_BYTES
            check_resources(pixels * PIXEL_BYTES, disk, out.parent, "trajectory/orbit_frames")
            precision = resolve_precision(precision, model.device)
            points, colors, found = point_cloud(
                model, path, min_opacity, max_points, chunk, precision, progress
            )
            write_ply(out, points, colors)
            summary.update(points=len(points), opaque_pixels=found, views=len(path.poses),
                           trajectory=path.file or path.name, min_opacity=min_opacity)  # fmt: skip
            what = f"{len(points)} points (of {found} opaque pixels in {len(path.poses)} views)"
        else:
            verts, faces, colors, normals = mesh(model, resolution, density_level, chunk)
            write_ply(out, verts, colors, faces, normals)
            summary.update(vertices=len(verts), faces=len(faces), resolution=resolution,
                           density_level=density_level)  # fmt: skip
            what = f"a mesh of {len(verts)} vertices, {len(faces)} faces (density level {density_level:g})"
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    if log:
        unfinished = summary["iteration"] < config.iters
        note = (
            f" (the run's checkpoint at iteration {summary['iteration']} of {config.iters})"
            if unfinished
            else ""
        )
        log(f"wrote {out}: {what}{note}")
    return summary

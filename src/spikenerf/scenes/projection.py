"""Seeing the scene through a camera (pinhole, or through its lens): where world points land in an image
(:func:`project_points`, numpy or torch) and how far the image moves in one step of a trajectory
(:func:`image_motion`).
"""

from __future__ import annotations

import math
import sys

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.scenes.trajectory import Intrinsics


def project_points(c2w, points, intrinsics: Intrinsics):  # type: ignore[no-untyped-def]
    """Image coordinates of world ``points`` (..., 3) in cameras ``c2w`` (..., 4, 4) (OpenGL axes; both numpy
    arrays or both torch tensors, broadcast): (u, v, depth), each (...). Pixel ``(x, y)`` covers
    ``[x, x + 1) × [y, y + 1)`` (its centre is ``x + 0.5``, as :func:`spikenerf.data.rays.camera_directions`
    casts it), through the lens of a distorted camera; depth > 0 in front of the camera, where u and v are
    meaningful. Torch tensors are projected with autocast off (under ``--amp bf16`` a third of the points
    would land in another pixel).

    Raises:
        InputError: ``points`` not (..., 3) or ``c2w`` not (..., 4, 4).
    """
    if points.ndim == 0 or points.shape[-1] != 3:
        raise InputError(f"points must be (..., 3), found {tuple(points.shape)}", param="points")
    if c2w.ndim < 2 or tuple(c2w.shape[-2:]) != (4, 4):
        raise InputError(f"c2w must be (..., 4, 4) poses, found {tuple(c2w.shape)}", param="c2w")
    torch = sys.modules.get("torch")  # a tensor needs torch imported already; numpy ≥ 2 arrays have a
    if torch is not None and isinstance(points, torch.Tensor):  # ``device`` too (the string "cpu")
        with torch.autocast(points.device.type, enabled=False):
            return _project(c2w, points, intrinsics)
    return _project(c2w, points, intrinsics)


def _project(c2w, points, intrinsics: Intrinsics):  # type: ignore[no-untyped-def]
    rel = (points - c2w[..., :3, 3])[..., None, :]
    cam = (rel @ c2w[..., :3, :3])[..., 0, :]  # world → camera axes
    depth = -cam[..., 2]
    safe = depth * (depth > 1e-9) + 1.0 * (depth <= 1e-9)  # any value where the point is behind
    if intrinsics.distortion is not None:  # (the lens acts on OpenCV's normalised plane: y down)
        x, y = intrinsics.distortion.distort(cam[..., 0] / safe, -cam[..., 1] / safe)
        return intrinsics.fl_x * x + intrinsics.cx, intrinsics.fl_y * y + intrinsics.cy, depth
    u = intrinsics.fl_x * cam[..., 0] / safe + intrinsics.cx
    v = -intrinsics.fl_y * cam[..., 1] / safe + intrinsics.cy
    return u, v, depth


def image_motion(poses: np.ndarray, intrinsics: Intrinsics, box: np.ndarray, pairs: int = 64) -> float:
    """How far the image moves in one step: the median, in pixels, of the displacement between consecutive
    poses of a 6³ lattice of points inside ``box``, over ``pairs`` step pairs spread along the trajectory
    (points behind either camera or outside the first image are left out). NaN when none is seen. Where a
    pose is held for several steps (an image sequence's ``steps_per_frame``), a pair reaches from the
    held pose to the next one and its displacement is divided by the steps the pose was held (consecutive
    repeated poses gave 0 px a step for a camera that moves a frame's worth every few steps).

    Args:
        poses: (T, 4, 4) camera-to-world, OpenGL axes (the camera looks down −z), T ≥ 2.
        intrinsics: the camera. box: (2, 3) scene box min/max corners.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) < 2:
        raise InputError(f"poses must be (T ≥ 2, 4, 4), found {poses.shape}", param="poses")
    lo, hi = np.asarray(box, dtype=np.float64)
    grid = np.linspace(0.1, 0.9, 6)
    points = lo + np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), -1).reshape(-1, 3) * (hi - lo)

    def project(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u, v, depth = project_points(c2w, points, intrinsics)
        return np.stack([u, v], axis=-1), depth

    changes = np.flatnonzero((poses[1:] != poses[:-1]).any(axis=(1, 2)))  # step m → m + 1 moves
    moves = []
    for k in np.unique(np.linspace(0, len(poses) - 2, pairs).astype(int)):
        at = np.searchsorted(changes, k)  # the first move at or after step k
        start = int(changes[at - 1]) + 1 if at > 0 else 0  # where the pose of step k began to be held
        j = int(changes[at]) + 1 if at < len(changes) else k + 1  # (none left: held to the end, 0 px)
        (a, za), (b, zb) = project(poses[k]), project(poses[j])
        seen = (za > 1e-9) & (zb > 1e-9) & (a[:, 0] >= 0) & (a[:, 0] < intrinsics.width)
        seen &= (a[:, 1] >= 0) & (a[:, 1] < intrinsics.height)
        moves.append(np.linalg.norm(b - a, axis=-1)[seen] / (j - min(start, k)))
    moved = np.concatenate(moves)
    return float(np.median(moved)) if len(moved) else math.nan

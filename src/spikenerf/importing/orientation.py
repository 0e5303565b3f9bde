"""Turning an imported frame upright before its unit box is fitted (``import --orient``): the scene's up from
the cameras, then a turn about +Z onto the scene's vertical planes (:func:`plane_turn`) or for the smallest
box."""

from __future__ import annotations

import math
from typing import Literal, get_args

import numpy as np

from spikenerf.core.errors import InputError

#: the sparse points' percentiles that bound the scene box (per axis, in the oriented frame)
BOX_PERCENTILES = (2.0, 98.0)


def up_direction(poses: np.ndarray) -> np.ndarray | None:
    """The scene's up (3,) unit vector seen from poses (N, 4, 4): the direction most nearly perpendicular to
    every camera's right axis (a camera without roll holds its right axis level, whatever its path: an
    orbit, an arc of one, a path that rises and falls), signed to agree with the mean of the cameras' up
    axes. When the right axes do not spread over two directions (every camera turned alike, as in a
    forward-facing capture) or that direction is over 45° from the mean up, the mean up itself. None when
    the up axes nearly cancel (their mean is under 0.25 long)."""
    mean_up = poses[:, :3, 1].mean(0)
    length = float(np.linalg.norm(mean_up))
    if length < 0.25:
        return None
    mean_up = mean_up / length
    _, sv, vt = np.linalg.svd(poses[:, :3, 0], full_matrices=False)
    if len(sv) == 3 and sv[1] > 0.02 * sv[0] and abs(vt[2] @ mean_up) > math.cos(math.radians(45)):
        return vt[2] * np.sign(vt[2] @ mean_up)
    return mean_up


#: how an imported frame is oriented before its unit box is fitted (``import --orient``): ``up`` turns it
#: upright and then about +Z so that the scene's vertical planes lie along the axes (the smallest box where
#: the points show no planes), ``up-box`` upright and turned for the smallest box, ``none`` keeps the axes
Orient = Literal["up", "up-box", "none"]
ORIENTS: tuple[str, ...] = get_args(Orient)
#: :func:`upright`'s turn about +Z: the scene's vertical planes onto the axes, or the smallest box
Turn = Literal["planes", "box"]
TURNS: tuple[str, ...] = get_args(Turn)
#: neighbours of a sparse point that its local plane is fitted to (:func:`plane_turn`)
PLANE_NEIGHBOURS = 32
#: :func:`plane_turn`'s score (the four-fold alignment of the plane normals over its value for normals that
#: point anywhere) from which the planes decide the turn; below it the smallest box does. Normals at random
#: angles reach 2 with probability e⁻⁴ ≈ 2% (the score is Rayleigh-distributed for them)
PLANE_MIN_SCORE = 2.0


def check_orient(orient: str) -> None:
    """InputError naming ``orient`` unless it is one of :data:`ORIENTS`."""
    if orient not in ORIENTS:
        raise InputError(f"orient must be one of {', '.join(ORIENTS)}, found {orient!r}", param="orient")


def plane_turn(xyz: np.ndarray, neighbours: int = PLANE_NEIGHBOURS) -> tuple[float, float]:
    """The turn about +Z (radians, in (−π/4, π/4]) that brings the scene's vertical planes onto the X and Y
    axes, from sparse points (N, 3) of an upright frame, and how clearly the points show such planes.

    Each point's local plane is the least-squares plane of its ``neighbours`` nearest points (PCA; its normal
    is the direction of least spread). A normal at angle φ in the XY plane is weighted by its flatness
    (1 − λ₀/λ₁) and how horizontal it is (|n_xy|²). Walls at right angles agree in 4φ (the Manhattan-world
    assumption), so the turn is the angle of the weighted mean of e^{4iφ}, divided by 4 (curved surfaces
    spread their normals evenly: they add noise, not a bias). Returns ``(turn, score)``: the score is the
    length of that mean over its expected length for normals pointing anywhere (≈ 0.9; ≥
    :data:`PLANE_MIN_SCORE` is a clear answer). ``(0, 0)`` for fewer than 2·``neighbours`` points."""
    from scipy.spatial import cKDTree

    xyz = np.asarray(xyz, np.float64)
    if len(xyz) < 2 * neighbours:
        return 0.0, 0.0
    _, idx = cKDTree(xyz).query(xyz, k=neighbours)
    near = xyz[idx] - xyz[idx].mean(1, keepdims=True)  # (N, k, 3)
    spread, axes = np.linalg.eigh(np.einsum("nki,nkj->nij", near, near))  # ascending
    normal = axes[:, :, 0]
    weight = (1 - spread[:, 0] / np.maximum(spread[:, 1], 1e-300)) * (normal[:, 0] ** 2 + normal[:, 1] ** 2)
    total = float(weight.sum())
    if not total > 0:
        return 0.0, 0.0
    mean = complex((weight * np.exp(4j * np.arctan2(normal[:, 1], normal[:, 0]))).sum())
    return -float(np.angle(mean)) / 4, abs(mean) / math.sqrt(float((weight**2).sum()))


def upright(poses: np.ndarray, points: np.ndarray | None = None, turn: Turn = "planes") -> np.ndarray:
    """A rotation (3, 3) that takes :func:`up_direction` to +Z and then turns about +Z (``turn``, one of
    :data:`TURNS`): ``planes`` puts the scene's vertical planes on the X and Y axes (:func:`plane_turn`)
    where the sparse points (N, 3) show them clearly (the grid field's factors are axis-aligned, so
    axis-aligned structure costs it least; docs/real-data.md measures it), else it does what ``box`` does:
    the angle (1° steps) that makes the points' box smallest (:data:`BOX_PERCENTILES`). At most 20000
    points, evenly picked. No turn without points; the identity when the cameras show no up."""
    return orientation(poses, points, turn)[0]


def orientation(
    poses: np.ndarray, points: np.ndarray | None = None, turn: Turn = "planes"
) -> tuple[np.ndarray, str, float]:
    """:func:`upright`'s rotation (3, 3) and how it turned about +Z: ``(rotation, rule, score)``, rule
    ``planes``, ``box`` or ``none`` (no points, or no up) and :func:`plane_turn`'s score (0: not asked)."""
    from scipy.spatial.transform import Rotation

    if turn not in TURNS:
        raise InputError(f"turn must be one of {', '.join(TURNS)}, found {turn!r}", param="turn")
    up = up_direction(poses)
    if up is None:
        return np.eye(3), "none", 0.0
    axis = np.cross(up, [0.0, 0.0, 1.0])
    sin, cos = float(np.linalg.norm(axis)), float(up[2])
    if sin < 1e-12:  # already up, or upside down: half a turn about X
        tilt = np.eye(3) if cos > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        tilt = Rotation.from_rotvec(axis / sin * math.atan2(sin, cos)).as_matrix()
    if points is None or len(points) < 8:
        return tilt, "none", 0.0
    points = np.asarray(points, np.float64)
    points = points[np.unique(np.linspace(0, len(points) - 1, min(len(points), 20000)).astype(int))] @ tilt.T
    score = 0.0
    if turn == "planes":
        angle, score = plane_turn(points)
        if score >= PLANE_MIN_SCORE:
            return Rotation.from_euler("z", angle).as_matrix() @ tilt, "planes", score
    xy = points[:, :2]
    angles = np.radians(np.arange(90))
    c, s = np.cos(angles), np.sin(angles)
    turned = np.stack([xy[:, 0, None] * c - xy[:, 1, None] * s, xy[:, 0, None] * s + xy[:, 1, None] * c])
    lo, hi = np.percentile(turned, BOX_PERCENTILES, axis=1)  # (2, A) each
    return Rotation.from_euler("z", angles[np.argmin((hi - lo).max(0))]).as_matrix() @ tilt, "box", score

"""The unit box of an imported scene: the similarity that maps it into ``[-1, 1]^3`` (from sparse points, the
source's scene box or the cameras' focus), the frustum box of forward-facing poses and near/far from sparse
points."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.importing.orientation import BOX_PERCENTILES, Orient, check_orient, orientation


def focus_point(poses: np.ndarray) -> np.ndarray:
    """The point (3,) nearest (least squares) to every camera's optical axis (what an orbit looks at)."""
    found = _axes_meet(poses)
    return poses[:, :3, 3].mean(0) if found is None else found  # parallel axes: the cameras' mean


def _axes_meet(poses: np.ndarray) -> np.ndarray | None:
    """The least-squares meeting point (3,) of the optical axes; None when they are (nearly) parallel."""
    eyes, fwd = poses[:, :3, 3], -poses[:, :3, 2]
    proj = np.eye(3)[None] - fwd[:, :, None] * fwd[:, None, :]  # projects out each axis direction
    a, b = proj.sum(0), np.einsum("nij,nj->i", proj, eyes)
    if np.linalg.cond(a) > 1e8:
        return None
    return np.linalg.solve(a, b)


def frustum_box(poses: np.ndarray, near: float, far: float) -> np.ndarray:
    """The bounds (2, 3) of the camera centres and the points ``near`` and ``far`` along each optical axis
    of poses (N, 4, 4) (LLFF's per-view depth bounds: a forward-facing scene)."""
    eyes, fwd = poses[:, :3, 3], -poses[:, :3, 2]
    pts = np.concatenate([eyes, eyes + near * fwd, eyes + far * fwd])
    return np.stack([pts.min(0), pts.max(0)])


#: the box from sparse points is this much wider than their percentiles: the points sample textured
#: surfaces only and the percentiles drop the extremes, so without a margin the box clips the scene's edges
#: (docs/real-data.md measures it on the benchmark scenes)
BOX_MARGIN = 1.2


@dataclass(frozen=True, eq=False)
class Normalisation:
    """The similarity that maps a source frame into the unit box: ``x' = scale · rotation @ (x − center)``.

    Attributes:
        rotation: (3, 3) turns the source frame (identity: kept as it is). center: (3,) in the source frame.
        scale: source units → unit-box units. turn: how the upright frame was turned about +Z (``planes``,
        ``box``; ``none``: not turned). plane_score: the score of
        :func:`~spikenerf.importing.orientation.plane_turn` (0: not computed).
    """

    rotation: np.ndarray
    center: np.ndarray
    scale: float
    turn: str = "none"
    plane_score: float = 0.0

    def points(self, x: np.ndarray) -> np.ndarray:
        """Points (N, 3) of the source frame in the unit-box frame."""
        return self.scale * (np.asarray(x, np.float64) - self.center) @ self.rotation.T

    def poses(self, poses: np.ndarray) -> np.ndarray:
        """Camera-to-world poses (N, 4, 4) of the source frame in the unit-box frame."""
        out = np.array(poses, np.float64)
        out[:, :3, :3] = self.rotation @ out[:, :3, :3]
        out[:, :3, 3] = self.points(out[:, :3, 3])
        return out

    def record(self) -> dict:
        """What ``config.yaml`` stores under ``imported.normalisation``."""
        return {
            "center": [float(c) for c in self.center],
            "scale": float(self.scale),
            "rotation": [[float(v) for v in row] for row in self.rotation],
            "turn": self.turn,
            "plane_score": round(float(self.plane_score), 3),
        }


#: the smallest half-width of the frustum box, as a share of the cameras' spread, that sizes a scene from
#: the cameras alone (:func:`frustum_focus`)
MIN_FRUSTUM_SHARE = 0.05
_NO_BOX = (
    "give a 'scene_box' in a transforms.json, a COLMAP model with points, or LLFF poses_bounds.npy with "
    "depth bounds"
)


def normalisation(
    poses: np.ndarray,
    points: np.ndarray | None = None,
    scene_box: np.ndarray | None = None,
    camera_angle_x: float = 0.69,
    orient: Orient = "up",
    focus: np.ndarray | None = None,
) -> Normalisation:
    """The similarity mapping the scene into the unit box ``[-1, 1]^3`` (see :class:`Normalisation`).

    The box comes from the sparse points (N, 3) (2nd–98th percentile per axis, widened by
    :data:`BOX_MARGIN`) when given, else the source's scene box (2, 3), else the cameras' focus point with
    the half-width of the view frustum at the nearest camera distance. Without a source box and with
    ``orient`` (one of :data:`~spikenerf.importing.orientation.ORIENTS`) ``up`` or ``up-box``, the frame is
    first turned upright and about +Z (:func:`~spikenerf.importing.orientation.upright`, turn ``planes`` or
    ``box``): a COLMAP model's axes are arbitrary, and an axis-aligned box in them clips the scene.
    ``focus`` (3,): the point every camera looks at, where the source knows it (an orbit's centre); the
    frustum box is then sized around it whatever the lens, while for cameras alone a box under
    :data:`MIN_FRUSTUM_SHARE` of their spread is refused (axes that meet near a camera, or a lens too
    narrow for the path: no sure focus).
    """
    check_orient(orient)
    rotation, turn, score = np.eye(3), "none", 0.0
    if orient != "none" and scene_box is None:
        rotation, turn, score = orientation(poses, points, "box" if orient == "up-box" else "planes")
    if points is not None and len(points) >= 8:
        lo, hi = np.percentile(np.asarray(points, np.float64) @ rotation.T, BOX_PERCENTILES, axis=0)
        lo, hi = (lo + hi) / 2 - BOX_MARGIN * (hi - lo) / 2, (lo + hi) / 2 + BOX_MARGIN * (hi - lo) / 2
    elif scene_box is not None:
        lo, hi = np.asarray(scene_box, np.float64)
    else:
        c, half = frustum_focus(poses, camera_angle_x, focus)
        lo, hi = rotation @ c - half, rotation @ c + half
    half = float(np.max(hi - lo)) / 2
    if not half > 0:
        raise InputError("the scene has no extent (all sparse points or cameras coincide)")
    return Normalisation(rotation, rotation.T @ ((lo + hi) / 2), 1.0 / half, turn, score)


def frustum_focus(
    poses: np.ndarray, camera_angle_x: float, focus: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """The centre (3,) and half-width of the scene seen from poses (N, 4, 4) alone (:func:`normalisation`):
    the point their optical axes meet (``focus`` where the source knows it) and the half-width of the view
    frustum there at the nearest camera distance. InputError when the axes are parallel, or, without
    ``focus``, when that half-width is under :data:`MIN_FRUSTUM_SHARE` of the cameras' spread."""
    c = _axes_meet(poses)
    if c is None and focus is not None:  # (where both exist they agree up to rounding)
        c = np.asarray(focus, np.float64)
    if c is None:
        raise InputError(
            "cannot size the scene from the cameras alone: their optical axes are parallel and meet nowhere "
            f"(a forward-facing or straight path); {_NO_BOX}"
        )
    eyes = poses[:, :3, 3]
    spread = float(np.ptp(eyes, axis=0).max())
    half = float(np.linalg.norm(eyes - c, axis=1).min()) * math.tan(camera_angle_x / 2)
    if focus is None and half < MIN_FRUSTUM_SHARE * spread:
        raise InputError(
            "cannot size the scene from the cameras alone: where their optical axes meet, the view's "
            f"half-width {half:.3g} is under {MIN_FRUSTUM_SHARE:.0%} of the {spread:.3g} the cameras spread "
            f"over (a {math.degrees(camera_angle_x):.3g}° field of view too narrow for the path, or axes "
            f"that meet near a camera); check the field of view, or {_NO_BOX}"
        )
    return c, half


def near_far_from_points(
    poses: np.ndarray, points: np.ndarray, max_points: int = 20000, max_cameras: int = 128
) -> tuple[float, float] | None:
    """Ray bounds from the depths of sparse points (M, 3) in cameras (N, 4, 4): 0.8·p1 and 1.2·p99 of the
    positive depths (None when too few points are in front of the cameras). At most ``max_points`` points
    and ``max_cameras`` cameras (evenly spaced) are used, one camera at a time: memory stays bounded."""
    points = points[np.unique(np.linspace(0, len(points) - 1, min(len(points), max_points)).astype(int))]
    poses = poses[np.unique(np.linspace(0, len(poses) - 1, min(len(poses), max_cameras)).astype(int))]
    depth = np.concatenate([-(points - c2w[:3, 3]) @ c2w[:3, 2] for c2w in poses]) if len(points) else []
    depth = np.asarray(depth, np.float64)
    depth = depth[depth > 0]
    if len(depth) < 16:
        return None
    near, far = np.percentile(depth, [1, 99])
    return max(0.8 * float(near), 0.05), 1.2 * float(far)

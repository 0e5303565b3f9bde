"""The render paths of ``spikenerf render --trajectory`` (their names, :data:`RENDER_PATHS`) and their pose
maths: the LLFF-style spiral around the cameras' mean pose (:func:`spiral_path`) for forward-facing captures,
and the smooth path through keyframes of a trajectory (:func:`key_path`: slerp between keys, positions on a
Catmull-Rom spline, keys picked by :func:`path_keys`).
"""

from __future__ import annotations

import math
from typing import Literal, get_args

import numpy as np

from spikenerf.scenes.poses import interpolate_poses, look_at_unchecked

#: the built-in render paths of ``spikenerf render --trajectory`` (a file path is the other kind): ``test``
#: (the held-out views) and the generated ones, which take a frame count
RenderPathKind = Literal["test", "orbit", "spiral", "interpolate"]
RENDER_PATHS: tuple[str, ...] = get_args(RenderPathKind)
#: the render paths generated at a given number of frames (``--orbit-frames``)
GENERATED_PATHS = RENDER_PATHS[1:]
#: the spiral's turns, the rate of its depth wobble per turn (LLFF's ``zrate``) and the percentile of the
#: cameras' offsets that sets its radii
SPIRAL_TURNS, SPIRAL_ZRATE, SPIRAL_PERCENTILE = 2, 0.5, 90.0
#: where the spiral looks: this fraction of the way from ``1/near`` to ``1/far`` in inverse depth (LLFF's
#: ``dt = 0.75``), so ``1/focus = (1 − 0.75)/near + 0.75/far``
SPIRAL_FOCUS_DISPARITY = 0.75
#: the training poses the ``interpolate`` path passes through (spread evenly over the path's steps)
INTERPOLATE_KEYS = 16


def mean_pose(poses: np.ndarray) -> np.ndarray:
    """The mean camera (4, 4) of poses (N, 4, 4) c2w: the average position and the rotation nearest (in the
    Frobenius norm, by an SVD) to the average of the rotation matrices: an orthonormal one, det +1."""
    poses = np.asarray(poses, dtype=np.float64)
    u, _, vt = np.linalg.svd(poses[:, :3, :3].mean(0))
    rot = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0]) @ vt
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rot, poses[:, :3, 3].mean(0)
    return out


def spiral_focus(near: float, far: float) -> float:
    """The spiral's focus depth from the scene's ray bounds ``near`` < ``far`` (both > 0): the depth whose
    inverse lies :data:`SPIRAL_FOCUS_DISPARITY` of the way from ``1/near`` to ``1/far``."""
    return 1.0 / ((1.0 - SPIRAL_FOCUS_DISPARITY) / near + SPIRAL_FOCUS_DISPARITY / far)


#: the least length of the training cameras' mean view direction for a spiral (cos 45°: beyond it they look
#: around an object rather than ahead, and the spiral's centre falls among what they film)
FORWARD_FACING = math.cos(math.pi / 4)


def view_agreement(poses: np.ndarray) -> float:
    """The length of the mean unit view direction (−z axis) of the cameras ``poses`` (N, 4, 4) c2w: 1 when
    all look the same way (a forward-facing capture), near 0 around an object."""
    views = -np.asarray(poses, dtype=np.float64)[:, :3, 2]
    views /= np.maximum(np.linalg.norm(views, axis=-1, keepdims=True), 1e-12)
    return float(np.linalg.norm(views.mean(0))) if len(views) else 1.0


def spiral_path(
    poses: np.ndarray, near: float, far: float, count: int, turns: float = SPIRAL_TURNS
) -> np.ndarray:
    """An LLFF-style spiral (count, 4, 4) c2w for forward-facing captures, around the cameras ``poses``
    (N, 4, 4) c2w.

    Centred on :func:`mean_pose`; the radii (3,) are the :data:`SPIRAL_PERCENTILE` th percentile of the
    absolute camera offsets from the mean position, in the mean camera's axes (right, up, back). Frame i at
    angle θ = 2π·turns·i/count sits at ``(cos θ, −sin θ, −sin(θ·zrate)) · radii`` in those axes and looks
    at the focus point, :func:`spiral_focus` (near, far) in front of the mean camera, with the mean
    camera's up. Over count ≥ 3 frames the frames' mean position is the cameras' mean position.
    """
    centre = mean_pose(poses)
    rot, mid = centre[:3, :3], centre[:3, 3]
    offsets = (np.asarray(poses, dtype=np.float64)[:, :3, 3] - mid) @ rot  # in the mean camera's axes
    radii = np.percentile(np.abs(offsets), SPIRAL_PERCENTILE, axis=0)
    focus = mid - spiral_focus(near, far) * rot[:, 2]  # the camera looks down its −z axis
    up = rot[:, 1]
    theta = 2.0 * math.pi * turns * np.arange(count) / count
    local = np.stack([np.cos(theta), -np.sin(theta), -np.sin(theta * SPIRAL_ZRATE)], -1) * radii
    eyes = mid + local @ rot.T
    return np.stack([look_at_unchecked(eye, focus, up) for eye in eyes]) if count else np.zeros((0, 4, 4))


def catmull_rom(points: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points (M, 3) on the uniform Catmull-Rom spline through ``points`` (K, 3), K ≥ 2, at parameters ``s``
    (M,) in [0, K − 1] (``s = j`` is ``points[j]`` exactly). The outer control points are the end points
    reflected through their neighbours (``2·p₀ − p₁``), so the curve keeps its pace into the ends instead of
    slowing to them, as it would with the end points repeated."""
    p = np.asarray(points, dtype=np.float64)
    padded = np.concatenate([2 * p[:1] - p[1:2], p, 2 * p[-1:] - p[-2:-1]])
    s = np.asarray(s, dtype=np.float64)
    lo = np.clip(np.floor(s).astype(np.int64), 0, len(p) - 2)
    t = (s - lo)[:, None]
    p0, p1, p2, p3 = padded[lo], padded[lo + 1], padded[lo + 2], padded[lo + 3]
    out = 0.5 * (
        2 * p1 + (p2 - p0) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2 + (3 * p1 - p0 - 3 * p2 + p3) * t**3
    )
    exact = s == np.round(s)
    return np.where(exact[:, None], p[np.clip(np.round(s).astype(np.int64), 0, len(p) - 1)], out)


def key_path(key_poses: np.ndarray, count: int) -> np.ndarray:
    """A smooth path (count, 4, 4) c2w through ``key_poses`` (K, 4, 4) c2w in their order: rotations by
    quaternion slerp between neighbouring keys (:func:`interpolate_poses`), positions on the Catmull-Rom
    spline through the keys' positions (:func:`catmull_rom`). Frame i sits at key parameter
    ``s = i·(K − 1)/(count − 1)``: the first and last frames are the first and last keys, and key j is frame
    ``j·(count − 1)/(K − 1)`` exactly where that is an integer. One key (or count 1): the first key."""
    keys = np.asarray(key_poses, dtype=np.float64)
    if len(keys) == 1 or count == 1:
        return np.repeat(keys[:1], count, axis=0)
    s = np.linspace(0.0, len(keys) - 1.0, count)
    lo = np.clip(np.floor(s).astype(np.int64), 0, len(keys) - 2)
    out = interpolate_poses(keys[lo], keys[lo + 1], s - lo)
    out[:, :3, 3] = catmull_rom(keys[:, :3, 3], s)
    return out


def path_keys(poses: np.ndarray, keys: int) -> np.ndarray:
    """At most ``keys`` poses (≤ keys, 4, 4) of a path ``poses`` (T, 4, 4) in time order, spread evenly over
    its steps, the first and the last included; a pose held over consecutive steps counts once."""
    poses = np.asarray(poses, dtype=np.float64)
    moved = np.concatenate([[True], (poses[1:] != poses[:-1]).any(axis=(1, 2))])
    distinct = poses[moved]
    picked = np.unique(np.round(np.linspace(0, len(distinct) - 1, min(keys, len(distinct)))).astype(np.int64))
    return distinct[picked]

"""Camera pose maths on camera-to-world 4×4 matrices (OpenGL camera axes: +X right, +Y up, looking down −Z;
world +Z up): a pose looking from a point at another, rotation matrices ↔ unit quaternions, slerp, and poses
interpolated between two (slerp rotation, lerp position) or at a fractional index into a path.
"""

from __future__ import annotations

import numpy as np

from spikenerf.core.errors import InputError


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """Camera-to-world (4, 4) looking from ``eye`` at ``target`` (OpenGL axes, world +Z up).

    Args:
        eye: (3,) camera centre. target: (3,) point seen at the image centre. up: (3,) world up.
    Raises:
        InputError: naming ``eye``, ``target`` or ``up`` when one is not 3 finite numbers, or the pose
            they give is not finite (coordinates beyond float64's reach).
    """
    points = [as_point(eye, "eye"), as_point(target, "target")]
    with np.errstate(all="ignore"):  # (an overflow gives a pose that is not finite: named below)
        c2w = look_at_unchecked(*points, None if up is None else as_point(up, "up"))
    if not np.isfinite(c2w).all():
        raise InputError(
            f"look_at: eye {points[0].tolist()} and target {points[1].tolist()} give a pose that is not "
            "finite (coordinates too large)",
            param=("eye", "target"),
        )
    return c2w


def as_point(value: object, param: str) -> np.ndarray:
    """``value`` as a float64 (3,) of finite numbers; InputError naming ``param`` otherwise."""
    try:
        point = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        point = np.zeros(0)
    if point.shape != (3,) or not np.isfinite(point).all():
        raise InputError(f"{param} must be 3 finite numbers (x, y, z), found {value!r:.80}", param=param)
    return point


def look_at_unchecked(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """:func:`look_at` of checked float64 (3,) points, unchecked (orbit and novel_views check once)."""
    up = np.array([0.0, 0.0, 1.0]) if up is None else up
    back = eye - target
    norm = np.linalg.norm(back)
    if norm == 0:
        raise InputError("look_at: eye and target coincide", param=("eye", "target"))
    back /= norm
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-9:  # looking straight along the up axis
        right = np.cross(np.array([0.0, 1.0, 0.0]), back)
    right /= np.linalg.norm(right)
    cam_up = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, cam_up, back, eye
    return c2w


def matrix_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) → unit quaternions (..., 4) as (w, x, y, z) with w ≥ 0."""
    m = np.asarray(rot, dtype=np.float64)
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    # candidate i is 4·q_i·q; use the one with the largest |q_i| for numerical stability
    cands = np.stack(
        [
            np.stack([1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01], -1),
            np.stack([m21 - m12, 1 + m00 - m11 - m22, m10 + m01, m02 + m20], -1),
            np.stack([m02 - m20, m10 + m01, 1 - m00 + m11 - m22, m21 + m12], -1),
            np.stack([m10 - m01, m02 + m20, m21 + m12, 1 - m00 - m11 + m22], -1),
        ],
        -2,
    )
    diag = np.stack([cands[..., i, i] for i in range(4)], -1)
    best = np.take_along_axis(cands, diag.argmax(-1)[..., None, None], axis=-2)[..., 0, :]
    q = best / np.linalg.norm(best, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def quaternion_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) as (w, x, y, z) → rotation matrices (..., 3, 3)."""
    q = np.asarray(quat, dtype=np.float64)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (..., 4) along the shorter arc; ``t`` in [0, 1]."""
    q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.clip(np.abs(dot), 0.0, 1.0)
    theta = np.arccos(dot)
    sin = np.sin(theta)
    near = sin < 1e-6  # (almost) the same rotation: normalised lerp is exact enough
    safe = np.where(near, 1.0, sin)
    w0 = np.where(near, 1 - t, np.sin((1 - t) * theta) / safe)
    w1 = np.where(near, t, np.sin(t * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def interpolate_poses(p0: np.ndarray, p1: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """Camera-to-world poses (..., 4, 4) between ``p0`` and ``p1``: slerp rotation, lerp translation.

    ``t = 0`` returns ``p0`` and ``t = 1`` returns ``p1`` exactly.
    """
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    out = np.zeros(np.broadcast_shapes(p0.shape, p1.shape, (*t.shape, 4, 4)))
    rot = quaternion_to_matrix(
        slerp(matrix_to_quaternion(p0[..., :3, :3]), matrix_to_quaternion(p1[..., :3, :3]), t)
    )
    out[..., :3, :3] = rot
    out[..., :3, 3] = (1 - t[..., None]) * p0[..., :3, 3] + t[..., None] * p1[..., :3, 3]
    out[..., 3, 3] = 1.0
    tt = t[..., None, None]
    return np.where(tt == 0, p0, np.where(tt == 1, p1, out))


def pose_at(poses: np.ndarray, position: float) -> np.ndarray:
    """The pose (4, 4) at a fractional index into ``poses`` (N, 4, 4) (slerp between the two neighbours)."""
    i0 = int(np.clip(np.floor(position), 0, len(poses) - 1))
    i1 = min(i0 + 1, len(poses) - 1)
    return interpolate_poses(poses[i0], poses[i1], float(np.clip(position - i0, 0.0, 1.0)))

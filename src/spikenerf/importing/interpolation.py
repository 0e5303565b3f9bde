"""Keyframe poses over time: per-step slerp/lerp interpolation between keyframes (with the keyframe pair
around each step, which ``train``'s pose refinement reads too), the steps that get a held pose, and the
smoothing of keyframe poses along time."""

from __future__ import annotations

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.scenes.poses import interpolate_poses


def per_step_poses(key_poses: np.ndarray, key_steps: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Poses (T, 4, 4) at ``steps`` (T,) from keyframe poses (N, 4, 4) at ``key_steps`` (N,).

    Between two keyframes: slerp of the rotation, lerp of the position; before the first and after the last
    keyframe the motion of the nearest keyframe pair is extrapolated, for at most one keyframe interval
    (beyond that the pose is held).
    """
    order = np.argsort(key_steps)
    kp, ks = np.asarray(key_poses, np.float64)[order], np.asarray(key_steps, np.int64)[order]
    lo, hi, t = key_brackets(ks, steps)
    return interpolate_poses(kp[lo], kp[hi], np.clip(t, -1.0, 2.0))


def held_steps(key_steps: np.ndarray, n: int) -> tuple[int, int]:
    """How many of the steps ``0..n-1`` lie before (after) the keyframes at ``key_steps`` (N ≥ 2) by more
    than the one interval that :func:`per_step_poses` extrapolates: the steps that get a held pose, as if
    the camera stood still there. ``(first, last)``: steps ``0..first-1`` and ``n-last..n-1``."""
    ks = np.sort(np.asarray(key_steps, np.int64))
    before = int(ks[0] - (ks[1] - ks[0]))  # the first step still extrapolated
    after = int(ks[-1] + (ks[-1] - ks[-2]))  # the last one
    return min(max(before, 0), n), min(max(n - 1 - after, 0), n)


def key_brackets(key_steps: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The keyframe pair around each of ``steps`` (T,) among sorted ``key_steps`` (N,), N ≥ 2: indices
    ``lo``, ``hi`` (T,) and the fraction ``t`` (T,) of the way from ``lo`` to ``hi`` (below 0 before the
    first keyframe, above 1 after the last: the nearest pair is extrapolated)."""
    ks = np.asarray(key_steps, np.int64)
    if len(np.unique(ks)) != len(ks):
        raise InputError(f"two poses share one spike step (steps {ks.tolist()[:8]}...)")
    steps = np.asarray(steps, np.float64)
    hi = np.clip(np.searchsorted(ks, steps, side="right"), 1, len(ks) - 1)
    lo = hi - 1
    return lo, hi, (steps - ks[lo]) / (ks[hi] - ks[lo])


def smooth_poses(poses: np.ndarray, steps: np.ndarray, span: float) -> np.ndarray:
    """Keyframe poses (N, 4, 4) at spike ``steps`` (N,) smoothed along time by local quadratic regression.

    For each keyframe, its neighbours within ``span`` steps are expressed in the tangent space of its pose
    (rotation vectors of ``R_iᵀ R_j``, positions), a quadratic in time is fitted with tricube weights and
    evaluated at the keyframe (a Savitzky–Golay filter on SE(3) for irregular steps). A quadratic keeps
    constant-rate turns and circular paths unbiased (a plain average would shrink an orbit). A keyframe with
    fewer than four neighbours in its span is kept as it is. ``span`` ≤ 0 returns the poses unchanged.
    """
    from scipy.spatial.transform import Rotation

    poses = np.asarray(poses, np.float64)
    if span <= 0:
        return poses.copy()
    t = np.asarray(steps, np.float64)
    out = poses.copy()
    for i in range(len(poses)):
        near = np.flatnonzero(np.abs(t - t[i]) < span)
        if len(near) < 4:
            continue
        dt = (t[near] - t[i]) / span
        w = np.sqrt((1 - np.abs(dt) ** 3) ** 3)  # square root of tricube: weighted least squares rows
        design = np.stack([np.ones_like(dt), dt, dt**2], 1) * w[:, None]
        rel = np.einsum("ji,njk->nik", poses[i, :3, :3], poses[near, :3, :3])
        values = np.concatenate([Rotation.from_matrix(rel).as_rotvec(), poses[near, :3, 3]], 1) * w[:, None]
        coef = np.linalg.lstsq(design, values, rcond=None)[0][0]  # the fit at dt = 0
        out[i, :3, :3] = poses[i, :3, :3] @ Rotation.from_rotvec(coef[:3]).as_matrix()
        out[i, :3, 3] = coef[3:]
    return out

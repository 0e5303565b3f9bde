"""Estimated trajectories compared with the truth and with themselves: the similarity (Umeyama) alignment
used to score them (ATE, rotation), and the jump test that finds a folded keyframe trajectory."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity ``dst ≈ s · R @ src + t`` of least squares (Umeyama 1991) for points (N, 3).

    Returns:
        ``(s, R (3, 3), t (3,))``.
    """
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    rot = u @ sign @ vt
    var = (xs**2).sum() / len(src)
    s = float(np.trace(np.diag(d) @ sign) / var) if var > 0 else 1.0
    return s, rot, mu_d - s * rot @ mu_s


def rotation_angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angle in degrees (N,) of the rotation between each pair of rotations ``a``, ``b`` (N, 3, 3)."""
    rel = np.einsum("nji,njk->nik", a, b)
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)))


@dataclass(frozen=True)
class Jump:
    """The worst jump of a keyframe trajectory: between steps ``a`` and ``b`` the camera turns ``turn_deg``
    and moves ``move`` (the trajectory's units); ``what`` (``"turn"`` or ``"move"``) went ``ratio`` times
    faster there than at the neighbouring keyframes."""

    a: int
    b: int
    turn_deg: float
    move: float
    what: str
    ratio: float

    def describe(self) -> str:
        amount = f"turns {self.turn_deg:.1f}°" if self.what == "turn" else f"moves {self.move:.3g}"
        return (
            f"jump between steps {self.a} and {self.b} (it {amount} there, {self.ratio:.0f}× as fast as at "
            "the neighbouring keyframes)"
        )


#: pairs on each side whose median rate a pair is compared with (:func:`trajectory_jump`)
JUMP_NEIGHBOURS = 5


def trajectory_jump(
    poses: np.ndarray, steps: np.ndarray, factor: float = 5.0, min_turn_deg: float = 10.0
) -> Jump | None:
    """The worst jump between consecutive keyframes (N, 4, 4) at ``steps`` (N,), or None when there is none.

    A spike camera records 20 000–40 000 steps a second, so the true motion between keyframes a few steps
    apart is smooth: it may start, stop or speed up, but not for a single pair. A pair is a jump when its
    rate (turn or move per step) is over ``factor`` times the median rate of the ``JUMP_NEIGHBOURS`` pairs
    on each side of it, and it also turns more than ``min_turn_deg`` (a turn) or moves more than a tenth
    of the cameras' mean distance from their centroid (a move). COLMAP models that fold (cameras that go
    round twice, or flip at a symmetric scene) show such jumps; see docs/real-data.md.
    """
    if len(poses) < 3:
        return None
    order = np.argsort(steps)
    p, s = poses[order], np.asarray(steps)[order].astype(np.float64)
    gap = np.maximum(np.diff(s), 1.0)
    turn = rotation_angles_deg(p[:-1, :3, :3], p[1:, :3, :3])
    move = np.linalg.norm(np.diff(p[:, :3, 3], axis=0), axis=1)
    spread = float(np.linalg.norm(p[:, :3, 3] - p[:, :3, 3].mean(0), axis=1).mean())
    worst: Jump | None = None
    for what, amount, floor in (("turn", turn, min_turn_deg), ("move", move, 0.1 * spread)):
        rate = amount / gap
        for i in np.flatnonzero(amount > floor):
            near = np.r_[rate[max(0, i - JUMP_NEIGHBOURS) : i], rate[i + 1 : i + 1 + JUMP_NEIGHBOURS]]
            typical = float(np.median(near))
            ratio = rate[i] / typical if typical > 0 else np.inf
            if ratio > factor and (worst is None or ratio > worst.ratio):
                worst = Jump(int(s[i]), int(s[i + 1]), float(turn[i]), float(move[i]), what, float(ratio))
    return worst


def trajectory_errors(estimated: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Errors of estimated poses (N, 4, 4) against the truth after similarity alignment of the positions.

    Returns:
        ``ate_rmse`` (position RMSE in the truth's units), ``ate_rel`` (ATE / the truth's mean distance from
        its centroid), ``rot_mean_deg`` and ``rot_max_deg`` (the angle of each aligned rotation error).
    """
    s, rot, t = umeyama(estimated[:, :3, 3], truth[:, :3, 3])
    aligned = (s * (rot @ estimated[:, :3, 3].T)).T + t
    err = np.linalg.norm(aligned - truth[:, :3, 3], axis=1)
    spread = float(np.linalg.norm(truth[:, :3, 3] - truth[:, :3, 3].mean(0), axis=1).mean())
    angle = rotation_angles_deg(truth[:, :3, :3], rot @ estimated[:, :3, :3])
    ate = float(np.sqrt((err**2).mean()))
    return {
        "ate_rmse": ate,
        "ate_rel": ate / spread if spread > 0 else float("nan"),
        "rot_mean_deg": float(angle.mean()),
        "rot_max_deg": float(angle.max()),
    }

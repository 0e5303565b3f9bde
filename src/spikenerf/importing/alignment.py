"""Pose geometry for imported recordings: per-step interpolation, unit-box normalisation, near/far from
sparse points, and the similarity (Umeyama) alignment used to score estimated trajectories (ATE, rotation)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, get_args

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


#: the sparse points' percentiles that bound the scene box (per axis, in the oriented frame)
BOX_PERCENTILES = (2.0, 98.0)
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
        ``box``; ``none``: not turned). plane_score: :func:`plane_turn`'s score (0: not computed).
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
    ``orient`` (one of :data:`ORIENTS`) ``up`` or ``up-box``, the frame is first turned upright and about
    +Z (:func:`upright`, turn ``planes`` or ``box``): a COLMAP model's axes are arbitrary, and an
    axis-aligned box in them clips the scene. ``focus`` (3,): the point every camera looks at, where the
    source knows it (an orbit's centre); the frustum box is then sized around it whatever the lens, while
    for cameras alone a box under :data:`MIN_FRUSTUM_SHARE` of their spread is refused (axes that meet
    near a camera, or a lens too narrow for the path: no sure focus).
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

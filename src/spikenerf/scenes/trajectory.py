"""Camera trajectories and intrinsics in the NeRF "Blender" convention.

Poses are camera-to-world 4×4 matrices with OpenGL camera axes (+X right, +Y up, looking down −Z) in a world
whose +Z is up. Spike step k happens at time ``t_k = k / fps``.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np

from spikenerf.core.errors import InputError, is_finite, is_integer, is_number
from spikenerf.core.limits import check_memory
from spikenerf.scenes.distortion import Distortion, checked


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; rays go through pixel centres ``(u + 0.5, v + 0.5)``; ``distortion``:
    the lens (:mod:`spikenerf.scenes.distortion`), None for a pinhole (as is a lens whose terms are zero).

    Raises:
        InputError: naming the field when ``width``/``height`` is not an integer ≥ 1, a focal length not a
            finite number > 0, or ``cx``/``cy`` not finite (a NaN focal length rendered a white image), and
            ``distortion`` when the lens is not invertible over the image (``distortion.checked``).
    """

    width: int
    height: int
    fl_x: float
    fl_y: float
    cx: float
    cy: float
    distortion: Distortion | None = None

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if not is_integer(value) or value < 1:
                raise InputError(f"{name} must be an integer ≥ 1 (pixels), found {value!r}", param=name)
        for name in ("fl_x", "fl_y", "cx", "cy"):
            value = getattr(self, name)
            focal = name.startswith("fl")
            if not is_finite(value) or (focal and value <= 0):
                what = "a finite number > 0 (pixels)" if focal else "a finite number (pixels)"
                raise InputError(f"{name} must be {what}, found {value!r}", param=name)
        object.__setattr__(self, "distortion", checked(self.distortion, self))

    @classmethod
    def from_fov(cls, width: int, height: int, camera_angle_x: float) -> Intrinsics:
        """Square pixels from the horizontal field of view ``camera_angle_x`` (radians)."""
        focal = 0.5 * width / math.tan(0.5 * camera_angle_x)
        return cls(width, height, focal, focal, width / 2.0, height / 2.0)

    @property
    def camera_angle_x(self) -> float:
        """Horizontal field of view in radians."""
        return 2.0 * math.atan(0.5 * self.width / self.fl_x)

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera resampled to ``width × height`` pixels."""
        sx, sy = width / self.width, height / self.height
        k = (self.fl_x * sx, self.fl_y * sy, self.cx * sx, self.cy * sy)
        return Intrinsics(width, height, *k, self.distortion)  # (the lens: in normalised units, size-free)

    def matrix(self) -> np.ndarray:
        """(3, 3) K matrix."""
        return np.array([[self.fl_x, 0, self.cx], [0, self.fl_y, self.cy], [0, 0, 1]], dtype=np.float64)


@dataclass(frozen=True)
class Trajectory:
    """Per-step camera poses along a path.

    Attributes:
        poses: (N, 4, 4) float64 camera-to-world.
        times: (N,) float64 seconds, ``steps / fps``.
        steps: (N,) int64 spike-step indices.
        fps: readout rate in Hz (40 kHz for a spike camera).
    """

    poses: np.ndarray
    times: np.ndarray
    steps: np.ndarray
    fps: float

    def __len__(self) -> int:
        return len(self.steps)

    def __getitem__(self, index: slice | np.ndarray) -> Trajectory:
        return Trajectory(self.poses[index], self.times[index], self.steps[index], self.fps)


def check_trajectory(trajectory: Trajectory, param: str = "trajectory") -> None:
    """InputError naming ``param`` unless ``trajectory`` is a :class:`Trajectory` whose poses (N, 4, 4),
    times (N,) and steps (N,) agree in N ≥ 1, whose steps are increasing integers and whose ``fps`` is a
    finite number > 0: what a dataset's ``transforms.json`` must hold (a hand-made one simulated, then the
    loader refused the dataset, or the writer failed after every frame was rendered). The poses' rigidity
    is :func:`spikenerf.scenes.transforms.rigid_poses`'s."""
    if not isinstance(trajectory, Trajectory):
        found = f"{trajectory!r:.60}"
        raise InputError(f"{param} must be a Trajectory (e.g. orbit(...)), found {found}", param=param)
    poses, times, steps = (np.asarray(getattr(trajectory, k)) for k in ("poses", "times", "steps"))
    n = len(steps) if steps.ndim == 1 else -1
    if n < 1 or poses.shape != (n, 4, 4) or times.shape != (n,):
        raise InputError(
            f"{param}: poses {poses.shape}, times {times.shape} and steps {steps.shape} must be (N, 4, 4), "
            "(N,) and (N,) with N ≥ 1",
            param=param,
        )
    if steps.dtype.kind not in "iu" or (n > 1 and not (np.diff(steps) > 0).all()):
        raise InputError(f"{param}: steps must be increasing integers, found {steps[:4]!r:.80}", param=param)
    if not is_finite(trajectory.fps) or trajectory.fps <= 0 or not np.isfinite(times).all():
        raise InputError(
            f"{param}: fps must be a finite number > 0 and times finite, found fps {trajectory.fps!r}",
            param=param,
        )
    if n > 1 and not (np.diff(times) > 0).all():  # (the loader refuses a dataset whose times do not increase)
        raise InputError(f"{param}: times must increase, found {times[:4]!r:.80}", param=param)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """Camera-to-world (4, 4) looking from ``eye`` at ``target`` (OpenGL axes, world +Z up).

    Args:
        eye: (3,) camera centre. target: (3,) point seen at the image centre. up: (3,) world up.
    Raises:
        InputError: naming ``eye``, ``target`` or ``up`` when one is not 3 finite numbers, or the pose
            they give is not finite (coordinates beyond float64's reach).
    """
    points = [_point(eye, "eye"), _point(target, "target")]
    with np.errstate(all="ignore"):  # (an overflow gives a pose that is not finite: named below)
        c2w = _look_at(*points, None if up is None else _point(up, "up"))
    if not np.isfinite(c2w).all():
        raise InputError(
            f"look_at: eye {points[0].tolist()} and target {points[1].tolist()} give a pose that is not "
            "finite (coordinates too large)",
            param=("eye", "target"),
        )
    return c2w


def _point(value: object, param: str) -> np.ndarray:
    """``value`` as a float64 (3,) of finite numbers; InputError naming ``param`` otherwise."""
    try:
        point = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        point = np.zeros(0)
    if point.shape != (3,) or not np.isfinite(point).all():
        raise InputError(f"{param} must be 3 finite numbers (x, y, z), found {value!r:.80}", param=param)
    return point


def _look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
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


#: the most turns an orbit may make (a bound far above any camera path, well inside float precision)
MAX_TURNS = 1e6
#: the range of an orbit's radius (scene units): beyond it the camera positions lose their precision or
#: overflow (``import --orbit`` and ``simulate --radius`` take the same range; a Blender scene in
#: millimetres or georeferenced coordinates reaches 1e6 and more)
ORBIT_RADIUS = (1e-6, 1e9)
#: the largest coordinate of a centre and the largest jitter or shake (scene units), as the radius
MAX_LENGTH = ORBIT_RADIUS[1]
#: the largest start or offset azimuth (degrees, either sign): beyond it the turns between steps are lost to
#: rounding
MAX_AZIMUTH = 1e6
#: the largest elevation sweep (degrees peak to peak, either sign): a full circle
MAX_SWEEP = 360.0
#: the most steps a path may have (far above what any machine holds; :data:`ORBIT_STEP_BYTES` each)
MAX_STEPS = 2**40
#: memory an orbit needs per step while it is built (bytes; ~660 measured, with room)
ORBIT_STEP_BYTES = 1024


def orbit_angle_problem(elevation_deg: float, turns: float) -> str | None:
    """What is wrong with an orbit's elevation (degrees, within [−90, 90]) and turns (|turns| ≤
    :data:`MAX_TURNS`), in words naming ``elevation`` or ``turns``; None when both are fine."""
    if not abs(elevation_deg) <= 90:
        return f"elevation must lie within [-90, 90] degrees, found {elevation_deg:g}"
    if not abs(turns) <= MAX_TURNS:
        return f"turns must lie within ±{MAX_TURNS:g}, found {turns:g}"
    return None


def _number(value: object, param: str, limit: float, what: str = "", low: float | None = None) -> float:
    """``value`` as a float within [``low``, ``limit``] (``low`` None: within ±``limit``); InputError naming
    ``param`` otherwise (``what`` names the unit in the message, e.g. ``" degrees"``)."""
    number = is_number(value)
    lo = -limit if low is None else low
    if not number or not lo <= value <= limit:  # (NaN fails too)
        bounds = f"±{limit:g}" if low is None else f"[{low:g}, {limit:g}]"
        raise InputError(f"{param} must be finite and within {bounds}{what}, found {value!r}", param=param)
    return float(value)  # type: ignore[arg-type]


def _center(center: object) -> np.ndarray:
    """``center`` as a float64 (3,) with each coordinate within ±:data:`MAX_LENGTH`; else InputError."""
    c = _point(center, "center")
    if not (np.abs(c) <= MAX_LENGTH).all():
        raise InputError(
            f"center must lie within ±{MAX_LENGTH:g} scene units on each axis, found {c.tolist()}",
            param="center",
        )
    return c


def path_steps(duration: float, fps: float) -> int:
    """``round(duration · fps)``, the steps of a path: InputError naming ``duration``/``fps`` when either is
    not a finite number > 0, there is not one step, more than :data:`MAX_STEPS`, or more than the memory at
    hand holds (:data:`ORBIT_STEP_BYTES` a step; ``core.limits``, skipped under ``no_limits``)."""
    for name, value in (("duration", duration), ("fps", fps)):
        number = is_number(value)
        if not number or not 0 < value < math.inf:
            raise InputError(f"orbit: {name} must be finite and > 0, got {value!r}", param=name)
    try:  # as floats: numpy integers wrap around, a huge Python int does not fit a float
        duration, fps = float(duration), float(fps)
    except OverflowError:
        raise InputError(
            "orbit: duration and fps must be finite numbers", param=("duration", "fps")
        ) from None
    total = duration * fps
    if not total < MAX_STEPS:
        raise InputError(
            f"orbit: duration × fps must give at most {MAX_STEPS:.3g} steps, got {duration:g} s × {fps:g} Hz "
            f"= {total:.3g} steps",
            param=("duration", "fps"),
        )
    n = round(total)
    if n < 1:
        raise InputError(
            f"orbit: duration × fps must give at least 1 step, got {duration:g} s × {fps:g} Hz = {n} steps",
            param=("duration", "fps"),
        )
    check_memory(n * ORBIT_STEP_BYTES, "duration/fps")
    return n


def orbit(
    radius: float,
    elevation_deg: float,
    turns: float = 1.0,
    duration: float = 0.025,
    fps: float = 40000.0,
    center: tuple[float, float, float] = (0.0, 0.0, 0.0),
    start_azimuth_deg: float = 0.0,
    elevation_sweep_deg: float = 0.0,
    jitter: float = 0.0,
    seed: int = 0,
    shake: float = 0.0,
    shake_cycles: int = 8,
) -> Trajectory:
    """A circular orbit around ``center``, looking at it: ``round(duration · fps)`` steps.

    Args:
        radius: distance from the centre (scene units, within :data:`ORBIT_RADIUS`).
        elevation_deg: elevation above the XY plane, within [−90, 90] (±90: every step at the pole).
        turns: full 360° turns over the duration (|turns| ≤ :data:`MAX_TURNS`). duration: seconds.
        fps: steps per second (at most :data:`MAX_STEPS` steps, and as many as the memory holds).
        elevation_sweep_deg: peak-to-peak sinusoidal elevation change over the path (0 = flat orbit;
            |sweep| ≤ :data:`MAX_SWEEP`).
        center: the point looked at (each coordinate within ±:data:`MAX_LENGTH`).
        start_azimuth_deg: azimuth of step 0 (within ±:data:`MAX_AZIMUTH`).
        jitter: standard deviation of a smooth random position offset (scene units, 0 to :data:`MAX_LENGTH`),
            seeded by ``seed`` (an integer ≥ 0).
        shake: amplitude (scene units, within ±:data:`MAX_LENGTH`) of a look-at point circling ``center``
            ``shake_cycles`` times (|cycles| ≤ :data:`MAX_TURNS`) over the path (and bobbing twice as fast):
            a fast hand-shake-like rotation of the camera (0 = none).
    Returns:
        A :class:`Trajectory` whose step ``k`` is at azimuth ``start + 360° · turns · k / N``.
    Raises:
        InputError: naming the parameter that is not a finite number in its range, or the pose that is not
            finite.
    """
    radius = _number(radius, "radius", ORBIT_RADIUS[1], " scene units", low=ORBIT_RADIUS[0])
    for name, value in (("elevation_deg", elevation_deg), ("turns", turns)):  # (range: orbit_angle_problem)
        if not is_number(value):
            raise InputError(f"orbit: {name} must be a number, found {value!r}", param=name)
    start_azimuth_deg = _number(start_azimuth_deg, "start_azimuth_deg", MAX_AZIMUTH, " degrees")
    elevation_sweep_deg = _number(elevation_sweep_deg, "elevation_sweep_deg", MAX_SWEEP, " degrees")
    jitter = _number(jitter, "jitter", MAX_LENGTH, " scene units", low=0.0)
    shake = _number(shake, "shake", MAX_LENGTH, " scene units")
    shake_cycles = _number(shake_cycles, "shake_cycles", MAX_TURNS)
    if not is_integer(seed) or seed < 0:
        raise InputError(f"seed must be an integer ≥ 0, got {seed!r}", param="seed")
    c = _center(center)
    if problem := orbit_angle_problem(elevation_deg, turns):  # named as this function's parameters
        param = "turns" if problem.startswith("turns") else "elevation_deg"
        raise InputError(f"orbit: {param} {problem.partition(' ')[2]}", param=param)
    n = path_steps(duration, fps)
    steps = np.arange(n, dtype=np.int64)
    frac = steps / n
    azimuth = np.deg2rad(start_azimuth_deg) + 2 * np.pi * turns * frac
    elevation = np.deg2rad(elevation_deg + 0.5 * elevation_sweep_deg * np.sin(2 * np.pi * frac))
    eyes = c + radius * np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=-1
    )
    if jitter > 0:
        rng = np.random.default_rng(seed)
        knots = rng.normal(0.0, jitter, size=(8, 3))
        t = frac * (len(knots) - 1)
        eyes = eyes + np.stack([np.interp(t, np.arange(len(knots)), knots[:, i]) for i in range(3)], -1)
    ph = 2 * np.pi * shake_cycles * frac
    targets = c + shake * np.stack([np.sin(ph), np.cos(ph), np.sin(2 * ph)], -1)
    poses = np.stack([_look_at(e, t) for e, t in zip(eyes, targets, strict=True)])
    if not np.isfinite(poses).all():  # (the ranges above keep them finite: a guard, one pass)
        raise InputError(
            "orbit: the poses are not finite; lower radius, center, jitter or shake",
            param=("radius", "center", "jitter", "shake"),
        )
    return Trajectory(poses, steps / fps, steps, float(fps))


#: degrees between the held-out views and the training path's elevations (:func:`held_out_elevations`)
HELD_OUT_MARGIN = 15.0
#: the held-out views stay this far (degrees) from the poles, where ``look_at`` turns its up axis
POLE_MARGIN = 1.0


def held_out_elevations(
    elevation_deg: float, sweep_deg: float = 0.0, margin_deg: float = HELD_OUT_MARGIN
) -> tuple[float, float]:
    """The two elevations (degrees) that :func:`novel_views` cycles through for an orbit at
    ``elevation_deg`` sweeping ``sweep_deg`` peak to peak: ``margin_deg`` below and above the path's range
    (15° and 45° for a flat orbit at 30°). Where one side has no room (within :data:`POLE_MARGIN` of a
    pole), both lie on the other side, ``margin_deg`` and ``2·margin_deg`` from the path.

    Raises:
        InputError: neither side has room (the path spans almost every elevation).
    """
    lo, hi, limit = elevation_deg - sweep_deg / 2, elevation_deg + sweep_deg / 2, 90.0 - POLE_MARGIN
    below, above = lo - margin_deg, hi + margin_deg
    if above > limit:
        above = lo - 2 * margin_deg
    if below < -limit:
        below = hi + 2 * margin_deg
    if not (-limit <= below <= limit and -limit <= above <= limit):
        raise InputError(
            f"no room for held-out views {margin_deg:g}° off an orbit at elevation {elevation_deg:g}° "
            f"sweeping {sweep_deg:g}°",
            param="elevation",
        )
    return below, above


def novel_views(
    radius: float,
    count: int,
    elevations_deg: tuple[float, ...] = (15.0, 45.0),
    center: tuple[float, float, float] = (0.0, 0.0, 0.0),
    azimuth_offset_deg: float = 17.0,
) -> np.ndarray:
    """Held-out poses off the training orbit: ``count`` views spread over azimuth, cycling elevations.

    Args:
        radius: distance from ``center`` (within :data:`ORBIT_RADIUS`). count: an integer ≥ 0.
        elevations_deg: one or more elevations within [−90, 90] degrees.
        center: the point looked at (each coordinate within ±:data:`MAX_LENGTH`).
        azimuth_offset_deg: azimuth of the first view (within ±:data:`MAX_AZIMUTH`).
    Returns:
        (count, 4, 4) float64 camera-to-world poses looking at ``center``.
    Raises:
        InputError: naming the parameter that is not a finite number in its range.
    """
    radius = _number(radius, "radius", ORBIT_RADIUS[1], " scene units", low=ORBIT_RADIUS[0])
    if not is_integer(count) or count < 0:
        raise InputError(f"count must be an integer ≥ 0, found {count!r}", param="count")
    azimuth_offset_deg = _number(azimuth_offset_deg, "azimuth_offset_deg", MAX_AZIMUTH, " degrees")
    try:
        elevations = [float(e) for e in elevations_deg]
    except (TypeError, ValueError):
        elevations = []
    if not elevations or not all(abs(e) <= 90 for e in elevations):  # (NaN fails too)
        raise InputError(
            f"elevations_deg must be one or more finite elevations within [-90, 90] degrees, found "
            f"{elevations_deg!r:.80}",
            param="elevations_deg",
        )
    c = _center(center)
    poses = []
    for i in range(count):
        az = np.deg2rad(azimuth_offset_deg + 360.0 * i / max(count, 1))
        el = np.deg2rad(elevations[i % len(elevations)])
        eye = c + radius * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        poses.append(_look_at(eye, c))
    return np.stack(poses) if poses else np.zeros((0, 4, 4))


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
    return np.stack([_look_at(eye, focus, up) for eye in eyes]) if count else np.zeros((0, 4, 4))


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


def project_points(c2w, points, intrinsics: Intrinsics):  # type: ignore[no-untyped-def]
    """Image coordinates of world ``points`` (..., 3) in cameras ``c2w`` (..., 4, 4) (OpenGL axes; both numpy
    arrays or both torch tensors, broadcast): (u, v, depth), each (...). Pixel ``(x, y)`` covers
    ``[x, x + 1) × [y, y + 1)`` (its centre is ``x + 0.5``, as :func:`spikenerf.data.rays.camera_directions`
    casts it), through the lens of a distorted camera; depth > 0 in front of the camera, where u and v are
    meaningful. Torch tensors are projected with autocast off (under ``--amp bf16`` a third of the points
    would land in another pixel)."""
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
        intrinsics: the pinhole camera. box: (2, 3) scene box min/max corners.
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

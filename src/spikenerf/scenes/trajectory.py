"""Camera trajectories and intrinsics in the NeRF "Blender" convention, and the paths a simulation films:
the :class:`Intrinsics` and :class:`Trajectory` types, the orbit (its ranges, :func:`path_steps`) and the
held-out views off it (:func:`held_out_elevations`, :func:`novel_views`).

Poses are camera-to-world 4×4 matrices with OpenGL camera axes (+X right, +Y up, looking down −Z) in a world
whose +Z is up. Spike step k happens at time ``t_k = k / fps``. The pose maths (``look_at``, slerp, pose
interpolation) is :mod:`spikenerf.scenes.poses`; the render paths, :mod:`spikenerf.scenes.render_paths`;
projecting points into an image, :mod:`spikenerf.scenes.projection`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spikenerf.core.errors import InputError, is_finite, is_integer, is_number
from spikenerf.core.limits import check_memory
from spikenerf.scenes.distortion import Distortion, checked
from spikenerf.scenes.poses import as_point, look_at_unchecked


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
        """Square pixels from the horizontal field of view ``camera_angle_x`` (radians, in (0, π)).

        Raises:
            InputError: naming ``camera_angle_x`` outside (0, π) (0 was a ZeroDivisionError, π a focal
                length of 5e-16), or ``width``/``height`` as the constructor does.
        """
        if not (is_finite(camera_angle_x) and 0 < camera_angle_x < math.pi):
            raise InputError(
                f"camera_angle_x must be a field of view in (0, π) radians, found {camera_angle_x!r}",
                param="camera_angle_x",
            )
        focal = 0.5 * width / math.tan(0.5 * camera_angle_x) if is_number(width) else 1.0  # (width: below)
        return cls(width, height, focal, focal, width / 2.0, height / 2.0)

    @property
    def camera_angle_x(self) -> float:
        """Horizontal field of view in radians of the pinhole (the lens left out: the ``transforms.json`` key
        that, with the width, gives ``fl_x``)."""
        return 2.0 * math.atan(0.5 * self.width / self.fl_x)

    @property
    def view_angle_x(self) -> float:
        """Horizontal field of view in radians that the image sees through its lens: the angle between the
        rays through the middles of its left and right edges (:attr:`camera_angle_x` for a pinhole; wider
        for a barrel or fisheye lens)."""
        if self.distortion is None:
            return self.camera_angle_x
        x, y = self.distortion.undistort(np.array([-self.cx, self.width - self.cx]) / self.fl_x, np.zeros(2))
        rays = np.stack([x, y, np.ones(2)], axis=-1)  # (2, 3) left, right
        cos = float(rays[0] @ rays[1]) / float(np.prod(np.linalg.norm(rays, axis=-1)))
        return math.acos(min(1.0, max(-1.0, cos)))

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
    c = as_point(center, "center")
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
    poses = np.stack([look_at_unchecked(e, t) for e, t in zip(eyes, targets, strict=True)])
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
        poses.append(look_at_unchecked(eye, c))
    return np.stack(poses) if poses else np.zeros((0, 4, 4))

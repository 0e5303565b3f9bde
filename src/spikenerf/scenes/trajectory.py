"""Camera trajectories and intrinsics in the NeRF "Blender" convention.

Poses are camera-to-world 4×4 matrices with OpenGL camera axes (+X right, +Y up, looking down −Z) in a world
whose +Z is up. Spike step k happens at time ``t_k = k / fps``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spikenerf.core.errors import InputError


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; rays go through pixel centres ``(u + 0.5, v + 0.5)``."""

    width: int
    height: int
    fl_x: float
    fl_y: float
    cx: float
    cy: float

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
        return Intrinsics(width, height, self.fl_x * sx, self.fl_y * sy, self.cx * sx, self.cy * sy)

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


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """Camera-to-world (4, 4) looking from ``eye`` at ``target`` (OpenGL axes, world +Z up).

    Args:
        eye: (3,) camera centre. target: (3,) point seen at the image centre. up: (3,) world up.
    """
    eye = np.asarray(eye, dtype=np.float64)
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    back = eye - np.asarray(target, dtype=np.float64)
    norm = np.linalg.norm(back)
    if norm == 0:
        raise InputError("look_at: eye and target coincide")
    back /= norm
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-9:  # looking straight along the up axis
        right = np.cross(np.array([0.0, 1.0, 0.0]), back)
    right /= np.linalg.norm(right)
    cam_up = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, cam_up, back, eye
    return c2w


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
) -> Trajectory:
    """A circular orbit around ``center``, looking at it: ``round(duration · fps)`` steps.

    Args:
        radius: distance from the centre (scene units). elevation_deg: elevation above the XY plane.
        turns: full 360° turns over the duration. duration: seconds. fps: steps per second.
        elevation_sweep_deg: peak-to-peak sinusoidal elevation change over the path (0 = flat orbit).
        jitter: standard deviation of a smooth random position offset (scene units), seeded.
    Returns:
        A :class:`Trajectory` whose step ``k`` is at azimuth ``start + 360° · turns · k / N``.
    """
    n = round(duration * fps)
    if n < 1 or radius <= 0 or fps <= 0:
        raise InputError(f"orbit: need radius > 0 and duration·fps ≥ 1, got radius={radius}, steps={n}")
    steps = np.arange(n, dtype=np.int64)
    frac = steps / n
    azimuth = np.deg2rad(start_azimuth_deg) + 2 * np.pi * turns * frac
    elevation = np.deg2rad(elevation_deg + 0.5 * elevation_sweep_deg * np.sin(2 * np.pi * frac))
    c = np.asarray(center, dtype=np.float64)
    eyes = c + radius * np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=-1
    )
    if jitter > 0:
        rng = np.random.default_rng(seed)
        knots = rng.normal(0.0, jitter, size=(8, 3))
        t = frac * (len(knots) - 1)
        eyes = eyes + np.stack([np.interp(t, np.arange(len(knots)), knots[:, i]) for i in range(3)], -1)
    poses = np.stack([look_at(e, c) for e in eyes])
    return Trajectory(poses, steps / fps, steps, float(fps))


def novel_views(
    radius: float,
    count: int,
    elevations_deg: tuple[float, ...] = (15.0, 45.0),
    center: tuple[float, float, float] = (0.0, 0.0, 0.0),
    azimuth_offset_deg: float = 17.0,
) -> np.ndarray:
    """Held-out poses off the training orbit: ``count`` views spread over azimuth, cycling elevations.

    Returns:
        (count, 4, 4) float64 camera-to-world poses looking at ``center``.
    """
    c = np.asarray(center, dtype=np.float64)
    poses = []
    for i in range(count):
        az = np.deg2rad(azimuth_offset_deg + 360.0 * i / max(count, 1))
        el = np.deg2rad(elevations_deg[i % len(elevations_deg)])
        eye = c + radius * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        poses.append(look_at(eye, c))
    return np.stack(poses) if poses else np.zeros((0, 4, 4))

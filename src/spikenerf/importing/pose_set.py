"""What every pose source of an imported recording gives (:class:`PoseSet`: camera-to-world poses in our
convention, OpenGL camera axes, see scenes/trajectory.py, with the spike steps they belong to when the source
says so) and the checks its readers share."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.scenes import transforms
from spikenerf.scenes.distortion import Distortion
from spikenerf.scenes.trajectory import Intrinsics


@dataclass(frozen=True)
class PoseSet:
    """Poses (N, 4, 4) float64 c2w; steps (N,) int64 spike steps or None (spread evenly later);
    intrinsics if the source knows them (at its own image size); points (M, 3) sparse scene points or None;
    scene_box (2, 3) if the source states one; names (N,) of the frames (for messages); camera_angle_x
    (radians) when the source gives only a field of view; depth_bounds (near, far) along the optical axes
    in the source's units (LLFF); note: how the poses were found when it matters (stored in config.yaml);
    focus (3,): the point every camera looks at when the source knows it (an orbit's centre); lens: the
    lens distortion of a source without full intrinsics (a field of view and ``k1``…); steps_named: the
    steps are the numbers ending the frames' names (not ``step`` fields), for messages."""

    poses: np.ndarray
    steps: np.ndarray | None = None
    intrinsics: Intrinsics | None = None
    points: np.ndarray | None = None
    scene_box: np.ndarray | None = None
    names: tuple[str, ...] = ()
    camera_angle_x: float | None = None
    depth_bounds: tuple[float, float] | None = None
    note: str = ""
    focus: np.ndarray | None = None
    lens: Distortion | None = None
    steps_named: bool = False


#: coordinates at or beyond this are absurd (NaN-free, but the unit-box fit of 1e308 overflows to inf)
FAR_LIMIT = 1e12


def check_poses(poses: np.ndarray, path: str | Path | None, minimum: int = 2) -> np.ndarray:
    """Poses as float64 (N, 4, 4); InputError on NaN/inf, a singular rotation or fewer than ``minimum``."""
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise InputError(f"expected (N, 4, 4) poses, found shape {poses.shape}", path=path)
    if not np.isfinite(poses).all():
        bad = int((~np.isfinite(poses)).any(axis=(1, 2)).sum())
        raise InputError(f"{bad} of {len(poses)} poses hold NaN or infinite values", path=path)
    if len(poses) < minimum:
        raise InputError(f"found {len(poses)} poses, need at least {minimum} to interpolate", path=path)
    if not (np.abs(poses[:, :3, 3]) < FAR_LIMIT).all():  # 1e308 overflowed the unit-box fit to inf
        raise InputError(f"poses hold absurdly distant camera positions (≥ {FAR_LIMIT:g})", path=path)
    off = transforms.rotation_error(poses[:, :3, :3])  # the dataset loader's own test
    if (off > transforms.ROTATION_TOL).any():
        i = int(np.argmax(off))
        raise InputError(f"pose {i} is not a rotation: scaled, sheared or mirrored", path=path)
    return poses


def steps_from_names(names: list[str], path: str | Path | None = None) -> np.ndarray | None:
    """Spike steps (N,) from N frame names when every name's stem ends in a number, else None; InputError
    (naming ``path``) when two names carry the same number (spreading their poses evenly would misplace
    them)."""
    found = [re.search(r"(\d+)$", Path(n).stem) for n in names]
    if not names or not all(found):
        return None
    steps = np.array([int(m.group(1)) for m in found if m], np.int64)
    _, first, counts = np.unique(steps, return_index=True, return_counts=True)
    if (counts > 1).any():
        i, j = np.flatnonzero(steps == steps[first[counts > 1][0]])[:2]
        raise InputError(f"{names[i]!r} and {names[j]!r} name the same step: each pose needs its own", path)
    return steps

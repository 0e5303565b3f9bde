"""Camera poses for a real recording: read from a pose file, or made from a known orbit (docs/real-data.md).

Every reader returns a :class:`~spikenerf.importing.pose_set.PoseSet` of camera-to-world poses in our
convention (OpenGL camera axes, see scenes/trajectory.py), with the spike steps they belong to when the file
says so. Supported: a nerfstudio / Blender ``transforms.json``, a COLMAP model folder (``cameras``,
``images``, ``points3D`` as ``.txt``, or ``.bin`` converted through pycolmap: ``colmap_model.py``), an LLFF
``poses_bounds.npy`` and an orbit (``--orbit``).
"""

from __future__ import annotations

import math
import tokenize
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.importing.colmap_model import read_colmap_model
from spikenerf.importing.pose_set import FAR_LIMIT, PoseSet, check_poses, steps_from_names
from spikenerf.scenes import transforms
from spikenerf.scenes.trajectory import (  # (the orbit's ranges: one definition, the library's)
    MAX_AZIMUTH,
    ORBIT_RADIUS,
    Intrinsics,
    orbit,
    orbit_angle_problem,
)


# ------------------------------------------------------------------------------------- transforms.json
def _step_of(frame: dict, i: int, path: Path) -> int:
    """``frame["step"]`` as an int: an integer, or a float with an integral value (``3.0``, as some JSON
    writers give it); InputError naming ``frames[i].step`` otherwise (a frame without one among frames with
    one, a fraction, a string, a step beyond 64 bits)."""
    if "step" not in frame:
        raise InputError(f"frames[{i}]: has no step while other frames give one", path=path)
    value = frame["step"]
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool):
        raise InputError(f"frames[{i}].step: expected an integer, found {value!r}", path=path)
    if not -(2**63) <= value < 2**63:
        raise InputError(f"frames[{i}].step {value} is beyond a 64-bit step number", path=path)
    return value


def read_transforms_poses(path: Path) -> PoseSet:
    """A nerfstudio/Blender ``transforms.json``: ``frames[].transform_matrix`` (+ ``step`` when present)."""
    data = transforms.read_transforms(path)
    poses = check_poses(transforms.frame_poses(data, path), path)
    frames = data["frames"]
    steps, named = None, False
    if any("step" in f for f in frames):
        steps = np.array([_step_of(f, i, path) for i, f in enumerate(frames)], np.int64)
        _, first, counts = np.unique(steps, return_index=True, return_counts=True)
        if (counts > 1).any():
            step = int(steps[first[counts > 1][0]])
            i, j = np.flatnonzero(steps == step)[:2]
            message = f"frames[{i}] and frames[{j}] share step {step}: each pose needs its own"
            raise InputError(message, path=path)
    elif all(isinstance(f.get("file_path"), str) for f in frames):
        steps = steps_from_names([f["file_path"] for f in frames], path)
        named = steps is not None
    k, fov, cam = None, None, transforms.camera(data, path)
    if all(key in cam for key in ("fl_x", "w", "h")):
        k = transforms.intrinsics(data, path)
    elif "camera_angle_x" in cam:
        fov = transforms.field_of_view(cam, path)
    box = transforms.scene_box(data, path)
    names = tuple(str(f.get("file_path", i)) for i, f in enumerate(frames))
    lens = transforms.lens(data, path) if k is None else None  # (else k holds it)
    return PoseSet(poses, steps, k, None, box, names, fov, lens=lens, steps_named=named)


# ------------------------------------------------------------------------------------------------- LLFF
def read_poses_bounds(path: Path) -> PoseSet:
    """LLFF ``poses_bounds.npy``: (N, 17) rows: 3×5 [R | t | (h, w, f)] (axes down, right, back), bounds."""
    try:  # mapped: a header asking for more than the file holds is refused, not allocated (MemoryError)
        arr = np.array(np.load(path, mmap_mode="r", allow_pickle=False))
    except (OSError, ValueError, EOFError, tokenize.TokenError) as err:  # (EOF, TokenError: a cut header)
        raise InputError(f"cannot read a .npy array ({type(err).__name__}: {err})", path=path) from err
    if arr.dtype.kind not in "iuf":  # bool, complex, strings, structured: not LLFF numbers
        raise InputError(f"expected an array of real numbers, found dtype {arr.dtype}", path=path)
    if arr.ndim != 2 or arr.shape[1] != 17:
        raise InputError(f"expected an (N, 17) array, found shape {arr.shape}", path=path)
    if len(arr) < 2:
        raise InputError(f"found {len(arr)} poses, need at least 2 to interpolate", path=path)
    if not np.isfinite(arr).all():
        raise InputError(f"{int((~np.isfinite(arr)).any(1).sum())} of {len(arr)} rows hold NaN or inf", path)
    m = arr[:, :15].reshape(-1, 3, 5).astype(np.float64)
    poses = np.tile(np.eye(4), (len(arr), 1, 1))
    poses[:, :3, 0], poses[:, :3, 1], poses[:, :3, 2] = m[:, :, 1], -m[:, :, 0], m[:, :, 2]
    poses[:, :3, 3] = m[:, :, 3]
    h, w, f = (float(v) for v in m[0, :, 4])
    if min(h, w, f) > 0:
        transforms.check_camera(w, h, [f], "column 4 (h, w, focal)", path)
    k = Intrinsics(round(w), round(h), f, f, w / 2, h / 2) if min(h, w, f) > 0 else None
    near, far = float(arr[:, 15].min()), float(arr[:, 16].max())
    bounds = (near, far) if 0 < near < far < FAR_LIMIT else None  # columns 15-16: the depth range per view
    return PoseSet(check_poses(poses, path), None, k, depth_bounds=bounds)


def read_pose_source(path: str | Path) -> PoseSet:
    """A pose file or folder, by its kind: COLMAP model folder, ``.npy`` (LLFF) or ``.json`` (transforms)."""
    path = Path(path)
    if path.is_dir():
        sparse = path / "sparse" / "0"
        return read_colmap_model(sparse if sparse.is_dir() and not (path / "images.txt").exists() else path)
    if not path.is_file():
        raise InputError("pose file not found", path=path)
    if path.suffix == ".npy":
        return read_poses_bounds(path)
    if path.suffix == ".json":
        return read_transforms_poses(path)
    raise InputError("expected a transforms .json, an LLFF poses_bounds.npy or a COLMAP model folder", path)


#: an orbit whose cameras spread over less than this share of its radius keeps them in one place
MIN_ORBIT_SPREAD = 1e-6


def orbit_poses(spec: str, steps: int, fps: float) -> PoseSet:
    """``--orbit RADIUS,ELEVATION_DEG[,TURNS[,START_AZIMUTH_DEG]]`` around the origin over ``steps`` steps
    (RADIUS within :data:`ORBIT_RADIUS`)."""
    try:
        values = [float(v) for v in spec.split(",")]
    except ValueError:
        values = []
    if not 2 <= len(values) <= 4 or not all(map(math.isfinite, values)) or values[0] <= 0:
        raise InputError(
            f"orbit: expected finite RADIUS,ELEVATION[,TURNS[,AZIMUTH]] with RADIUS > 0, found {spec!r}",
            param="orbit",
        )
    if not ORBIT_RADIUS[0] <= values[0] <= ORBIT_RADIUS[1]:
        raise InputError(
            f"orbit: the radius must lie within [{ORBIT_RADIUS[0]:g}, {ORBIT_RADIUS[1]:g}] (the scene is "
            f"scaled to its unit box, so any unit will do), found {values[0]:g} (in {spec!r})",
            param="orbit",
        )
    turns = values[2] if len(values) > 2 else 1.0
    start = values[3] if len(values) > 3 else 0.0
    if not abs(start) <= MAX_AZIMUTH:
        raise InputError(
            f"orbit: the start azimuth must lie within ±{MAX_AZIMUTH:g} degrees, found {start:g} "
            f"(in {spec!r})",
            param="orbit",
        )
    if problem := orbit_angle_problem(values[1], turns):
        raise InputError(f"orbit: {problem} (in {spec!r})", param="orbit")
    if turns == 0 or abs(values[1]) == 90:  # every view from one place: no parallax to place the scene
        raise InputError(
            f"orbit: {spec!r} keeps the camera in one place (turns 0, or elevation ±90°); a recording needs "
            "a path around the scene",
            param="orbit",
        )
    traj = orbit(values[0], values[1], turns, steps / fps, fps, start_azimuth_deg=start)
    if not np.ptp(traj.poses[:, :3, 3], axis=0).max() > MIN_ORBIT_SPREAD * values[0]:  # a sliver of a turn
        raise InputError(
            f"orbit: {spec!r} puts the camera in (nearly) one place at all {steps} steps (check the turns "
            "and the elevation); a recording needs a path around the scene",
            param="orbit",
        )
    return PoseSet(traj.poses, traj.steps.copy(), focus=np.zeros(3))

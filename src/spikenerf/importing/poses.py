"""Camera poses for a real recording: read from a pose file, or made from a known orbit (docs/real-data.md).

Every reader returns a :class:`PoseSet` of camera-to-world poses in our convention (OpenGL camera axes, see
scenes/trajectory.py), with the spike steps they belong to when the file says so. Supported: a nerfstudio /
Blender ``transforms.json``, a COLMAP model folder (``cameras``, ``images``, ``points3D`` as ``.txt``, or
``.bin`` converted through pycolmap), an LLFF ``poses_bounds.npy`` and an orbit (``--orbit``).
"""

from __future__ import annotations

import math
import re
import struct
import tempfile
import tokenize
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.scenes import transforms
from spikenerf.scenes.distortion import Distortion, colmap_camera
from spikenerf.scenes.poses import quaternion_to_matrix
from spikenerf.scenes.trajectory import (  # (the orbit's ranges: one definition, the library's)
    MAX_AZIMUTH,
    ORBIT_RADIUS,
    Intrinsics,
    orbit,
    orbit_angle_problem,
)

#: OpenCV camera axes (COLMAP: +X right, +Y down, +Z forward) → OpenGL (+Y up, looking down −Z)
CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
COLMAP_MISSING = "COLMAP poses need pycolmap: pip install 'spikenerf[colmap]'"


@dataclass(frozen=True)
class PoseSet:
    """Poses (N, 4, 4) float64 c2w; steps (N,) int64 spike steps or None (spread evenly later);
    intrinsics if the source knows them (at its own image size); points (M, 3) sparse scene points or None;
    scene_box (2, 3) if the source states one; names (N,) of the frames (for messages); camera_angle_x
    (radians) when the source gives only a field of view; depth_bounds (near, far) along the optical axes
    in the source's units (LLFF); note: how the poses were found when it matters (stored in config.yaml);
    focus (3,): the point every camera looks at when the source knows it (an orbit's centre); lens: the
    lens distortion of a source without full intrinsics (a field of view and ``k1``…)."""

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
    """Spike steps from frame names when every name's stem ends in a number, else None; InputError (naming
    ``path``) when two names carry the same number (spreading their poses evenly would misplace them)."""
    found = [re.search(r"(\d+)$", Path(n).stem) for n in names]
    if not names or not all(found):
        return None
    steps = np.array([int(m.group(1)) for m in found if m], np.int64)
    _, first, counts = np.unique(steps, return_index=True, return_counts=True)
    if (counts > 1).any():
        i, j = np.flatnonzero(steps == steps[first[counts > 1][0]])[:2]
        raise InputError(f"{names[i]!r} and {names[j]!r} name the same step: each pose needs its own", path)
    return steps


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
    steps = None
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
    k, fov, cam = None, None, transforms.camera(data, path)
    if all(key in cam for key in ("fl_x", "w", "h")):
        k = transforms.intrinsics(data, path)
    elif "camera_angle_x" in cam:
        fov = transforms.field_of_view(cam, path)
    box = transforms.scene_box(data, path)
    names = tuple(str(f.get("file_path", i)) for i, f in enumerate(frames))
    lens = transforms.lens(data, path) if k is None else None  # (else k holds it)
    return PoseSet(poses, steps, k, None, box, names, fov, lens=lens)


# ------------------------------------------------------------------------------------------- COLMAP model
def _lines(path: Path) -> list[list[str]]:
    if not path.is_file():
        raise InputError("missing file of a COLMAP text model", path=path)
    text = path.read_text(encoding="utf-8", errors="replace")
    return [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def _pose_rows(path: Path, cameras: set[int]) -> list[list[str]]:
    """The pose lines of a COLMAP ``images.txt``: two lines an image (``IMAGE_ID QW QX QY QZ TX TY TZ
    CAMERA_ID NAME``, then its points, possibly empty); InputError naming the line of a pose that is cut
    short, holds a non-numeric quaternion, translation or camera id, or names an unknown camera (it would be
    dropped without a word)."""
    if not path.is_file():
        raise InputError("missing file of a COLMAP text model", path=path)
    text = path.read_text(encoding="utf-8", errors="replace")
    lines = [(n, ln.split()) for n, ln in enumerate(text.splitlines(), 1) if not ln.lstrip().startswith("#")]
    while lines and not lines[-1][1]:
        lines.pop()
    rows = []
    for number, row in lines[0::2]:
        if what := f"{len(row)} fields, not 10" if len(row) != 10 else _pose_problem(row, cameras):
            raise InputError(f"line {number}: a pose line with {what} ({' '.join(row)[:60]})", path=path)
        rows.append(row)
    for number, row in lines[1::2]:  # each image's POINTS2D line: (X, Y, POINT3D_ID) triples, may be empty
        if len(row) % 3:
            raise InputError(
                f"line {number}: expected an image's POINTS2D line (X Y POINT3D_ID triples, or an empty "
                f"line) after its pose line, found {len(row)} fields ({' '.join(row)[:60]}); images.txt "
                "holds two lines an image",
                path=path,
            )
    return rows


def _pose_problem(row: list[str], cameras: set[int]) -> str:
    """What is wrong with a 10-field pose line of ``images.txt`` ("" when nothing)."""
    try:
        list(map(float, row[1:8]))  # QW QX QY QZ TX TY TZ (NaN/inf: refused with the rest of the poses)
        camera = int(row[8])
    except ValueError:
        return "a non-numeric quaternion, translation or camera id"
    return "" if camera in cameras else "an unknown camera"


def _colmap_camera(fields: list[str], path: Path) -> Intrinsics:
    """A ``cameras.txt`` line ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``, its lens terms kept
    (:func:`~spikenerf.scenes.distortion.colmap_camera`: a model whose terms cannot be applied is refused)."""
    try:
        model, w, h, params = fields[1], int(fields[2]), int(fields[3]), [float(p) for p in fields[4:]]
    except (ValueError, IndexError) as err:
        raise InputError(f"malformed camera line {' '.join(fields)!r} ({err})", path=path) from err
    try:
        pinhole, lens = colmap_camera(model, params)
    except InputError as err:
        raise InputError(f"camera {fields[0]}: {err.message}", path=path) from None
    if not (w > 0 and h > 0 and all(math.isfinite(p) and p > 0 for p in pinhole[:2])):
        raise InputError(f"camera {fields[0]}: width, height and focal length must be > 0", path=path)
    if not all(math.isfinite(p) for p in pinhole[2:4]):
        found = ", ".join(map(str, pinhole[2:4]))
        raise InputError(f"camera {fields[0]}: principal point cx, cy must be finite, found {found}", path)
    transforms.check_camera(w, h, list(pinhole[:2]), f"camera {fields[0]}", path)
    try:
        return Intrinsics(w, h, *pinhole, lens)
    except InputError as err:
        raise InputError(f"camera {fields[0]}: {err.message.removeprefix('distortion: ')}", path) from None


def read_colmap_text(folder: Path) -> PoseSet:
    """A COLMAP text model (``cameras.txt``, ``images.txt``, ``points3D.txt``); the first camera is used."""
    # each error names its own file (an InputError is a ValueError: a catch-all would rename it the folder)
    cams_path, pts_path = folder / "cameras.txt", folder / "points3D.txt"
    cams = {}
    for row in _lines(cams_path):
        try:
            cams[int(row[0])] = row
        except ValueError as err:
            raise InputError(f"malformed camera line {' '.join(row)[:60]!r} ({err})", cams_path) from err
    pose_rows = _pose_rows(folder / "images.txt", set(cams))
    rows = _lines(pts_path) if pts_path.is_file() else []
    if (short := next((i for i, r in enumerate(rows) if len(r) < 8), None)) is not None:
        found = " ".join(rows[short])[:60]
        raise InputError(f"point row {short + 1}: expected ID X Y Z R G B ERROR, found {found!r}", pts_path)
    try:
        pts = [[float(v) for v in r[1:4]] for r in rows]
    except ValueError as err:
        raise InputError(f"malformed point coordinates ({err})", path=pts_path) from err
    if not cams:
        raise InputError("no cameras in cameras.txt", path=folder)
    if pts and not (np.abs(np.asarray(pts)) < FAR_LIMIT).all():  # NaN, inf or absurd: a meaningless box
        raise InputError("points3D.txt holds NaN, infinite or absurdly distant points", path=pts_path)
    pose_rows.sort(key=lambda r: r[9])
    quats = np.array([[float(v) for v in r[1:5]] for r in pose_rows]).reshape(-1, 4)
    trans = np.array([[float(v) for v in r[5:8]] for r in pose_rows]).reshape(-1, 3)
    if (
        not np.isfinite(quats).all()
        or not np.isfinite(trans).all()
        or (np.linalg.norm(quats, axis=1) == 0).any()
    ):
        raise InputError("holds NaN, infinite or zero-quaternion poses", path=folder / "images.txt")
    w2c = np.tile(np.eye(4), (len(pose_rows), 1, 1))
    w2c[:, :3, :3], w2c[:, :3, 3] = quaternion_to_matrix(quats), trans
    poses = check_poses(np.linalg.inv(w2c) @ CV_TO_GL, folder / "images.txt")
    names = [r[9] for r in pose_rows]
    points = np.asarray(pts, np.float64).reshape(-1, 3)
    camera = _colmap_camera(cams[int(pose_rows[0][8])], folder / "cameras.txt")
    return PoseSet(
        poses,
        steps_from_names(names, folder / "images.txt"),
        camera,
        points if len(points) else None,
        None,
        tuple(names),
    )


#: parameters of each COLMAP camera model, by its id in ``cameras.bin`` (colmap/sensor/models.h; 12-17:
#: the division, fisheye, EUCM and equirectangular models pycolmap 4.2 writes)
CAMERA_PARAMS = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12, 11: 16,
                 12: 4, 13: 5, 14: 3, 15: 4, 16: 6, 17: 2}  # fmt: skip


def check_binary_layout(path: Path) -> None:
    """InputError naming ``path`` (a COLMAP ``cameras.bin``, ``images.bin``, ``points3D.bin``, ``rigs.bin``
    or ``frames.bin``) unless its records, as its counts declare them, fit in the file. pycolmap reads on
    past the end of a cut file (a zero-byte or truncated ``points3D.bin`` or a cut ``frames.bin`` makes it
    allocate without end, gigabytes in seconds) and takes an absurd count at its word. A camera model
    newer than :data:`CAMERA_PARAMS` ends the check of ``cameras.bin`` there (pycolmap knows it)."""
    if not path.is_file():
        raise InputError("missing file of a COLMAP binary model", path=path)
    data = path.read_bytes()
    at = 0

    def skip(size: int, what: str) -> int:
        nonlocal at
        if at + size > len(data):
            raise InputError(
                f"truncated COLMAP binary file: {what} ends past its {len(data)} bytes", path=path
            )
        at += size
        return at - size

    def take(fmt: str, what: str) -> tuple:
        return struct.unpack_from(fmt, data, skip(struct.calcsize(fmt), what))

    (count,) = take("<Q", "the record count")
    for i in range(count):
        if at >= len(data):
            raise InputError(
                f"truncated COLMAP binary file: it declares {count} records, holds {i}", path=path
            )
        if path.name == "cameras.bin":
            model = take("<Ii", f"camera record {i + 1}")[1]
            if model not in CAMERA_PARAMS:  # a model newer than this table: pycolmap reads the rest
                return
            take(f"<QQ{CAMERA_PARAMS[model]}d", f"camera record {i + 1}")
        elif path.name == "images.bin":
            take("<I7dI", f"image record {i + 1}")
            end = data.find(b"\0", at)
            if end < 0:
                raise InputError(f"truncated COLMAP binary file: image record {i + 1} has no name end", path)
            at = end + 1
            (points,) = take("<Q", f"image record {i + 1}")
            skip(24 * points, f"image record {i + 1}'s {points} points")
        elif path.name == "frames.bin":  # (COLMAP 3.12+) id, rig id, pose, then its sensors' data ids
            (ids,) = take("<II7dI", f"frame record {i + 1}")[-1:]
            skip(16 * ids, f"frame record {i + 1}'s {ids} data ids")
        elif path.name == "rigs.bin":  # (COLMAP 3.12+) id, sensor count, reference sensor, other sensors
            (sensors,) = take("<II", f"rig record {i + 1}")[-1:]
            skip(8 if sensors else 0, f"rig record {i + 1}")
            for _ in range(max(sensors - 1, 0)):
                if take("<iIB", f"rig record {i + 1}'s sensors")[-1]:
                    skip(56, f"rig record {i + 1}'s sensor poses")
        else:  # points3D.bin
            (track,) = take("<Q3d3BdQ", f"point record {i + 1}")[-1:]
            skip(8 * track, f"point record {i + 1}'s track of {track}")


def read_colmap_model(folder: Path) -> PoseSet:
    """A COLMAP model folder: text files directly, binary ones converted to text through pycolmap."""
    if (folder / "images.txt").is_file():
        return read_colmap_text(folder)
    if not (folder / "images.bin").is_file():
        hint = (
            f"; for a dataset's poses give {folder / 'transforms.json'}"
            if (folder / "transforms.json").is_file()
            else ""
        )
        raise InputError(f"not a COLMAP model folder (no images.txt or images.bin){hint}", path=folder)
    try:
        import pycolmap
    except ImportError as err:
        raise InputError(f"reading a binary model: {COLMAP_MISSING}", path=folder) from err
    for name in ("cameras.bin", "images.bin", "points3D.bin", "rigs.bin", "frames.bin"):
        if (folder / name).is_file() or name in ("cameras.bin", "images.bin"):
            check_binary_layout(folder / name)  # (pycolmap reads a cut file on, without end)
    with tempfile.TemporaryDirectory() as tmp:
        try:
            pycolmap.Reconstruction(str(folder)).write_text(tmp)
        except Exception as err:  # pycolmap raises plain RuntimeError/ValueError on a bad model
            why = (str(err).strip().splitlines() or [type(err).__name__])[0]
            raise InputError(f"pycolmap cannot read the binary model ({why})", path=folder) from err
        try:
            return read_colmap_text(Path(tmp))
        except InputError as err:  # it names the converted text file, deleted here: name the user's file
            if err.path is None or not err.path.startswith(tmp):
                raise
            name = Path(err.path).name.replace(".txt", ".bin")
            raise InputError(f"{err.message} (in its text conversion)", path=folder / name) from err


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

"""A COLMAP model folder as a :class:`~spikenerf.importing.pose_set.PoseSet`: ``cameras``, ``images`` and
``points3D`` as ``.txt``, or ``.bin`` (its layout checked first) converted through pycolmap."""

from __future__ import annotations

import math
import struct
import tempfile
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.importing.pose_set import FAR_LIMIT, PoseSet, check_poses, steps_from_names
from spikenerf.scenes import transforms
from spikenerf.scenes.distortion import colmap_camera
from spikenerf.scenes.poses import quaternion_to_matrix
from spikenerf.scenes.trajectory import Intrinsics

#: OpenCV camera axes (COLMAP: +X right, +Y down, +Z forward) → OpenGL (+Y up, looking down −Z)
CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
COLMAP_MISSING = "COLMAP poses need pycolmap: pip install 'spikenerf[colmap]'"


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
    steps = steps_from_names(names, folder / "images.txt")
    points = points if len(points) else None
    return PoseSet(poses, steps, camera, points, None, tuple(names), steps_named=steps is not None)


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

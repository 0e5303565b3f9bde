"""Trajectory files: a transforms JSON of poses with its optional camera and bounds, or a nerfstudio
``camera_path.json`` (docs/formats.md, docs/lens.md), read for ``render --trajectory FILE``, ``export`` and
``simulate --eval-views``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.data.dataset import read_mapping
from spikenerf.scenes.trajectory import Intrinsics
from spikenerf.scenes.transforms import (
    CAMERA_KEYS,
    LENS_KEYS,
    camera,
    check_camera,
    frame_poses,
    intrinsics,
    number,
    pose,
    read_transforms,
)


def read_pose_file(path: str | Path, size: tuple[int, int]) -> np.ndarray:
    """Poses (N, 4, 4) float64 c2w from a NeRF-style transforms JSON (``frames[].transform_matrix``).

    A camera the file gives is checked as a trajectory file's is (:func:`file_camera`, images of ``size`` =
    (width, height) where it gives no ``w``/``h``), though the caller renders the poses with its own camera:
    a NaN or negative ``camera_angle_x`` is a broken file, never passed over."""
    path = Path(path)
    if path.is_dir() and not (path / "transforms.json").is_file():
        raise InputError("is a folder, not a transforms JSON of poses", path=path)
    meta = read_transforms(path, missing="pose file not found")
    poses = frame_poses(meta, path)
    file_camera(meta, path, size)
    return poses


#: the keys of a nerfstudio ``camera_path.json`` (``ns-render camera-path``; the viewer writes it) read here
NERFSTUDIO_KEYS = ("camera_path", "render_width", "render_height")


@dataclass
class CameraPath:
    """A trajectory file's cameras: ``poses`` (N, 4, 4) float64 c2w; ``intrinsics``, None where the file
    gives no camera; ``bounds`` (near, far), None where it gives neither; ``kind``: ``transforms`` (a
    transforms JSON) or ``camera_path`` (a nerfstudio camera_path.json)."""

    poses: np.ndarray
    intrinsics: Intrinsics | None
    bounds: tuple[float, float] | None
    kind: str = "transforms"


def read_camera_path(path: str | Path, size: tuple[int, int]) -> CameraPath:
    """A trajectory file: a transforms JSON or a nerfstudio camera_path.json (:func:`nerfstudio_path`),
    told apart by their keys (``frames``; ``camera_path``).

    A transforms JSON of poses (``frames[].transform_matrix``) with its optional shared camera
    (``camera_angle_x`` or ``fl_x`` [``fl_y``, ``cx``, ``cy``]; ``w`` and ``h`` together, else ``size`` =
    (width, height); its lens, ``camera_model`` and the terms) and ``near``/``far`` (both, near < far).
    A file's camera is used whole: without lens keys it is a pinhole whatever the dataset's lens, and a lens
    (``camera_model`` or a term) without the file's own ``fl_x`` or ``camera_angle_x`` is refused, never
    combined with the dataset's focal length nor dropped."""
    path = Path(path)
    meta = read_mapping(path)
    if "camera_path" in meta:
        if "frames" in meta:
            raise InputError(
                "holds both 'frames' (a transforms JSON) and 'camera_path' (a nerfstudio camera path): "
                "which one is meant?",
                path=path,
            )
        return nerfstudio_path(meta, path)
    if "frames" not in meta and any(key in meta for key in NERFSTUDIO_KEYS):
        raise InputError(
            "missing field 'camera_path' (a nerfstudio camera_path.json's list of cameras)", path
        )
    poses = frame_poses(meta, path)
    k = file_camera(meta, path, size)
    bounds = None
    if "near" in meta or "far" in meta:
        near, far = number(meta, "near", path, positive=True), number(meta, "far", path, positive=True)
        if near >= far:
            raise InputError(f"fields 'near', 'far': expected near < far, found {near}, {far}", path=path)
        bounds = (near, far)
    return CameraPath(poses, k, bounds)


def file_camera(meta: dict, path: Path, size: tuple[int, int]) -> Intrinsics | None:
    """The shared camera of a transforms JSON of poses (its top-level object ``meta``), None where it gives
    none: ``camera_angle_x`` or ``fl_x`` [``fl_y``, ``cx``, ``cy``], its lens, and ``w`` and ``h`` together
    beside them (else the images are ``size`` = (width, height)); every key checked as a dataset's are
    (:func:`~spikenerf.scenes.transforms.intrinsics`), a lens or size without a focal length refused."""
    cam = camera(meta, path)
    given = [key for key in (*CAMERA_KEYS, *LENS_KEYS) if key in meta or key in cam]
    if given and not ("fl_x" in cam or "camera_angle_x" in cam):
        lensed = " (a file's lens is never paired with the dataset's focal length)"
        lensed = lensed if any(key in LENS_KEYS for key in given) else ""
        raise InputError(f"fields {given}: a camera needs 'camera_angle_x' or 'fl_x'{lensed}", path=path)
    sized = [d for d in (meta, cam) if "w" in d or "h" in d]
    if sized and sized[0] is meta and cam and not any(key in meta for key in ("fl_x", "camera_angle_x")):
        raise InputError("fields 'w', 'h' belong beside the camera's 'fl_x' or 'camera_angle_x'", path=path)
    return intrinsics(meta, path, None if sized else size) if given else None  # (w/h given: the size)


def nerfstudio_path(meta: dict, path: Path) -> CameraPath:
    """The cameras of a nerfstudio ``camera_path.json`` (its top-level object ``meta``): ``render_width``
    and ``render_height`` (positive integers) the image size, ``camera_path[i].camera_to_world`` 16 numbers,
    a row-major 4×4 c2w (OpenGL axes, as ours) that must be rigid, ``camera_path[i].fov`` the vertical field
    of view in degrees, the same for every camera (one shared camera here; focal length ``(H/2)/tan(fov/2)``
    for both axes, principal point at the image centre). ``camera_type``, where given, must be
    ``perspective``; ``aspect``, ``keyframes``, ``fps``, ``seconds`` and the rest are not read. No bounds:
    the caller derives them from the scene box. No lens: ``camera_model`` or a lens term, at the top or in
    a camera, is refused (a pinhole render would silently drop it)."""
    sizes = []
    for key in ("render_width", "render_height"):
        value = number(meta, key, path, positive=True)
        if value != int(value):
            raise InputError(f"field '{key}': expected a positive integer, found {meta[key]!r}", path=path)
        sizes.append(int(value))
    width, height = sizes
    kind = meta.get("camera_type", "perspective")
    if kind != "perspective":
        raise InputError(f"field 'camera_type': {kind!r} is not supported (only 'perspective')", path=path)
    cameras = meta["camera_path"]
    if not isinstance(cameras, list) or not cameras:
        raise InputError(
            f"field 'camera_path': expected a non-empty list of objects, found {cameras!r:.40}", path
        )
    matrices, fovs = [], []
    for i, cam in enumerate([meta, *cameras]):  # (the top level first: its lens keys only)
        where = f"camera_path[{i - 1}]." if i else ""
        if i and not isinstance(cam, dict):
            raise InputError(f"camera_path[{i - 1}]: expected an object, found {type(cam).__name__}", path)
        if lensed := [key for key in LENS_KEYS if key in cam]:
            raise InputError(
                f"field {where}'{lensed[0]}': a nerfstudio camera path has no lens (its cameras are "
                "pinholes); give the poses as a transforms JSON with 'fl_x' and the lens instead",
                path=path,
            )
        if not i:
            continue
        if "camera_to_world" not in cam:
            raise InputError(f"missing field {where}'camera_to_world'", path=path)
        flat = cam["camera_to_world"]
        try:
            values = np.asarray(flat, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            values = np.zeros(0)
        if values.size != 16 or values.ndim not in (1, 2):
            raise InputError(
                f"field {where}'camera_to_world': expected 16 numbers (a row-major 4×4), found {flat!r:.60}",
                path=path,
            )
        matrices.append(pose(values.reshape(4, 4), f"{where}camera_to_world", path))
        fov = number(cam, "fov", path, where, positive=True)
        if fov >= 180:
            raise InputError(f"field {where}'fov': expected degrees in (0, 180), found {fov}", path=path)
        fovs.append(fov)
    if any(f != fovs[0] for f in fovs):
        i = next(i for i, f in enumerate(fovs) if f != fovs[0])
        raise InputError(
            f"field camera_path[{i}].'fov' = {fovs[i]:g} differs from {fovs[0]:g}: a changing field of view "
            "is not supported",
            path=path,
        )
    focal = 0.5 * height / math.tan(math.radians(fovs[0]) / 2)
    check_camera(width, height, [focal], "fields 'render_width', 'render_height', 'fov'", path)
    k = Intrinsics(width, height, focal, focal, width / 2.0, height / 2.0)
    return CameraPath(np.stack(matrices), k, None, "camera_path")

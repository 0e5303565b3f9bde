"""The one reader of a NeRF "Blender" / nerfstudio ``transforms.json``: the file, its frames, their
camera-to-world matrices, the shared camera (intrinsics), the scene box and plain numbers.

Every reader of such a file uses these rules: an image sequence (:mod:`spikenerf.scenes.sequence`), a
dataset folder (:mod:`spikenerf.data.dataset`: ``transforms.json``, ``transforms_blur.json``,
``transforms_test.json``) and an imported recording's pose file (:mod:`spikenerf.importing.poses`). Every
problem is one :class:`~spikenerf.core.errors.InputError` line naming the file and the key.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from spikenerf.core.errors import InputError, is_finite
from spikenerf.scenes.distortion import TERMS, Distortion
from spikenerf.scenes.trajectory import Intrinsics

#: the shared camera's keys (nerfstudio names)
CAMERA_KEYS = ("camera_angle_x", "fl_x", "fl_y", "cx", "cy", "w", "h")
#: lens distortion terms (nerfstudio's names, :mod:`spikenerf.scenes.distortion`)
DISTORTION_KEYS = TERMS
#: nerfstudio ``camera_model`` values of a perspective camera: read as ``OPENCV`` (radial-tangential; zero
#: terms, or none, are a pinhole); ``OPENCV_FISHEYE`` is the equidistant fisheye
PERSPECTIVE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
#: every key of the shared camera that :func:`camera` reads
LENS_KEYS = ("camera_model", *DISTORTION_KEYS)
#: the scene box's keys, the first present is read: ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``
BOX_KEYS = ("scene_box", "aabb")
_REQUIRED = object()
#: how far RᵀR may stray from I (largest entry) for a matrix to count as a rotation: pose files round
ROTATION_TOL = 1e-3


def rotation_error(rot: np.ndarray) -> np.ndarray:
    """max |RᵀR − I| of each (..., 3, 3) matrix; +inf where the determinant is negative (a mirror)."""
    rot = np.asarray(rot, dtype=np.float64)
    off = np.abs(np.swapaxes(rot, -1, -2) @ rot - np.eye(3)).max(axis=(-2, -1))
    return np.where(np.linalg.det(rot) < 0, np.inf, off)


class _DuplicateKey(Exception):
    """A JSON object names ``key`` twice (raised by :func:`_unique_keys` out of ``json.loads``)."""

    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook`` of :func:`read_transforms`: the object, or _DuplicateKey for a key given twice
    (``json.loads`` keeps the last silently). One ``dict`` and a length test per object: cheap."""
    obj = dict(pairs)
    if len(obj) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise _DuplicateKey(key)
            seen.add(key)
    return obj


def read_transforms(path: str | Path, missing: str = "transforms file not found") -> dict[str, Any]:
    """The top-level JSON object of ``path``; InputError(``missing``) when there is no such file, and for an
    object that gives a key twice (which one is meant?), as strict YAML does (``core.yamlio``)."""
    path = Path(path)
    if path.is_dir() and (path / "transforms.json").is_file():
        raise InputError(f"is a folder: give the file {path / 'transforms.json'}", path=path)
    if not path.is_file():
        raise InputError(missing, path=path)
    try:
        meta = json.loads(path.read_text(encoding="utf-8"), object_pairs_hook=_unique_keys)
    except (ValueError, RecursionError) as err:  # (undecodable, not JSON, a number beyond int's digit limit,
        raise InputError(f"malformed JSON ({err})", path=path) from None  # nested beyond the stack)
    except _DuplicateKey as err:
        raise InputError(
            f"malformed JSON: key {err.key!r} given twice in one object (which one is meant?)", path=path
        ) from None
    if not isinstance(meta, dict):
        raise InputError(f"expected a JSON object at the top level, found {type(meta).__name__}", path=path)
    return meta


def frames_of(
    meta: dict[str, Any], path: Path, required: tuple[str, ...] = (), empty: bool = False
) -> list[dict[str, Any]]:
    """``meta["frames"]``: a list of objects, each holding the ``required`` keys; empty only if ``empty``."""
    frames = meta.get("frames")
    if not isinstance(frames, list) or not (frames or empty):
        kind = "a list" if empty else "a non-empty list"
        raise InputError(f"field 'frames': expected {kind} of objects, found {frames!r:.40}", path=path)
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise InputError(f"frames[{i}]: expected an object, found {type(frame).__name__}", path=path)
        for key in required:
            if key not in frame:
                raise InputError(f"frames[{i}]: missing field '{key}'", path=path)
    return frames


def number(
    obj: dict[str, Any],
    key: str,
    path: Path,
    where: str = "",
    positive: bool = False,
    default: Any = _REQUIRED,
) -> float:
    """``obj[key]`` as a float: finite, and > 0 if ``positive``; ``default`` when absent (else an error).

    ``where`` prefixes the key in messages (``"frames[3]."``)."""
    if key not in obj and default is _REQUIRED:
        raise InputError(f"missing field {where}'{key}'", path=path)
    value = obj.get(key, default)
    finite = isinstance(value, (int, float)) and is_finite(value)
    if not finite or (positive and value <= 0):
        kind = "a positive number" if positive else "a finite number"
        raise InputError(f"field {where}'{key}': expected {kind}, found {value!r}", path=path)
    return float(value)


def pose(value: object, field: str, path: Path | None) -> np.ndarray:
    """A rigid 4×4 camera-to-world matrix, float64 (finite, a rotation, last row 0 0 0 1); ``field`` names
    it in messages (``frames[3].transform_matrix``)."""
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{field}: expected a 4×4 list of numbers, found {value!r:.60}", path=path) from None
    if m.shape != (4, 4):
        raise InputError(f"{field}: expected a 4×4 matrix, found shape {m.shape}", path=path)
    if not np.isfinite(m).all():
        raise InputError(f"{field}: matrix holds NaN or infinite values", path=path)
    rot = m[:3, :3]
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise InputError(f"{field}: last row must be [0, 0, 0, 1], found {m[3].tolist()}", path=path)
    if rotation_error(rot) > ROTATION_TOL:
        raise InputError(f"{field}: rotation part is not a rotation (scaled, sheared or mirrored)", path=path)
    return m


def frame_poses(meta: dict[str, Any], path: Path) -> np.ndarray:
    """(N, 4, 4) float64 ``frames[].transform_matrix`` of a file with at least one frame, each checked as
    :func:`pose` does: all at once (400 000 poses in 0.8 s, not 17 s, so that a render weighs what such a
    file asks for up front), frame by frame where one fails, to name it."""
    frames = frames_of(meta, path, ("transform_matrix",))
    matrices = [f["transform_matrix"] for f in frames]
    good = poses_at_once(matrices)
    if good is not None:
        return good
    return np.stack([pose(m, f"frames[{i}].transform_matrix", path) for i, m in enumerate(matrices)])


def poses_at_once(matrices: list[object] | np.ndarray) -> np.ndarray | None:
    """(N, 4, 4) float64 of ``matrices`` when every one passes :func:`pose`'s checks, in one pass over the
    array; None when one does not (then check them one by one, which names it)."""
    with contextlib.suppress(TypeError, ValueError, OverflowError):  # (ragged, not numbers: one by one)
        m = np.asarray(matrices, dtype=np.float64)
        if (
            m.ndim == 3
            and m.shape[1:] == (4, 4)
            and np.isfinite(m).all()
            and np.allclose(m[:, 3], [0, 0, 0, 1], atol=1e-6)
            and (rotation_error(m[:, :3, :3]) <= ROTATION_TOL).all()
        ):
            return m
    return None


def rigid_poses(poses: object, param: str, one: bool = False) -> np.ndarray:
    """``poses`` as float64 (N, 4, 4) (N ≥ 0; ``one``: a single (4, 4)) when each is what :func:`pose` accepts
    (finite, a rotation, last row 0 0 0 1): the check of poses given in code (a trajectory, held-out views,
    a pose to render), as a ``transforms.json`` gets; InputError naming ``param`` (and the pose) otherwise.
    One pass over the array (:func:`poses_at_once`), pose by pose only to name the one that fails."""
    try:
        m = np.asarray(poses, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{param} must be numbers, found {poses!r:.60}", param=param) from None
    if m.ndim != (2 if one else 3) or m.shape[-2:] != (4, 4):
        shown = "(4, 4)" if one else "(N, 4, 4)"
        hint = " (one pose? pass poses[None])" if not one and m.shape == (4, 4) else ""
        raise InputError(f"{param} must be {shown} camera-to-world, found shape {m.shape}{hint}", param=param)
    stack = m[None] if one else m
    if poses_at_once(stack) is None:
        for i, matrix in enumerate(stack):
            try:
                pose(matrix, param if one else f"{param}[{i}]", None)
            except InputError as err:
                raise InputError(err.message, param=param) from None
    return m


def camera(meta: dict[str, Any], path: Path) -> dict[str, Any]:
    """The shared camera's keys (:data:`CAMERA_KEYS`, ``camera_model`` and the lens terms), read at the top
    level, else from the first frame; every frame that repeats a key must agree (per-frame cameras are not
    supported); each number given must be valid (:func:`check_camera_values`); the model must be a
    perspective one or ``OPENCV_FISHEYE`` (:func:`lens` reads the terms)."""
    listed = meta.get("frames")
    frames = [f for f in listed if isinstance(f, dict)] if isinstance(listed, list) else []
    source = meta if ("fl_x" in meta or "camera_angle_x" in meta or not frames) else frames[0]
    keys = (*CAMERA_KEYS, *LENS_KEYS)
    cam = {k: source[k] for k in keys if k in source}
    if source is not meta:  # (a lens given at the top level beside a per-frame focal length)
        cam.update({k: meta[k] for k in LENS_KEYS if k in meta and k not in cam})
    check_camera_values(cam, path)  # (first: a NaN read per frame "differs" from itself)
    shared = {**dict.fromkeys(DISTORTION_KEYS, 0), "camera_model": "PINHOLE", **cam}  # (unset: a pinhole)
    for i, frame in enumerate(frames):
        for key in [k for k in keys if k in frame and k in shared and not _same(k, frame[k], shared[k])]:
            raise InputError(
                f"frames[{i}].{key} differs from {shared[key]!r}: per-frame cameras unsupported", path
            )
    model = cam.get("camera_model", "PINHOLE")
    if model not in (*PERSPECTIVE_MODELS, "OPENCV_FISHEYE"):
        raise InputError(
            f"field 'camera_model': {model!r} is not supported (expected a perspective camera, "
            f"{', '.join(PERSPECTIVE_MODELS)}, or OPENCV_FISHEYE)",
            path,
        )
    return cam


#: camera keys whose value must be a positive number (the others: a finite one; ``camera_angle_x`` also < π)
POSITIVE_KEYS = ("camera_angle_x", "fl_x", "fl_y", "w", "h")


def check_camera_values(cam: dict[str, Any], path: Path) -> None:
    """InputError naming ``path`` and the key for any number of :func:`camera`'s keys that is given but not
    valid (not finite; ``fl_x``, ``fl_y``, ``w``, ``h`` not positive; ``camera_angle_x`` not in (0, π)),
    even where a reader would not use it (``camera_angle_x`` beside ``fl_x``): such a file is damaged."""
    for key in (*CAMERA_KEYS, *DISTORTION_KEYS):
        if key == "camera_angle_x" and key in cam:
            field_of_view(cam, path)
        elif key in cam:
            number(cam, key, path, positive=key in POSITIVE_KEYS)


def _same(key: str, a: object, b: object) -> bool:
    """Whether two values of a camera key agree; any two perspective ``camera_model`` values (or none) do."""
    if key == "camera_model":
        return (a if a not in PERSPECTIVE_MODELS else None) == (b if b not in PERSPECTIVE_MODELS else None)
    return a == b


def lens(meta: dict[str, Any], path: Path) -> Distortion | None:
    """The lens of the shared camera (:func:`camera`): ``camera_model`` (a perspective model reads as
    ``OPENCV``) and its terms ``k1``…``k4``, ``p1``, ``p2`` (finite numbers, absent: 0); None for a pinhole
    (a perspective model whose terms are all zero). InputError naming the file and the key otherwise."""
    cam = camera(meta, path)
    model = "OPENCV_FISHEYE" if cam.get("camera_model") == "OPENCV_FISHEYE" else "OPENCV"
    terms = {key: number(cam, key, path, default=0.0) for key in DISTORTION_KEYS}
    try:
        found = Distortion(model, **terms)
    except InputError as err:  # (p1/p2 given to a fisheye)
        raise InputError(f"field '{err.params[0]}': {err.message}", path=path) from None
    return None if found.is_pinhole else found


#: focal lengths beyond these multiples of the image's larger side are absurd (a field of view under 1e-4°,
#: or within 1e-4° of 180°): a camera of 1e308 in a pose file would be kept, seeing nothing
FOCAL_RANGE = (1e-6, 1e6)


def check_camera(w: float, h: float, focals: list[float], what: str, path: Path) -> None:
    """InputError naming ``path`` unless the positive size ``w``×``h`` is below 2**31 pixels a side and each
    focal length lies within :data:`FOCAL_RANGE` times its larger side."""
    side = max(w, h)
    if not (side < 2**31 and all(FOCAL_RANGE[0] <= f / side <= FOCAL_RANGE[1] for f in focals)):
        lo, hi = FOCAL_RANGE
        focal = ", ".join(f"{f:g}" for f in focals)
        raise InputError(
            f"{what}: an absurd camera ({w:g}×{h:g} pixels, focal length {focal}): expected sides below "
            f"2**31 and a focal length {lo:g} to {hi:g} times the larger side",
            path=path,
        )


def field_of_view(cam: dict[str, Any], path: Path) -> float:
    """``camera_angle_x`` of :func:`camera`'s keys: radians in (0, π)."""
    angle = number(cam, "camera_angle_x", path, positive=True)
    if angle >= math.pi:
        raise InputError(f"field 'camera_angle_x': expected radians in (0, π), found {angle}", path=path)
    return angle


def intrinsics(meta: dict[str, Any], path: Path, size: tuple[int, int] | None = None) -> Intrinsics:
    """The shared camera (:func:`camera`): ``fl_x`` [``fl_y``, ``cx``, ``cy``] or ``camera_angle_x``.

    ``size`` = (width, height) of the images when known: ``w``/``h``, if given, must match it; without it
    ``w`` and ``h`` are required (positive integers). ``fl_y`` defaults to ``fl_x``, ``cx``/``cy`` to the
    image centre.
    """
    cam = camera(meta, path)
    if size is None:
        w, h = (number(cam, key, path, positive=True) for key in ("w", "h"))
        if w != int(w) or h != int(h):
            raise InputError(f"fields 'w', 'h': expected integers, found {w}, {h}", path=path)
        size = (int(w), int(h))
    width, height = size
    for key, found in (("w", width), ("h", height)):
        if key in cam and cam[key] != found:
            raise InputError(f"field '{key}' = {cam[key]!r} but the images are {width}×{height} pixels", path)
    if "fl_x" in cam:
        fl_x = number(cam, "fl_x", path, positive=True)
        fl_y = number(cam, "fl_y", path, positive=True, default=fl_x)
        cx = number(cam, "cx", path, default=width / 2.0)
        cy = number(cam, "cy", path, default=height / 2.0)
        check_camera(width, height, [fl_x, fl_y], "fields 'w', 'h', 'fl_x', 'fl_y'", path)
        return with_lens(Intrinsics(width, height, fl_x, fl_y, cx, cy), lens(meta, path), path)
    if "camera_angle_x" in cam:
        k = Intrinsics.from_fov(width, height, field_of_view(cam, path))
        check_camera(width, height, [k.fl_x], "fields 'w', 'h', 'camera_angle_x'", path)
        return with_lens(k, lens(meta, path), path)
    raise InputError("missing camera: expected 'camera_angle_x' or 'fl_x' (with optional fl_y, cx, cy)", path)


def with_lens(k: Intrinsics, found: Distortion | None, path: Path | None) -> Intrinsics:
    """``k`` with the lens ``found`` (None: ``k``); a lens that cannot be undone over the image is one
    InputError naming ``path`` and the keys of the lens (its model and terms)."""
    if found is None:
        return k
    try:
        return dataclasses.replace(k, distortion=found)
    except InputError as err:
        keys = ", ".join(f"'{key}'" for key in found.as_json())
        raise InputError(f"fields {keys}: {err.message.removeprefix('distortion: ')}", path=path) from None


def scene_box(meta: dict[str, Any], path: Path, required: bool = False) -> np.ndarray | None:
    """(2, 3) float64 (min, max) from ``scene_box`` (or ``aabb``) with min < max; None when absent."""
    for key in BOX_KEYS:
        if key in meta:
            try:
                box = np.asarray(meta[key], dtype=np.float64)
            except (TypeError, ValueError, OverflowError):  # (an int beyond a float: 10**400)
                box = np.zeros(0)
            if box.shape != (2, 3) or not np.isfinite(box).all() or not (box[0] < box[1]).all():
                raise InputError(
                    f"field '{key}': expected [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min < max, "
                    f"found {meta[key]!r:.80}",
                    path=path,
                )
            return box
    if required:
        raise InputError("missing field 'scene_box': expected [[xmin, ymin, zmin], [xmax, ymax, zmax]]", path)
    return None

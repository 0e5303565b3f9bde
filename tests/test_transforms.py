"""The one transforms.json reader (scenes/transforms.py): every rule once, one error per function."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from spikenerf.core.errors import InputError
from spikenerf.scenes import transforms
from spikenerf.scenes.trajectory import Intrinsics


def _pose(x: float = 0.0) -> list[list[float]]:
    m = np.eye(4)
    m[0, 3] = x
    return m.tolist()


def _write(path: Path, **meta: object) -> Path:
    data = {
        "w": 8,
        "h": 6,
        "camera_angle_x": 0.9,
        "frames": [{"transform_matrix": _pose(i)} for i in range(3)],
    }
    path.write_text(json.dumps({**data, **meta}))
    return path


def test_a_file_reads_into_poses_intrinsics_and_box(tmp_path: Path) -> None:
    path = _write(tmp_path / "t.json", scene_box=[[-1, -1, -1], [1, 1, 1]])
    meta = transforms.read_transforms(path)
    poses = transforms.frame_poses(meta, path)
    assert poses.shape == (3, 4, 4) and poses.dtype == np.float64 and poses[2, 0, 3] == 2.0
    assert transforms.intrinsics(meta, path) == Intrinsics.from_fov(8, 6, 0.9)
    assert transforms.scene_box(meta, path).tolist() == [[-1, -1, -1], [1, 1, 1]]
    assert transforms.scene_box({}, path) is None
    full = {**meta, "fl_x": 10.0}  # fl_y, cx, cy default to fl_x and the image centre
    assert transforms.intrinsics(full, path) == Intrinsics(8, 6, 10.0, 10.0, 4.0, 3.0)
    assert transforms.intrinsics(full, path, size=(8, 6)) == Intrinsics(8, 6, 10.0, 10.0, 4.0, 3.0)
    assert transforms.number({"a": 2}, "a", path, positive=True) == 2.0
    assert transforms.number({}, "a", path, default=0.5) == 0.5
    assert transforms.field_of_view({"camera_angle_x": 1.0}, path) == 1.0


def test_each_rule_is_one_error_naming_the_file_and_the_key(tmp_path: Path) -> None:
    path = _write(tmp_path / "t.json")
    with pytest.raises(InputError, match=r"missing\.json: gone"):
        transforms.read_transforms(tmp_path / "missing.json", "gone")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(InputError, match=r"bad\.json: malformed JSON"):
        transforms.read_transforms(tmp_path / "bad.json")
    with pytest.raises(InputError, match=r"t\.json: frames\[0\]: missing field 'file_path'"):
        transforms.frames_of(json.loads(path.read_text()), path, ("file_path",))
    with pytest.raises(InputError, match=r"t\.json: field 'frames': expected a non-empty list"):
        transforms.frames_of({"frames": []}, path)
    with pytest.raises(InputError, match=r"^.*t\.json: field frames\[0\]\.'time': expected a finite number"):
        transforms.number({"time": math.nan}, "time", path, "frames[0].")
    with pytest.raises(InputError, match=r"missing field 'near'"):
        transforms.number({}, "near", path)
    scaled = (np.eye(4) * [2, 2, 2, 1]).tolist()
    with pytest.raises(InputError, match=r"t\.json: frames\[0\]\.transform_matrix: rotation part is not"):
        transforms.pose(scaled, "frames[0].transform_matrix", path)
    with pytest.raises(InputError, match=r"frames\[2\]\.transform_matrix: expected a 4×4 matrix"):
        transforms.frame_poses(
            {"frames": [{"transform_matrix": _pose()}] * 2 + [{"transform_matrix": [1]}]}, path
        )
    with pytest.raises(InputError, match=r"t\.json: field 'k1': expected a finite number, found 'abc'"):
        transforms.lens({"camera_model": "OPENCV", "k1": "abc", "fl_x": 1.0}, path)
    with pytest.raises(
        InputError, match=r"t\.json: field 'camera_model': 'EQUIRECTANGULAR' is not supported"
    ):
        transforms.camera({"camera_model": "EQUIRECTANGULAR", "fl_x": 1.0}, path)
    with pytest.raises(InputError, match=r"t\.json: field 'w' = 8 but the images are 4×6 pixels"):
        transforms.intrinsics(json.loads(path.read_text()), path, size=(4, 6))
    with pytest.raises(InputError, match=r"t\.json: field 'camera_angle_x': expected radians in \(0, π\)"):
        transforms.field_of_view({"camera_angle_x": 4.0}, path)
    with pytest.raises(InputError, match=r"t\.json: field 'aabb': expected \[\[xmin"):
        transforms.scene_box({"aabb": [[1, 1, 1], [0, 0, 0]]}, path)
    with pytest.raises(InputError, match=r"t\.json: missing field 'scene_box'"):
        transforms.scene_box({}, path, required=True)


def test_frame_poses_checks_all_frames_at_once_and_names_the_first_bad_one(tmp_path: Path) -> None:
    """Well-formed poses are checked together (a 400 000-pose trajectory in seconds); one that fails any
    rule of :func:`transforms.pose` is still named, found frame by frame."""
    path = tmp_path / "t.json"
    rot = np.array([[1.0, 0, 0, 0], [0, 0, -1, -4], [0, 1, 0, 0], [0, 0, 0, 1]])
    frames = [{"transform_matrix": rot.tolist()}] * 20_000
    poses = transforms.frame_poses({"frames": frames}, path)
    assert poses.shape == (20_000, 4, 4) and poses.dtype == np.float64 and (poses == rot).all()
    bad = {
        "rotation part is not a rotation": (rot * [1, 1, -1, 1]).tolist(),  # a mirror
        "last row must be": [*rot.tolist()[:3], [0, 0, 0, 2]],
        "matrix holds NaN or infinite": [[math.nan] * 4, *rot.tolist()[1:]],
        "expected a 4×4 list of numbers": [[1, 0, 0], {"a": 1}],
        "expected a 4×4 matrix": rot[:3].tolist(),
    }
    for needle, matrix in bad.items():
        frames = [{"transform_matrix": rot.tolist()}] * 3 + [{"transform_matrix": matrix}]
        with pytest.raises(InputError, match=rf"t\.json: frames\[3\]\.transform_matrix: {needle}"):
            transforms.frame_poses({"frames": frames}, path)


def test_a_pose_of_numbers_no_float_holds_is_one_error(tmp_path: Path) -> None:
    from spikenerf.core.errors import InputError
    from spikenerf.scenes.transforms import frame_poses

    huge = [[10**400, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    with pytest.raises(InputError, match=r"frames\[0\]\.transform_matrix: expected a 4×4 list of numbers"):
        frame_poses({"frames": [{"transform_matrix": huge}]}, tmp_path / "t.json")


@pytest.mark.parametrize(
    "camera",
    [
        {"w": 16, "h": 16, "fl_x": 1e308},  # a field of view of 1e-307 rad: the dataset would see nothing
        {"w": 16, "h": 16, "fl_x": 20.0, "fl_y": 1e-300},
        {"w": 16, "h": 16, "camera_angle_x": 1e-300},
        {"w": 2**40, "h": 16, "fl_x": 20.0},
    ],
)
def test_an_absurd_camera_is_refused_naming_its_fields(tmp_path: Path, camera: dict) -> None:
    path = tmp_path / "transforms.json"
    with pytest.raises(InputError, match=r"an absurd camera") as err:
        transforms.intrinsics(camera, path)
    assert str(err.value).startswith(f"{path}: fields") and "\n" not in str(err.value)
    assert transforms.intrinsics({"w": 16, "h": 16, "camera_angle_x": 1e-3}, path).fl_x > 16  # narrow: fine


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        ({"camera_angle_x": math.nan}, "camera_angle_x"),  # beside fl_x, which alone would be enough
        ({"camera_angle_x": math.inf}, "camera_angle_x"),
        ({"camera_angle_x": 0.0}, "camera_angle_x"),
        ({"camera_angle_x": 3.2}, "camera_angle_x"),
        ({"fl_y": math.nan}, "fl_y"),
        ({"cx": math.inf}, "cx"),
        ({"cy": "4"}, "cy"),
        ({"k1": math.nan}, "k1"),
        ({"p2": -math.inf}, "p2"),
        ({"w": math.nan}, "w"),
        ({"h": -6}, "h"),
    ],
)
def test_every_camera_field_given_is_checked_even_where_another_suffices(
    tmp_path: Path, extra: dict, field: str
) -> None:
    """A damaged camera field is refused wherever it stands: a NaN ``camera_angle_x`` beside a valid
    ``fl_x`` passed (the focal length was read, the angle never), as did any field of a pose file that
    ``import`` does not use (``fl_x`` without ``w``/``h``, ``cx`` beside ``camera_angle_x``)."""
    path = tmp_path / "t.json"
    good = {"w": 8, "h": 6, "fl_x": 10.0, "frames": [{"transform_matrix": _pose()}]}
    assert transforms.camera(good, path)["fl_x"] == 10.0
    for meta in ({**good, **extra}, {"frames": [{"transform_matrix": _pose(), **good, **extra}]}):
        with pytest.raises(InputError, match=rf"^{re.escape(str(path))}: field '{field}': expected ") as err:
            transforms.camera(meta, path)
        assert "\n" not in str(err.value)

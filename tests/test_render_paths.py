"""The render paths of ``spikenerf render --trajectory``: the spiral and the interpolated path (pure pose
maths, checked against their geometric definitions) and nerfstudio's camera_path.json reader."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from spikenerf.core.errors import InputError
from spikenerf.data.camera_path import read_camera_path
from spikenerf.scenes.poses import interpolate_poses, look_at
from spikenerf.scenes.render_paths import (
    GENERATED_PATHS,
    RENDER_PATHS,
    SPIRAL_PERCENTILE,
    catmull_rom,
    key_path,
    mean_pose,
    path_keys,
    spiral_focus,
    spiral_path,
)


def _forward_facing(n: int = 24, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) cameras on a jittered plane patch around (0, 0, 3), each looking near the origin."""
    rng = np.random.default_rng(seed)
    eyes = np.c_[rng.uniform(-0.6, 0.6, n), rng.uniform(-0.3, 0.3, n), 3 + rng.uniform(-0.1, 0.1, n)]
    return np.stack([look_at(e, rng.normal(0, 0.2, 3), np.array([0.0, 1.0, 0.0])) for e in eyes])


def _assert_rigid(poses: np.ndarray) -> None:
    rot = poses[:, :3, :3]
    assert np.abs(np.swapaxes(rot, 1, 2) @ rot - np.eye(3)).max() < 1e-9
    assert np.allclose(np.linalg.det(rot), 1.0, atol=1e-9)
    assert np.array_equal(poses[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (len(poses), 1)))


def test_the_kinds_are_one_tuple_and_the_generated_ones_take_a_frame_count() -> None:
    assert RENDER_PATHS == ("test", "orbit", "spiral", "interpolate")
    assert GENERATED_PATHS == ("orbit", "spiral", "interpolate")


@pytest.mark.parametrize("count", [1, 3, 7, 40])
def test_every_generated_pose_is_rigid(count: int) -> None:
    poses = _forward_facing()
    _assert_rigid(spiral_path(poses, 1.0, 8.0, count))
    _assert_rigid(key_path(path_keys(poses, 6), count))
    _assert_rigid(mean_pose(poses)[None])


def test_mean_pose_is_the_average_position_and_the_middle_rotation() -> None:
    pose = look_at(np.array([1.0, 2.0, 3.0]), np.zeros(3))
    assert np.allclose(mean_pose(pose[None]), pose)
    turn = lambda a: np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])  # noqa: E731
    poses = np.repeat(np.eye(4)[None], 2, 0)
    poses[0, :3, :3], poses[1, :3, :3] = turn(0.4) @ turn(0.3), turn(0.4) @ turn(-0.3)
    poses[:, :3, 3] = [[0, 0, 0], [2, 4, 6]]
    mean = mean_pose(poses)
    assert np.allclose(mean[:3, :3], turn(0.4)) and np.allclose(mean[:3, 3], [1, 2, 3])


def test_view_agreement_tells_forward_facing_cameras_from_an_orbit() -> None:
    from spikenerf.scenes.render_paths import FORWARD_FACING, view_agreement
    from spikenerf.scenes.trajectory import orbit

    assert view_agreement(_forward_facing()) > 0.95
    around = orbit(4.0, 30.0, turns=1.0, duration=0.025).poses
    assert view_agreement(around) < FORWARD_FACING  # looking in from every side: the mean view is short


def test_the_spiral_is_centred_on_the_mean_camera_and_looks_at_the_focus_point() -> None:
    poses, near, far = _forward_facing(), 1.5, 9.0
    spiral = spiral_path(poses, near, far, 30)
    centre = mean_pose(poses)
    mid, rot = centre[:3, 3], centre[:3, :3]
    assert np.allclose(spiral[:, :3, 3].mean(0), mid, atol=1e-12)
    focus_depth = spiral_focus(near, far)
    assert math.isclose(1 / focus_depth, 0.25 / near + 0.75 / far)
    assert near < focus_depth < far
    focus = mid - focus_depth * rot[:, 2]
    to_focus = focus - spiral[:, :3, 3]
    forward = -spiral[:, :3, 2]
    cos = np.sum(forward * to_focus, -1) / np.linalg.norm(to_focus, axis=-1)
    assert np.allclose(cos, 1.0, atol=1e-12)  # every frame's optical axis passes through the focus point
    assert (spiral[:, :3, 1] @ rot[:, 1] > 0.9).all()  # upright as the mean camera
    # the radii: the 90th percentile of the cameras' offsets in the mean camera's axes; frame 0 (θ = 0)
    # sits at +radius along the mean camera's right axis, and the spiral reaches ±radius along its up axis
    local = (poses[:, :3, 3] - mid) @ rot
    radii = np.percentile(np.abs(local), SPIRAL_PERCENTILE, axis=0)
    spiral_local = (spiral[:, :3, 3] - mid) @ rot
    assert np.allclose(spiral_local[0], [radii[0], 0, 0], atol=1e-12)
    assert math.isclose(np.abs(spiral_local[:, 1]).max(), radii[1], rel_tol=0.02)
    assert np.abs(spiral_local[:, 2]).max() <= radii[2] + 1e-12
    # two turns: frame i and frame i + count/2 share a right/up offset
    assert np.allclose(spiral_local[:15, :2], spiral_local[15:, :2], atol=1e-12)


def test_the_interpolated_path_passes_through_its_keys_and_is_continuous() -> None:
    keys = path_keys(_forward_facing(40, seed=3), 5)
    assert len(keys) == 5
    path = key_path(keys, 4 * 8 + 1)  # key j is frame 8·j
    assert np.array_equal(path[::8], keys)  # exactly, not nearly
    fine = key_path(keys, 4 * 16 + 1)
    assert np.array_equal(fine[::16], keys)
    # no jump: doubling the frames halves the largest step between neighbours, in position and in angle
    for a, b in ((path, fine),):
        steps = [np.linalg.norm(np.diff(p[:, :3, 3], axis=0), axis=-1).max() for p in (a, b)]
        angles = [_largest_turn(p) for p in (a, b)]
        assert steps[1] < 0.6 * steps[0] and angles[1] < 0.6 * angles[0]
    # rotations are slerped: between keys 1 and 2 the frames turn at a constant rate
    turns = [_angle(path[i], path[i + 1]) for i in range(8, 16)]
    assert np.allclose(turns, turns[0], rtol=1e-6)
    assert np.allclose(path[12, :3, :3], interpolate_poses(keys[1], keys[2], 0.5)[:3, :3])


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    cos = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2
    return float(np.arccos(np.clip(cos, -1, 1)))


def _largest_turn(path: np.ndarray) -> float:
    return max(_angle(path[i], path[i + 1]) for i in range(len(path) - 1))


def test_catmull_rom_hits_its_points_and_follows_a_straight_even_line_between_inner_points() -> None:
    points = np.array([[0.0, 0, 0], [1, 2, 0], [2, 4, 0], [3, 6, 0], [7, 1, 1]])
    s = np.linspace(0, 4, 33)
    curve = catmull_rom(points, s)
    assert np.array_equal(curve[::8], points)
    # points 0..3 are evenly spaced on a line: the spline is that line, at an even pace, up to the first
    # point too (its outer control point is reflected, not repeated: no easing into the end)
    inner = s <= 2
    assert np.allclose(curve[inner], np.outer(s[inner], [1, 2, 0]))


def test_the_interpolated_path_keeps_its_pace_at_the_ends() -> None:
    """Keys evenly spaced on a circle: the frames' steps at the path's ends are within 10 % of those in its
    middle (with repeated end points the spline slowed to 0.6× there)."""
    angles = np.linspace(0, np.pi, 9)
    points = np.c_[np.cos(angles), np.sin(angles), np.zeros(9)]
    curve = catmull_rom(points, np.linspace(0, 8, 161))
    steps = np.linalg.norm(np.diff(curve, axis=0), axis=-1)
    assert steps[[0, -1]].min() > 0.9 * np.median(steps) and steps.max() < 1.1 * np.median(steps)


def test_path_keys_spreads_over_the_path_and_counts_a_held_pose_once() -> None:
    poses = _forward_facing(6)
    held = np.repeat(poses, 3, axis=0)  # each pose held for 3 steps
    keys = path_keys(held, 16)
    assert np.array_equal(keys, poses)
    picked = path_keys(poses, 3)
    assert np.array_equal(picked, poses[[0, 2, 5]]) or np.array_equal(picked, poses[[0, 3, 5]])
    assert np.array_equal(key_path(poses[:1], 4), np.repeat(poses[:1], 4, 0))


# -- nerfstudio camera_path.json ----------------------------------------------------------------------------
def _camera_path(tmp_path: Path, poses: np.ndarray, fov: float = 50.0, **extra: object) -> Path:
    data = {
        "camera_type": "perspective",
        "render_height": 24,
        "render_width": 40,
        "camera_path": [
            {"camera_to_world": p.ravel().tolist(), "fov": fov, "aspect": 40 / 24} for p in poses
        ],
        "fps": 24,
        "seconds": 2,
        **extra,
    }
    path = tmp_path / "camera_path.json"
    path.write_text(json.dumps(data))
    return path


def test_a_nerfstudio_camera_path_round_trips_its_poses_fov_and_size(tmp_path: Path) -> None:
    poses = _forward_facing(5)
    found = read_camera_path(_camera_path(tmp_path, poses), (64, 64))
    assert found.kind == "camera_path" and found.bounds is None
    assert np.array_equal(found.poses, poses)  # 16 numbers, row-major: the translation is 3, 7, 11
    k = found.intrinsics
    assert (k.width, k.height, k.cx, k.cy) == (40, 24, 20.0, 12.0)
    assert math.isclose(k.fl_y, 12 / math.tan(math.radians(25))) and k.fl_x == k.fl_y  # fov is vertical
    assert math.isclose(2 * math.degrees(math.atan(k.height / 2 / k.fl_y)), 50.0)
    nested = json.loads((tmp_path / "camera_path.json").read_text())
    for cam in nested["camera_path"]:  # a 4×4 nested list reads the same
        cam["camera_to_world"] = np.reshape(cam["camera_to_world"], (4, 4)).tolist()
    del nested["camera_type"]  # (absent: perspective)
    (tmp_path / "nested.json").write_text(json.dumps(nested))
    assert np.array_equal(read_camera_path(tmp_path / "nested.json", (64, 64)).poses, poses)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.pop("render_width"), "missing field 'render_width'"),
        (lambda d: d.update(render_height=12.5), "'render_height': expected a positive integer"),
        (lambda d: d.update(camera_type="fisheye"), "'camera_type': 'fisheye' is not supported"),
        (lambda d: d.update(camera_path=[]), "'camera_path': expected a non-empty list"),
        (lambda d: d.update(frames=[]), "holds both 'frames'"),
        (lambda d: d["camera_path"][1].pop("fov"), "missing field camera_path[1].'fov'"),
        (lambda d: d["camera_path"][0].update(fov=180), "camera_path[0].'fov': expected degrees in (0, 180)"),
        (lambda d: d["camera_path"][2].update(fov=60), "camera_path[2].'fov' = 60 differs from 50"),
        (lambda d: d["camera_path"][1]["camera_to_world"].pop(), "expected 16 numbers (a row-major 4×4)"),
        (lambda d: d["camera_path"][1].update(camera_to_world="eye"), "expected 16 numbers"),
        (
            lambda d: d["camera_path"][0].pop("camera_to_world"),
            "missing field camera_path[0].'camera_to_world'",
        ),
        (
            lambda d: d["camera_path"][1].update(
                camera_to_world=np.reshape(d["camera_path"][1]["camera_to_world"], (4, 4)).T.ravel().tolist()
            ),
            "camera_path[1].camera_to_world: last row must be [0, 0, 0, 1]",  # column-major: refused
        ),
        (lambda d: d.update(camera_path=[{"fov": 50, "camera_to_world": [2.0] * 16}]), "last row"),
        (lambda d: d.pop("camera_path"), "missing field 'camera_path'"),
        (lambda d: d.update(k1=-0.2), "field 'k1': a nerfstudio camera path has no lens"),  # (was dropped)
        (
            lambda d: d["camera_path"][1].update(camera_model="OPENCV_FISHEYE"),
            "camera_path[1].'camera_model'",
        ),
    ],
)
def test_a_malformed_camera_path_is_one_line_naming_the_file(tmp_path: Path, change, message: str) -> None:  # type: ignore[no-untyped-def]
    path = _camera_path(tmp_path, _forward_facing(3))
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))
    with pytest.raises(InputError) as err:
        read_camera_path(path, (64, 64))
    assert message in err.value.message and "\n" not in str(err.value)
    assert err.value.path == str(path)


# -- a transforms JSON's lens --------------------------------------------------------------------------------
def _transforms(tmp_path: Path, **fields: object) -> Path:
    path = tmp_path / "transforms_path.json"
    path.write_text(json.dumps({**fields, "frames": [{"transform_matrix": _forward_facing(1)[0].tolist()}]}))
    return path


@pytest.mark.parametrize(
    "lens",
    [
        {"k1": -0.2},
        {"camera_model": "OPENCV", "k1": -0.2, "p2": 0.01},
        {"camera_model": "OPENCV_FISHEYE"},  # (all terms zero: still a lens, r_d = θ)
        {"camera_model": "OPENCV_FISHEYE", "k2": 0.01},
    ],
)
def test_a_trajectory_lens_without_its_focal_length_is_refused_naming_the_file_and_key(
    tmp_path: Path, lens: dict
) -> None:
    """A file's lens is never silently dropped nor paired with the dataset's focal length: without the
    file's own fl_x (or camera_angle_x) it is one error naming the file and the missing key."""
    path = _transforms(tmp_path, **lens)
    with pytest.raises(InputError) as err:
        read_camera_path(path, (40, 24))
    assert "'fl_x'" in err.value.message and "lens" in err.value.message
    assert err.value.path == str(path) and "\n" not in str(err.value)
    found = read_camera_path(_transforms(tmp_path, fl_x=30.0, w=40, h=24, **lens), (64, 64)).intrinsics
    model = lens.get("camera_model", "OPENCV")
    assert found.distortion is not None and found.distortion.model == model  # with its focal: the lens
    assert all(
        getattr(found.distortion, key) == value for key, value in lens.items() if key != "camera_model"
    )


def test_a_trajectory_camera_without_lens_keys_is_a_pinhole(tmp_path: Path) -> None:
    """The file's camera is used whole: fl_x without lens keys is a pinhole (the dataset's lens is not
    borrowed), and a file with no camera at all gives none (the dataset's camera, lens included)."""
    found = read_camera_path(_transforms(tmp_path, fl_x=30.0), (40, 24))
    assert found.intrinsics is not None and found.intrinsics.distortion is None
    assert read_camera_path(_transforms(tmp_path), (40, 24)).intrinsics is None

"""Trajectory maths: orbit poses looking at the centre, right-handed axes, times, novel views off the path."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spikenerf.core.errors import InputError
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.projection import image_motion
from spikenerf.scenes.trajectory import Intrinsics, novel_views, orbit


def _project(c2w: np.ndarray, k: Intrinsics, point: np.ndarray) -> tuple[float, float]:
    """Pixel coordinates (u, v) of a world point, OpenGL camera (looking down −Z, +Y up, v grows down)."""
    x, y, z = (np.linalg.inv(c2w) @ np.append(point, 1.0))[:3]
    assert z < 0, "point behind the camera"
    return k.cx + k.fl_x * x / -z, k.cy - k.fl_y * y / -z


def test_default_orbit_is_1000_steps_at_40khz_one_turn() -> None:
    traj = orbit(4.0, 30.0)
    assert len(traj) == 1000 and traj.fps == 40000.0
    np.testing.assert_array_equal(traj.steps, np.arange(1000))
    np.testing.assert_allclose(traj.times, traj.steps / 40000.0)
    assert traj.times[-1] == pytest.approx(0.025 - 1 / 40000)
    eyes = traj.poses[:, :3, 3]
    azimuth = np.unwrap(np.arctan2(eyes[:, 1], eyes[:, 0]))
    np.testing.assert_allclose(azimuth, 2 * np.pi * traj.steps / 1000, atol=1e-9)  # counter-clockwise from +Z


def test_orbit_poses_on_the_sphere_at_the_elevation_and_looking_at_the_centre() -> None:
    center = np.array([0.2, -0.1, 0.3])
    traj = orbit(3.0, 25.0, duration=0.001, center=tuple(center))
    eyes = traj.poses[:, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(eyes - center, axis=1), 3.0)
    np.testing.assert_allclose(eyes[:, 2] - center[2], 3.0 * math.sin(math.radians(25.0)))
    forward = -traj.poses[:, :3, 2]  # the camera looks down its −Z axis
    to_center = (center - eyes) / np.linalg.norm(center - eyes, axis=1, keepdims=True)
    np.testing.assert_allclose(forward, to_center, atol=1e-12)
    np.testing.assert_allclose(traj.poses[:, 3], np.tile([0, 0, 0, 1.0], (len(traj), 1)))


def test_rotations_are_right_handed_and_upright() -> None:
    traj = orbit(4.0, 30.0, duration=0.002)
    rot = traj.poses[:, :3, :3]
    np.testing.assert_allclose(
        rot.transpose(0, 2, 1) @ rot, np.broadcast_to(np.eye(3), rot.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(rot), 1.0)
    np.testing.assert_allclose(rot[:, 2, 0], 0.0, atol=1e-12)  # camera +X stays horizontal
    assert (rot[:, 2, 1] > 0).all()  # camera +Y points up in the world (+Z up)


def test_centre_projects_to_the_principal_point_and_up_is_up() -> None:
    k = Intrinsics.from_fov(200, 100, 0.69)
    for pose in orbit(4.0, 30.0, duration=0.001).poses[::7]:
        u, v = _project(pose, k, np.zeros(3))
        assert (u, v) == (pytest.approx(100.0), pytest.approx(50.0))
        _, v_up = _project(pose, k, np.array([0.0, 0.0, 0.5]))
        assert v_up < v  # a point above the centre is higher in the image (smaller row)


def test_intrinsics_fov_round_trip_and_scaling() -> None:
    k = Intrinsics.from_fov(400, 300, 0.6911112070083618)
    assert k.camera_angle_x == pytest.approx(0.6911112070083618)
    assert (k.cx, k.cy) == (200.0, 150.0)
    half = k.scaled(200, 150)
    assert half.fl_x == pytest.approx(k.fl_x / 2) and half.camera_angle_x == pytest.approx(k.camera_angle_x)
    np.testing.assert_allclose(k.matrix(), [[k.fl_x, 0, 200], [0, k.fl_y, 150], [0, 0, 1]])


def test_novel_views_are_off_the_training_path() -> None:
    traj = orbit(4.0, 30.0)
    views = novel_views(4.0, 8)
    assert views.shape == (8, 4, 4)
    gaps = np.linalg.norm(views[:, None, :3, 3] - traj.poses[None, :, :3, 3], axis=-1).min(1)
    assert (gaps > 0.5).all()  # other elevations (15°, 45°): at least ~1 scene unit from any training pose
    elevations = np.degrees(np.arcsin(views[:, 2, 3] / 4.0))
    np.testing.assert_allclose(sorted(set(np.round(elevations, 6))), [15.0, 45.0])
    np.testing.assert_allclose(-views[:, :3, 2], -views[:, :3, 3] / 4.0, atol=1e-12)  # look at the centre
    assert novel_views(4.0, 0).shape == (0, 4, 4)


@pytest.mark.parametrize(
    ("elevation", "sweep", "expected"),
    [(30, 0, (15, 45)), (30, 30, (0, 60)), (60, 0, (45, 75)), (80, 0, (65, 50)), (-80, 0, (-50, -65))],
)
def test_held_out_views_keep_off_a_sweeping_path(elevation: float, sweep: float, expected: tuple) -> None:
    """The held-out elevations lie 15° outside the path's elevation range (both on one side near a pole), so
    every test camera stays ~1 scene unit from every training camera, with an elevation sweep too."""
    from spikenerf.scenes.trajectory import held_out_elevations

    both = held_out_elevations(elevation, sweep)
    np.testing.assert_allclose(both, expected)
    traj = orbit(4.0, elevation, elevation_sweep_deg=sweep)
    views = novel_views(4.0, 8, both)
    gaps = np.linalg.norm(views[:, None, :3, 3] - traj.poses[None, :, :3, 3], axis=-1).min(1)
    assert (gaps > 1.0).all()


def test_held_out_views_without_room_and_a_polar_orbit_are_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.cli import main
    from spikenerf.scenes.trajectory import held_out_elevations

    with pytest.raises(InputError, match="no room for held-out views") as err:
        held_out_elevations(0.0, 160.0)
    assert err.value.params == ("elevation",)
    base = ["simulate", "--scene", "analytic-orbs", "--frames", "20", "--width", "8", "--height", "8"]
    for extra in (["--elevation", "90"], ["--elevation", "0", "--elevation-sweep", "160"]):
        with pytest.raises(SystemExit) as exit_:
            main([*base, "--out", str(tmp_path / "out"), "--no-progress", *extra])
        assert exit_.value.code == 2 and not (tmp_path / "out").exists()


def test_look_at_straight_down_is_finite_and_bad_orbits_are_input_errors() -> None:
    pose = look_at(np.array([0.0, 0.0, 5.0]), np.zeros(3))
    assert np.isfinite(pose).all() and np.linalg.det(pose[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(-pose[:3, 2], [0, 0, -1])
    with pytest.raises(InputError):
        look_at(np.ones(3), np.ones(3))
    with pytest.raises(InputError):
        orbit(-1.0, 30.0)
    with pytest.raises(InputError):
        orbit(4.0, 30.0, duration=1e-6)


def test_slicing_keeps_steps_and_times() -> None:
    traj = orbit(4.0, 30.0, duration=0.001)
    part = traj[10:20]
    np.testing.assert_array_equal(part.steps, np.arange(10, 20))
    np.testing.assert_allclose(part.times, np.arange(10, 20) / 40000.0)
    assert len(part) == 10 and part.fps == traj.fps


@settings(max_examples=30, deadline=None)
@given(
    radius=st.floats(0.5, 20.0),
    elevation=st.floats(-80.0, 80.0),
    turns=st.floats(0.1, 3.0),
    steps=st.integers(1, 60),
)
def test_orbit_properties(radius: float, elevation: float, turns: float, steps: int) -> None:
    traj = orbit(radius, elevation, turns=turns, duration=steps / 40000.0)
    assert len(traj) == steps
    eyes = traj.poses[:, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(eyes, axis=1), radius, rtol=1e-9)
    np.testing.assert_allclose(-traj.poses[:, :3, 2], -eyes / radius, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(traj.poses[:, :3, :3]), 1.0, atol=1e-9)


def test_image_motion_of_a_sideways_camera_is_focal_times_shift_over_depth() -> None:
    k = Intrinsics.from_fov(200, 100, 0.8)
    poses = np.tile(np.eye(4), (5, 1, 1))
    poses[:, 0, 3] = 0.01 * np.arange(5)  # 0.01 to the right a step, looking down −z
    box = np.array([[-0.5, -0.3, -4.001], [0.5, 0.3, -3.999]])  # a thin slab 4 in front
    assert image_motion(poses, k, box) == pytest.approx(k.fl_x * 0.01 / 4.0, rel=1e-3)
    assert math.isnan(image_motion(poses[:2], k, np.add(box, [0, 0, 10])))  # behind the camera: nothing seen
    with pytest.raises(InputError, match="poses"):
        image_motion(poses[:1], k, box)


def test_image_motion_of_held_poses_is_spread_over_the_steps_they_are_held() -> None:
    """An image sequence held for 4 steps a frame (``--steps-per-frame 4``) moves a frame's worth every 4th
    step: 0 px a step by consecutive pairs (a median of zeros), which sized spike-integral's windows as if
    the camera stood still. A camera that stands still is still 0."""
    k = Intrinsics.from_fov(200, 100, 0.8)
    frames = np.tile(np.eye(4), (10, 1, 1))
    frames[:, 0, 3] = 0.04 * np.arange(10)  # 0.04 a frame
    held = np.repeat(frames, 4, axis=0)
    box = np.array([[-0.5, -0.3, -4.001], [0.5, 0.3, -3.999]])
    assert image_motion(held, k, box) == pytest.approx(k.fl_x * 0.01 / 4.0, rel=1e-3)
    assert image_motion(np.tile(np.eye(4), (6, 1, 1)), k, box) == 0.0


def test_image_motion_doubles_with_the_image_size_on_an_orbit() -> None:
    traj = orbit(4.0, 30.0)
    box = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    small = image_motion(traj.poses, Intrinsics.from_fov(200, 200, 0.69), box)
    assert 0.1 < small < 1.0
    assert image_motion(traj.poses, Intrinsics.from_fov(400, 400, 0.69), box) == pytest.approx(
        2 * small, rel=0.02
    )

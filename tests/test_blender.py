"""The Blender backend: built-in scenes, linear white-background frames, calibration, camera convention,
user .blend files and errors. Tests that render need the optional ``bpy`` extra and skip without it."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spikenerf.core.errors import InputError
from spikenerf.scenes.blender import (
    BUILTIN_SCENES,
    DEFAULT_CAMERA_ANGLE_X,
    SUN_DIRECTION,
    BlenderSource,
    default_orbit_radius,
    resolve_scene,
    scene_extent,
)
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.trajectory import Intrinsics, Trajectory, orbit

SIZE, SPP = 32, 4


@pytest.fixture(scope="module")
def bpy():
    return pytest.importorskip(
        "bpy", reason="the Blender backend needs the optional extra spikenerf[blender]"
    )


def _orbit_for(scene: str | Path, steps: int = 8) -> Trajectory:
    box = scene_extent(scene)
    return orbit(default_orbit_radius(box), 30.0, duration=steps / 40000, center=tuple(box.mean(0)))


# ------------------------------------------------------------------------------------------ without bpy
def test_package_imports_without_bpy_and_lists_scenes() -> None:
    code = (
        "import sys; sys.modules['bpy'] = None\n"
        "import spikenerf.scenes.blender as b\n"
        "assert 'bpy' not in [m for m, v in sys.modules.items() if v is not None]\n"
        "print(len(b.BUILTIN_SCENES))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) >= 6


def test_constructing_without_bpy_raises_install_hint(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "bpy", None)  # makes `import bpy` fail like a missing install
    traj = orbit(4.0, 30.0, duration=2 / 40000)
    with pytest.raises(InputError, match=r"Blender is not installed: pip install 'spikenerf\[blender\]'"):
        BlenderSource("bricks", SIZE, SIZE, traj, np.zeros((0, 4, 4)))


def test_builtin_catalog_covers_the_paper_scene_kinds() -> None:
    assert {"bricks", "plant", "materials", "toy", "food", "drums"} <= set(BUILTIN_SCENES)
    assert all(isinstance(d, str) and d and "\n" not in d for d in BUILTIN_SCENES.values())


def test_default_orbit_radius_fits_the_bounding_sphere() -> None:
    box = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    r = default_orbit_radius(box, DEFAULT_CAMERA_ANGLE_X, margin=1.0)
    assert r == pytest.approx(math.sqrt(3) / math.sin(DEFAULT_CAMERA_ANGLE_X / 2))
    shifted = default_orbit_radius(box + 5.0, DEFAULT_CAMERA_ANGLE_X, margin=1.0)
    assert shifted == pytest.approx(r)  # depends on the size only, not the position
    assert default_orbit_radius(box * 2, DEFAULT_CAMERA_ANGLE_X, margin=1.0) == pytest.approx(2 * r)
    with pytest.raises(InputError, match="scene_box"):
        default_orbit_radius(np.array([[1.0, 0, 0], [0.0, 0, 0]]))


def test_resolve_scene_rejects_unknown_names_and_missing_files(tmp_path: Path) -> None:
    assert resolve_scene("drums") == ("builtin", "drums", None)
    with pytest.raises(InputError, match="unknown scene 'nope'"):
        resolve_scene("nope")
    with pytest.raises(InputError, match=r"no such \.blend file"):
        resolve_scene(tmp_path / "missing.blend")


# --------------------------------------------------------------------------------------------- with bpy
def test_frames_are_linear_on_white_with_the_object_in_the_centre(bpy, capfd) -> None:
    traj = _orbit_for("toy")
    src = BlenderSource("toy", SIZE, SIZE, traj, traj.poses[:1], spp=SPP, progress=False)
    assert src.intrinsics == Intrinsics.from_fov(SIZE, SIZE, DEFAULT_CAMERA_ANGLE_X)
    assert src.scene_box.shape == (2, 3) and src.name == "toy"
    capfd.readouterr()
    frames = list(src.frames([3, 0, 3]))
    assert capfd.readouterr().out == ""  # Blender's render chatter is silenced
    assert len(frames) == 3
    for f in frames:
        assert f.shape == (SIZE, SIZE, 3) and f.dtype == np.float32 and np.all(np.isfinite(f))
        corners = np.concatenate([f[:2, :2], f[:2, -2:], f[-2:, :2], f[-2:, -2:]]).reshape(-1, 3)
        np.testing.assert_allclose(corners, 1.0, atol=0.02)
        centre = f[SIZE // 2 - 4 : SIZE // 2 + 4, SIZE // 2 - 4 : SIZE // 2 + 4]
        assert centre.mean() < 0.8  # the object, not the white background
    assert np.abs(frames[0] - frames[2]).max() < 0.03  # same pose, same seed: same image (denoiser noise)
    assert np.abs(frames[0] - frames[1]).mean() > 0.01  # another pose renders differently
    poses, images = src.test_views()
    assert poses.shape == (1, 4, 4) and images.shape == (1, SIZE, SIZE, 3)
    assert np.abs(images[0] - frames[1]).max() < 0.03  # the test view is step 0's pose
    with pytest.raises(InputError, match="not on the trajectory"):
        next(src.frames([99]))


@pytest.mark.parametrize("name", sorted(BUILTIN_SCENES))
def test_every_builtin_scene_builds_centred_and_renders(bpy, name: str) -> None:
    box = scene_extent(name)
    assert np.all(box[0] < box[1]) and np.all(box[1] - box[0] > 0.2)
    assert np.all(np.abs(box) < 1.3), box  # roughly inside [-1, 1]^3
    traj = _orbit_for(name, steps=2)
    frame = next(BlenderSource(name, 8, 8, traj, spp=1, denoise="NONE", progress=False).frames([0]))
    assert frame.shape == (8, 8, 3) and np.all(np.isfinite(frame)) and frame.min() < 0.9


def _save_user_blend(bpy, path: Path, sphere_at: np.ndarray, light: bool = False) -> None:
    """A white diffuse plane facing the default sun, a small black sphere on it, a camera, a far-away object
    disabled for rendering, and a light only if ``light``."""
    import bmesh
    from mathutils import Matrix, Vector

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene

    def add(name, build, color, matrix):
        mesh = bpy.data.meshes.new(name)
        bm = bmesh.new()
        build(bm)
        bm.to_mesh(mesh)
        bm.free()
        mat = bpy.data.materials.new(name)
        nodes = mat.node_tree.nodes
        diffuse = nodes.new("ShaderNodeBsdfDiffuse")
        diffuse.inputs["Color"].default_value = (*color, 1.0)
        mat.node_tree.links.new(diffuse.outputs[0], nodes["Material Output"].inputs["Surface"])
        mesh.materials.append(mat)
        obj = bpy.data.objects.new(name, mesh)
        obj.matrix_world = matrix
        scene.collection.objects.link(obj)

    rot = Vector(SUN_DIRECTION).to_track_quat("Z", "Y").to_matrix().to_4x4()
    add("plane", lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=2.0), (1, 1, 1), rot)
    add(
        "ball",
        lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=16, v_segments=8, radius=0.1),
        (0, 0, 0),
        Matrix.Translation(Vector(sphere_at.tolist())),
    )
    add("hidden", lambda bm: bmesh.ops.create_cube(bm, size=1.0), (1, 0, 0), Matrix.Translation((9, 9, 9)))
    scene.objects["hidden"].hide_render = True
    cam = bpy.data.objects.new("user_camera", bpy.data.cameras.new("user_camera"))
    scene.collection.objects.link(cam)
    if light:
        scene.collection.objects.link(
            bpy.data.objects.new("user_lamp", bpy.data.lights.new("user_lamp", "POINT"))
        )
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)


def test_user_blend_round_trip_calibration_and_camera_convention(bpy, tmp_path: Path) -> None:
    sun = np.asarray(SUN_DIRECTION)
    in_plane = np.cross(sun, [0.0, 0.0, 1.0])
    in_plane /= np.linalg.norm(in_plane)
    ball = 0.9 * in_plane + 0.6 * np.cross(in_plane, sun) + 0.1 * sun  # on the plane, off both image axes
    path = tmp_path / "user.blend"
    _save_user_blend(bpy, path, ball)
    pose = look_at(4.0 * sun, np.zeros(3))  # looking along the sun: the plane faces camera and sun
    traj = Trajectory(pose[None], np.zeros(1), np.zeros(1, dtype=np.int64), 40000.0)
    size = 64
    src = BlenderSource(path, size, size, traj, spp=16, progress=False)
    assert src.name == "user"
    assert np.all(src.scene_box[0] < -0.5) and np.all(src.scene_box[1] > 0.5)
    assert np.all(src.scene_box[1] < 3.0)  # the object disabled for rendering does not count
    frame = next(src.frames([0]))
    cameras = [o.name for o in bpy.data.objects if o.type == "CAMERA"]
    assert cameras == ["spikenerf_camera"]  # the file's camera is dropped
    assert "spikenerf_sun" in bpy.data.objects  # no light in the file: the default light is added
    gray = frame.mean(-1)
    # projection of the ball's centre with the pinhole intrinsics (rows go down, OpenGL camera y goes up)
    k = src.intrinsics
    cam = np.linalg.inv(pose) @ np.append(ball, 1.0)
    u, v = k.cx + k.fl_x * cam[0] / -cam[2], k.cy - k.fl_y * cam[1] / -cam[2]
    rows, cols = np.nonzero(gray < 0.3)
    assert len(rows) > 4
    assert abs(cols.mean() + 0.5 - u) < 0.5 and abs(rows.mean() + 0.5 - v) < 0.5, (
        cols.mean(),
        rows.mean(),
        u,
        v,
    )
    # calibration: white diffuse facing the default light renders 1.0 (sun 0.8 + world 0.2)
    yy, xx = np.mgrid[:size, :size] + 0.5
    far = (xx - u) ** 2 + (yy - v) ** 2 > 12.0**2
    assert np.median(gray[far]) == pytest.approx(1.0, abs=0.03)


def test_user_blend_with_its_own_light_keeps_it(bpy, tmp_path: Path) -> None:
    path = tmp_path / "lit.blend"
    _save_user_blend(bpy, path, np.zeros(3), light=True)
    scene_extent(path)
    lights = sorted(o.name for o in bpy.data.objects if o.type == "LIGHT")
    assert lights == ["user_lamp"]  # no default sun added


def test_unreadable_blend_files_raise_input_error(bpy, tmp_path: Path) -> None:
    traj = orbit(4.0, 30.0, duration=2 / 40000)
    with pytest.raises(InputError, match=r"no such \.blend file"):
        BlenderSource(tmp_path / "missing.blend", SIZE, SIZE, traj)
    junk = tmp_path / "junk.blend"
    junk.write_bytes(b"not a blend file at all")
    with pytest.raises(InputError, match=r"not a \.blend file") as err:
        BlenderSource(junk, SIZE, SIZE, traj)
    assert err.value.path == str(junk)
    truncated = tmp_path / "truncated.blend"
    truncated.write_bytes(b"BLENDER-v500RENDH\x00\x00\x00")
    with pytest.raises(InputError, match="Blender cannot read this file"):
        BlenderSource(truncated, SIZE, SIZE, traj)

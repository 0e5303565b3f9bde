"""Image-sequence import: hold/interpolate, ranges, resampling, colour, 16-bit PNG, eval views, errors."""

from __future__ import annotations

import json
import math
import struct
import zlib
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from helpers import edit_json
from spikenerf.core.color import srgb_decode
from spikenerf.core.errors import InputError, parse_range
from spikenerf.core.png16 import decode_png16
from spikenerf.scenes.distortion import Distortion
from spikenerf.scenes.image_io import read_image, resample
from spikenerf.scenes.poses import interpolate_poses, matrix_to_quaternion, quaternion_to_matrix, slerp
from spikenerf.scenes.scene_box import estimate_scene_box
from spikenerf.scenes.sequence import SequenceSource, step_schedule
from spikenerf.scenes.sequence_frames import OPEN_END
from spikenerf.scenes.trajectory import orbit

N, SIZE, ANGLE = 6, 8, 0.6


def _pixels(i: int, size: int = SIZE) -> np.ndarray:
    """(size, size, 4) uint8 RGBA for frame i: a per-frame level, a gradient, a transparent corner."""
    img = np.zeros((size, size, 4), np.uint8)
    img[..., 0] = 20 + 30 * i
    img[..., 1] = np.arange(size, dtype=np.uint8)[None, :] * 20
    img[..., 2] = 188
    img[..., 3] = 255
    img[0, 0, 3] = 0
    return img


def _write_sequence(
    root: Path, n: int = N, size: int = SIZE, name: str = "transforms.json", **extra: object
) -> Path:
    """A tiny sequence: n RGBA PNGs in root/train and orbit poses, NeRF-synthetic style ("./train/r_i")."""
    (root / "train").mkdir(parents=True, exist_ok=True)
    poses = orbit(4.0, 30.0, duration=n / 40000.0).poses
    frames = []
    for i in range(n):
        iio.imwrite(root / "train" / f"r_{i}.png", _pixels(i, size))
        frames.append({"file_path": f"./train/r_{i}", "transform_matrix": poses[i].tolist()})
    meta = {"camera_angle_x": ANGLE, "frames": frames, **extra}
    (root / name).write_text(json.dumps(meta))
    return root / name


def _expected(i: int) -> np.ndarray:
    """The linear RGB on white that frame i should load as."""
    x = _pixels(i).astype(np.float64) / 255.0
    rgb = srgb_decode(x[..., :3])
    return (rgb * x[..., 3:] + 1 - x[..., 3:]).astype(np.float32)


@pytest.fixture
def tiny(tmp_path: Path) -> Path:
    return _write_sequence(tmp_path / "tiny")


# ---------------------------------------------------------------------------------------------- ranges
def test_parse_range() -> None:
    assert parse_range("2:5", "sequence_range") == slice(2, 5)
    assert parse_range(" 3: ", "sequence_range") == slice(3, None)
    assert parse_range(":4", "sequence_range") == slice(None, 4)
    assert parse_range("-3:-1", "sequence_range") == slice(-3, -1)
    for bad in ["abc", "3", "1:2:3", "a:b", "5:2", "4:4", "-1:-3"]:
        with pytest.raises(InputError, match="sequence_range") as err:
            parse_range(bad, "sequence_range")
        assert err.value.params == ("sequence_range",)


def test_range_selects_frames(tiny: Path) -> None:
    src = SequenceSource(tiny, frame_range=(2, 5))
    assert src.frame_indices.tolist() == [2, 3, 4] and len(src.trajectory) == 3
    np.testing.assert_allclose(next(src.frames([0])), _expected(2), atol=1e-6)
    tail = SequenceSource(tiny, frame_range=parse_range("-2:", "sequence_range"))
    assert tail.frame_indices.tolist() == [4, 5]
    np.testing.assert_array_equal(tail.trajectory.poses[1], SequenceSource(tiny).frame_poses[5])
    assert SequenceSource(tiny, frame_range=slice(2, 5)).frame_indices.tolist() == [2, 3, 4]
    for empty in [(5, -3), (6, OPEN_END), slice(6, None)]:
        with pytest.raises(InputError, match="selects no frames"):
            SequenceSource(tiny, frame_range=empty)
    for past, value in [
        ((0, 100), 100),
        ((10, OPEN_END), 10),
        (slice(-100, 2), -100),
    ]:  # not clipped silently
        with pytest.raises(InputError, match=f"{value} is outside the 6 listed frames") as err:
            SequenceSource(tiny, frame_range=past)
        assert err.value.params == ("frame_range",)


# ------------------------------------------------------------------------------------- hold/interpolate
def test_hold_repeats_each_frame_and_pose(tiny: Path) -> None:
    src = SequenceSource(tiny, steps_per_frame=3, fps=1000.0)
    traj = src.trajectory
    assert len(traj) == N * 3 and traj.fps == 1000.0
    np.testing.assert_array_equal(traj.steps, np.arange(N * 3))
    np.testing.assert_allclose(traj.times, np.arange(N * 3) / 1000.0)
    frames = list(src.frames(range(N * 3)))
    assert all(f.shape == (SIZE, SIZE, 3) and f.dtype == np.float32 for f in frames)
    for k, frame in enumerate(frames):
        np.testing.assert_allclose(frame, _expected(k // 3), atol=1e-6)
        np.testing.assert_array_equal(traj.poses[k], src.frame_poses[k // 3])
    assert src.name == "tiny" and src.intrinsics.width == SIZE
    assert math.isclose(src.intrinsics.camera_angle_x, ANGLE)


def test_interpolate_blends_frames_and_poses(tiny: Path) -> None:
    src = SequenceSource(tiny, steps_per_frame=4, interpolate=True)
    frames = list(src.frames(range(N * 4)))
    poses = src.trajectory.poses
    for i in range(N - 1):
        np.testing.assert_array_equal(poses[4 * i], src.frame_poses[i])  # endpoints exact
        np.testing.assert_allclose(frames[4 * i], _expected(i), atol=1e-6)
        np.testing.assert_allclose(
            frames[4 * i + 1], 0.75 * _expected(i) + 0.25 * _expected(i + 1), atol=1e-6
        )
        mid = poses[4 * i + 2]
        np.testing.assert_allclose(
            mid[:3, 3], 0.5 * (src.frame_poses[i][:3, 3] + src.frame_poses[i + 1][:3, 3])
        )
        rot0, rot1, rotm = src.frame_poses[i][:3, :3], src.frame_poses[i + 1][:3, :3], mid[:3, :3]
        np.testing.assert_allclose(rotm.T @ rotm, np.eye(3), atol=1e-12)
        full, half = _angle(rot0, rot1), _angle(rot0, rotm)
        assert full > 0.1 and math.isclose(half, full / 2, rel_tol=1e-9)
    for k in range(4 * (N - 1), 4 * N):  # the last frame is held
        np.testing.assert_allclose(frames[k], _expected(N - 1), atol=1e-6)
        np.testing.assert_array_equal(poses[k], src.frame_poses[N - 1])


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1)))


def test_step_schedule() -> None:
    frame, nxt, alpha = step_schedule(3, 2, interpolate=True)
    assert frame.tolist() == [0, 0, 1, 1, 2, 2] and nxt.tolist() == [1, 1, 2, 2, 2, 2]
    assert alpha.tolist() == [0, 0.5, 0, 0.5, 0, 0]
    assert step_schedule(3, 2, interpolate=False)[2].tolist() == [0] * 6


def test_quaternions_round_trip_and_slerp() -> None:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    rots = quaternion_to_matrix(q)
    flips = np.array([np.diag(d) for d in ([1, -1, -1], [-1, 1, -1], [-1, -1, 1])], dtype=float)
    rots = np.concatenate([rots, flips, np.eye(3)[None]])  # 180° turns: trace = −1
    np.testing.assert_allclose(quaternion_to_matrix(matrix_to_quaternion(rots)), rots, atol=1e-12)
    q0, q1 = matrix_to_quaternion(rots[:100]), matrix_to_quaternion(rots[100:200])
    np.testing.assert_allclose(slerp(q0, q1, 0.0), q0, atol=1e-12)
    assert np.allclose(np.abs(np.sum(slerp(q0, q1, 1.0) * q1, -1)), 1.0)
    p0, p1 = np.tile(np.eye(4), (2, 1, 1)), np.tile(np.eye(4), (2, 1, 1))
    p1[:, :3, :3] = quaternion_to_matrix(np.array([math.cos(0.5), 0, 0, math.sin(0.5)]))  # 1 rad about z
    p1[:, :3, 3] = [2.0, 0.0, -4.0]
    mid = interpolate_poses(p0, p1, np.array([0.25, 1.0]))
    assert math.isclose(_angle(np.eye(3), mid[0, :3, :3]), 0.25, rel_tol=1e-9)
    np.testing.assert_allclose(mid[0, :3, 3], [0.5, 0.0, -1.0])
    np.testing.assert_array_equal(mid[1], p1[1])


# -------------------------------------------------------------------------------------- resampling
def test_resample_scales_images_and_intrinsics(tiny: Path) -> None:
    native = SequenceSource(tiny)
    half = SequenceSource(tiny, width=4)
    assert (half.intrinsics.width, half.intrinsics.height) == (4, 4)
    assert math.isclose(half.intrinsics.fl_x, native.intrinsics.fl_x / 2) and half.intrinsics.cx == 2.0
    frame = next(half.frames([0]))
    np.testing.assert_allclose(frame, _expected(0).reshape(4, 2, 4, 2, 3).mean(axis=(1, 3)), atol=1e-6)
    odd = SequenceSource(tiny, width=3, height=5)
    frame = next(odd.frames([1]))
    assert frame.shape == (5, 3, 3) and odd.intrinsics.height == 5
    assert math.isclose(odd.intrinsics.fl_y, native.intrinsics.fl_y * 5 / 8)
    np.testing.assert_allclose(frame.mean(axis=(0, 1)), _expected(1).mean(axis=(0, 1)), atol=0.02)
    assert resample(np.ones((4, 4, 3), np.float32), 9, 7).shape == (7, 9, 3)
    with pytest.raises(InputError, match=r"^width: expected a positive integer"):
        SequenceSource(tiny, width=0)


# ------------------------------------------------------------------------------------------- colour
def test_rgba_composite_and_srgb_linearisation(tmp_path: Path) -> None:
    img = np.zeros((2, 2, 4), np.uint8)
    img[0, 0] = [188, 188, 188, 255]  # mid gray → ≈ 0.5 linear
    img[0, 1] = [0, 0, 0, 0]  # transparent → white
    img[1, 0] = [0, 0, 0, 128]  # half-covered black → 1 − a
    img[1, 1] = [255, 0, 0, 255]
    iio.imwrite(tmp_path / "a.png", img)
    rgba = read_image(tmp_path / "a.png")
    assert rgba.shape == (2, 2, 4) and math.isclose(rgba[0, 0, 0], 0.5029, abs_tol=1e-3)
    seq = tmp_path / "s"
    seq.mkdir()
    iio.imwrite(seq / "f.png", img)
    pose = np.eye(4)
    pose[2, 3] = 3.0
    (seq / "t.json").write_text(
        json.dumps(
            {"camera_angle_x": 1.0, "frames": [{"file_path": "f.png", "transform_matrix": pose.tolist()}]}
        )
    )
    frame = next(SequenceSource(seq / "t.json").frames([0]))
    assert abs(frame[0, 0, 1] - 0.5) < 0.01 and np.allclose(frame[0, 1], 1.0)
    np.testing.assert_allclose(frame[1, 0], 1 - 128 / 255, atol=1e-6)
    np.testing.assert_allclose(frame[1, 1], [1.0, 0.0, 0.0], atol=1e-6)
    iio.imwrite(tmp_path / "g.png", np.full((2, 2), 188, np.uint8))  # gray → repeated to RGB
    np.testing.assert_allclose(read_image(tmp_path / "g.png")[0, 0], [0.5029, 0.5029, 0.5029, 1.0], atol=1e-3)


def test_float_npy_is_linear(tmp_path: Path) -> None:
    np.save(tmp_path / "f.npy", np.full((2, 3, 3), 0.25, np.float32))
    rgba = read_image(tmp_path / "f.npy")
    assert rgba.shape == (2, 3, 4)
    np.testing.assert_array_equal(rgba[..., :3], 0.25)
    np.save(tmp_path / "i.npy", np.zeros((2, 2, 3), np.int32))
    with pytest.raises(InputError, match="linear floats"):
        read_image(tmp_path / "i.npy")


def _png16(path: Path, a: np.ndarray) -> None:
    """Write a 16-bit PNG cycling through all five scanline filters (None, Sub, Up, Average, Paeth)."""
    h, w, c = a.shape
    data = a.astype(">u2").view(np.uint8).reshape(h, w * 2 * c).astype(np.int32)
    bpp, rows = 2 * c, []
    for y in range(h):
        x = data[y]
        left = np.concatenate([np.zeros(bpp, np.int32), x[:-bpp]])
        up = data[y - 1] if y else np.zeros_like(x)
        upleft = np.concatenate([np.zeros(bpp, np.int32), up[:-bpp]])
        p = left + up - upleft
        pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - upleft)
        paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
        kind = y % 5
        pred = [np.zeros_like(x), left, up, (left + up) // 2, paeth][kind]
        rows.append(bytes([kind]) + ((x - pred) % 256).astype(np.uint8).tobytes())

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ctype = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, ctype, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(b"".join(rows)))
        + chunk(b"IEND", b"")
    )


@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_png16_decodes_exactly(tmp_path: Path, channels: int) -> None:
    a = np.random.default_rng(channels).integers(0, 65536, size=(11, 7, channels), dtype=np.uint16)
    _png16(tmp_path / "a.png", a)
    np.testing.assert_array_equal(decode_png16((tmp_path / "a.png").read_bytes(), tmp_path / "a.png"), a)
    rgba = read_image(tmp_path / "a.png")
    colour = a[..., 0] if channels <= 2 else a[..., 2]
    np.testing.assert_allclose(rgba[..., 2], srgb_decode(colour / 65535.0), atol=1e-6)


# --------------------------------------------------------------------------------- eval views, box
def test_eval_views(tiny: Path) -> None:
    root = tiny.parent
    _write_sequence(root, n=2, name="transforms_test.json")
    assert [a.shape for a in SequenceSource(tiny).test_views()] == [(0, 4, 4), (0, SIZE, SIZE, 3)]
    src = SequenceSource(tiny, width=4, eval_views=root / "transforms_test.json")
    poses, images = src.test_views()
    assert poses.shape == (2, 4, 4) and images.shape == (2, 4, 4, 3) and images.dtype == np.float32
    np.testing.assert_allclose(images[1], _expected(1).reshape(4, 2, 4, 2, 3).mean(axis=(1, 3)), atol=1e-6)
    edit_json(root / "transforms_test.json", lambda m: m.update(camera_angle_x=0.9))
    with pytest.raises(InputError, match="another camera"):
        SequenceSource(tiny, eval_views=root / "transforms_test.json")


def test_a_distorted_sequence_keeps_its_lens_and_its_eval_views_must_share_it(tiny: Path) -> None:
    root, lens = tiny.parent, {"camera_model": "OPENCV", "k1": -0.05}
    edit_json(tiny, lambda m: m.update(lens))
    assert SequenceSource(tiny, width=4).intrinsics.distortion == Distortion(k1=-0.05)
    _write_sequence(root, n=2, name="transforms_test.json")
    with pytest.raises(InputError, match=r"another lens: none, the sequence's is OPENCV k1=-0\.05"):
        SequenceSource(tiny, eval_views=root / "transforms_test.json")
    edit_json(root / "transforms_test.json", lambda m: m.update(lens))
    assert SequenceSource(tiny, eval_views=root / "transforms_test.json").test_views()[0].shape == (2, 4, 4)


def test_scene_box(tiny: Path) -> None:
    for centre in [(0.0, 0.0, 0.0), (1.0, -2.0, 0.5)]:
        box = estimate_scene_box(orbit(4.0, 20.0, duration=8 / 40000, center=centre).poses)
        np.testing.assert_allclose(box.mean(0), centre, atol=1e-9)
        np.testing.assert_allclose(box[1] - box[0], 4.0, atol=1e-9)  # 2 × 0.5 × radius
    forward = np.tile(np.eye(4), (3, 1, 1))
    forward[:, 0, 3] = [0.0, 0.1, 0.2]  # parallel axes: a finite guess ahead of the cameras
    box = estimate_scene_box(forward)
    assert np.isfinite(box).all() and box.mean(0)[2] < 0
    np.testing.assert_allclose(SequenceSource(tiny).scene_box.mean(0), 0.0, atol=1e-6)
    given = [[-1, -1, -1], [1, 2, 3]]
    edit_json(tiny, lambda m: m.update(scene_box=given))
    np.testing.assert_array_equal(SequenceSource(tiny).scene_box, given)
    edit_json(tiny, lambda m: m.update(scene_box=[[1, 1, 1], [0, 0, 0]]))
    with pytest.raises(InputError, match="'scene_box'"):
        SequenceSource(tiny)


def test_nerfstudio_intrinsics(tiny: Path) -> None:
    def ns(m: dict) -> None:
        del m["camera_angle_x"]
        m.update(fl_x=10.0, fl_y=12.0, cx=4.5, cy=3.5, w=SIZE, h=SIZE)

    cam = SequenceSource(edit_json(tiny, ns), width=4).intrinsics
    assert (cam.fl_x, cam.fl_y, cam.cx, cam.cy) == (5.0, 6.0, 2.25, 1.75)


# ----------------------------------------------------------------------------------------- errors
def _set_frame(i: int, **fields: object):
    return lambda m: m["frames"][i].update(fields)


ERRORS = {
    "malformed JSON": lambda p: p.write_text("{frames: ["),
    "expected a JSON object": lambda p: p.write_text("[1, 2]"),
    "field 'frames'": lambda p: edit_json(p, lambda m: m.pop("frames")),
    "non-empty list": lambda p: edit_json(p, lambda m: m.update(frames=[])),
    r"frames\[2\]: missing field 'transform_matrix'": lambda p: edit_json(
        p, lambda m: m["frames"][2].pop("transform_matrix")
    ),
    r"frames\[1\]: missing field 'file_path'": lambda p: edit_json(
        p, lambda m: m["frames"][1].pop("file_path")
    ),
    r"frames\[3\].transform_matrix: expected a 4×4 matrix": lambda p: edit_json(
        p, _set_frame(3, transform_matrix=[[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    ),
    r"frames\[0\].transform_matrix: expected a 4×4 list": lambda p: edit_json(
        p, _set_frame(0, transform_matrix=[[1, 2], [3]])
    ),
    "NaN": lambda p: edit_json(
        p, lambda m: m["frames"][4]["transform_matrix"][0].__setitem__(3, float("nan"))
    ),
    "not a rotation": lambda p: edit_json(
        p, _set_frame(1, transform_matrix=(np.eye(4) * [2, 2, 2, 1]).tolist())
    ),
    "absolute paths": lambda p: edit_json(p, _set_frame(0, file_path=str(p.parent / "train" / "r_0.png"))),
    "outside the folder": lambda p: (
        iio.imwrite(p.parent.parent / "secret.png", _pixels(0)),
        edit_json(p, _set_frame(0, file_path="train/../../secret.png")),
    ),
    r"frames\[5\].file_path: image './train/nope' not found": lambda p: edit_json(
        p, _set_frame(5, file_path="./train/nope")
    ),
    "must have the same size": lambda p: iio.imwrite(p.parent / "train" / "r_3.png", _pixels(0, 4)),
    "missing camera": lambda p: edit_json(p, lambda m: m.pop("camera_angle_x")),
    "'camera_angle_x'": lambda p: edit_json(p, lambda m: m.update(camera_angle_x="wide")),
    "images are 8×8": lambda p: edit_json(p, lambda m: m.update(w=16)),
    "per-frame cameras": lambda p: edit_json(p, _set_frame(2, camera_angle_x=0.7)),
    "fields 'camera_model', 'k1': the OPENCV k1=-2 lens is not invertible": lambda p: edit_json(
        p, lambda m: m.update(camera_model="OPENCV", k1=-2)
    ),
    "field 'p1': p1 must be 0 for OPENCV_FISHEYE": lambda p: edit_json(
        p, lambda m: m.update(camera_model="OPENCV_FISHEYE", p1=0.01)
    ),
    "'EQUIRECTANGULAR' is not supported": lambda p: edit_json(
        p, lambda m: m.update(camera_model="EQUIRECTANGULAR")
    ),
    "cannot read image": lambda p: (p.parent / "train" / "r_2.png").write_bytes(b"not a png at all"),
}


@pytest.mark.parametrize("expected", list(ERRORS))
def test_bad_input_raises_input_error_naming_file(tiny: Path, expected: str) -> None:
    ERRORS[expected](tiny)
    with pytest.raises(InputError, match=expected) as err:
        src = SequenceSource(tiny)
        list(src.frames(range(len(src.trajectory))))
    assert str(tiny.parent) in str(err.value)


def test_other_bad_arguments(tmp_path: Path, tiny: Path) -> None:
    with pytest.raises(InputError, match="transforms file not found"):
        SequenceSource(tmp_path / "missing.json")
    with pytest.raises(InputError, match="steps_per_frame: expected an integer"):
        SequenceSource(tiny, steps_per_frame=0)
    with pytest.raises(InputError, match=r"^steps_per_frame: this needs about .* of memory") as err:
        SequenceSource(tiny, steps_per_frame=10**15)  # refused before its schedule is allocated
    assert err.value.params == ("steps_per_frame", "no_limits")
    with pytest.raises(InputError, match=r"^fps: expected a positive number"):
        SequenceSource(tiny, fps=-1.0)
    with pytest.raises(InputError, match="transforms file not found"):
        SequenceSource(tiny, eval_views=tmp_path / "nope.json")


# ------------------------------------------------------------------------------------------ end to end
def test_simulate_cli_builds_dataset_from_sequence(tiny: Path, tmp_path: Path) -> None:
    from spikenerf.cli import main
    from spikenerf.data.dataset import load_dataset

    root = tiny.parent
    _write_sequence(root, n=2, name="transforms_test.json")
    out = tmp_path / "out"
    args = ["simulate", "--sequence", str(tiny), "--out", str(out), "--sequence-range", "1:5"]
    args += ["--steps-per-frame", "3", "--interpolate", "--width", "4", "--no-progress"]
    main([*args, "--eval-views", str(root / "transforms_test.json"), "--blur-fps", "10000"])
    data = load_dataset(out)
    assert len(data.trajectory) == 4 * 3 and (data.intrinsics.width, data.intrinsics.height) == (4, 4)
    source = SequenceSource(tiny, width=4, frame_range=(1, 5), steps_per_frame=3, interpolate=True)
    np.testing.assert_allclose(data.trajectory.poses, source.trajectory.poses, atol=1e-9)
    assert data.spikes("gray").shape == (12, 4, 4) and len(data.test) == 2
    # the dataset's 16-bit test images re-import as a sequence, equal up to 16-bit quantisation
    again = SequenceSource(out / "transforms_test.json")
    want = SequenceSource(tiny, width=4, eval_views=root / "transforms_test.json").test_views()[1]
    np.testing.assert_allclose(np.stack(list(again.frames(range(2)))), want, atol=1e-4)
    with pytest.raises(SystemExit) as exit_:
        main(["simulate", "--sequence", str(tiny), "--out", str(tmp_path / "bad"), "--sequence-range", "4:2"])
    assert exit_.value.code == 2 and not (tmp_path / "bad").exists()


def test_simulate_of_a_sequence_with_an_unreadable_frame_leaves_nothing(tiny: Path, tmp_path: Path) -> None:
    """A frame that only fails when it is decoded (after earlier frames are cached) is bad input: exit 2, and
    neither the dataset nor its work folder is left behind."""
    from spikenerf.cli import main

    png = tiny.parent / "train" / "r_3.png"
    png.write_bytes(png.read_bytes()[:-30])  # a truncated PNG: its header (and size) still reads
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_:
        main(["simulate", "--sequence", str(tiny), "--out", str(out), "--no-progress"])
    assert exit_.value.code == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny"]


def test_a_resumed_simulate_keeps_its_work_folder_when_a_later_frame_is_unreadable(
    tiny: Path, tmp_path: Path
) -> None:
    """Only a fresh run is cleaned up on bad input: a run resumed after an interruption keeps the frames its
    earlier part rendered (they stay valid once the bad frame is fixed)."""
    import os
    import subprocess
    import sys

    from spikenerf.cli import main
    from spikenerf.core.faults import KILL_ENV

    out = tmp_path / "out"
    args = ["simulate", "--sequence", str(tiny), "--out", str(out), "--no-progress"]
    killed = subprocess.run([sys.executable, "-m", "spikenerf", *args], capture_output=True,
                            env={**os.environ, KILL_ENV: "simulate.render:2"})  # fmt: skip
    assert killed.returncode != 0
    cached = sorted(p.name for p in (tmp_path / "out.partial").rglob("*.npy"))
    assert len(cached) == 2
    png = tiny.parent / "train" / "r_3.png"
    png.write_bytes(png.read_bytes()[:-30])
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2 and not out.exists()
    kept = sorted(p.name for p in (tmp_path / "out.partial").rglob("*.npy"))
    assert kept == [*cached, "00002.npy"]  # and the frame rendered before the bad one

"""``spikenerf import``: a .dat recording + a pose source → a dataset folder; bad input → exit 2."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli
from spikenerf.camera.io import read_dat, write_dat
from spikenerf.camera.spikecv import read_spikecv_config
from spikenerf.core.errors import InputError
from spikenerf.core.marker import mark
from spikenerf.data.dataset import load_dataset
from spikenerf.importing.alignment import trajectory_errors
from spikenerf.importing.colmap_model import read_colmap_text
from spikenerf.importing.interpolation import per_step_poses
from spikenerf.importing.normalisation import BOX_MARGIN, focus_point, normalisation
from spikenerf.importing.orientation import PLANE_MIN_SCORE, orientation, plane_turn, up_direction, upright
from spikenerf.scenes.distortion import Distortion
from spikenerf.scenes.poses import matrix_to_quaternion
from spikenerf.scenes.trajectory import orbit

H, W, T = 8, 24, 40  # 40 frames of 8×24 are not a whole number of 8×40 raw frames, and vice versa
ORBIT = ("--poses", "orbit", "--orbit", "4,30", "--fov", 40)  # the orbit that _truth() and the tests use


@pytest.fixture
def recording(tmp_path: Path) -> tuple[Path, np.ndarray]:
    rng = np.random.default_rng(0)
    spikes = (rng.random((T, H, W)) < 0.3).astype(np.uint8)
    rec = tmp_path / "rec" / "stream.dat"
    write_dat(rec, spikes)
    (rec.parent / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\nfps: 20000\nis_labeled: false\n")
    return rec, spikes


def _truth(n: int = T) -> np.ndarray:
    return orbit(4.0, 30.0, duration=n / 40000, fps=40000).poses


def _leftovers(tmp_path: Path) -> list[str]:
    return sorted(p.name for p in tmp_path.iterdir() if p.name != "rec")


def test_spikecv_config_and_orbit_import(capsys, recording, tmp_path: Path) -> None:
    rec, spikes = recording
    args = ["--keyframe-every", 8, "--window", 5, "--test-every", 2]
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *ORBIT, *args)
    assert code == 0, err
    ds = load_dataset(tmp_path / "ds")
    assert (ds.intrinsics.height, ds.intrinsics.width, ds.trajectory.fps) == (H, W, 20000.0)
    np.testing.assert_array_equal(ds.spikes(), spikes)
    assert len(ds.trajectory) == T and len(ds.test) == 3  # keyframes 0, 8, ..., 32, 39: held out 8, 24, 39
    truth = orbit(4.0, 30.0, duration=T / 20000, fps=20000).poses
    norm = normalisation(truth, camera_angle_x=np.radians(40))
    np.testing.assert_allclose(norm.rotation, np.eye(3), atol=1e-9)  # the orbit is upright already
    np.testing.assert_allclose(ds.trajectory.poses, norm.poses(truth), atol=1e-5)
    scale = norm.scale
    assert np.abs(ds.trajectory.poses[:, :3, 3]).max() > 1  # cameras sit outside the unit box
    assert ds.near < 4 * scale < ds.far
    code, out, _ = run_cli(capsys, "info", tmp_path / "ds")  # what import recorded, and the test views
    assert code == 0 and f"imported: {rec} (steps 0..{T - 1})   poses: orbit 4,30" in out
    tests = ", ".join(map(str, ds.config["imported"]["test_keyframes"]))
    said = (
        f"keyframes: 6 every 8 steps (tfp, window 5)   test views: the keyframes at recording steps {tests}"
    )
    assert said in out  # (the whole recording: its steps are the dataset's)
    assert "preview.png: TFP (gray, window 5)" in out  # the keyframes' window


def test_recorded_command_line(capsys, recording, tmp_path: Path) -> None:
    rec, _ = recording
    out = tmp_path / "ds"
    code, _, err = run_cli(capsys, "--threads", 1, "import", rec, "--out", out, *ORBIT, "--range", "0:30")
    assert code == 0, err
    assert load_dataset(out).config["command"] == (
        f"spikenerf --threads 1 import {rec} --out {out} --poses orbit --orbit 4,30 --range 0:30 --fov 40.0"
    )


def test_tfp_views_read_one_window_at_a_time_and_imports_get_none(
    capsys, recording, tmp_path: Path, monkeypatch
) -> None:
    import spikenerf.data.writer as writer

    reads = []

    def spy(*args, **kwargs):
        frames = read_dat(*args, **kwargs)
        reads.append(len(frames))
        return frames

    monkeypatch.setattr(writer, "read_dat", spy)
    code, _, err = run_cli(capsys, "import", rec := recording[0], "--out", tmp_path / "ds", *ORBIT)
    assert code == 0, err
    assert reads == [] and not {"transforms_gt.json", "transforms_tfp.json"} & {
        p.name for p in (tmp_path / "ds").iterdir()
    }
    sim = ["simulate", "--scene", "analytic-orbs", "--width", 8, "--height", 8, "--frames", 120]
    code, _, err = run_cli(
        capsys, *sim, "--gt-every", 50, "--test-views", 1, "--no-progress", "--out", rec.parent / "s"
    )
    assert code == 0, err
    assert reads == [21, 41, 40]  # steps 0, 50, 100 of 120: windows of 41 clipped to the stream
    meta = json.loads((rec.parent / "s" / "transforms_tfp.json").read_text())
    assert len(meta["train_filenames"]) == 3


def test_raw_416_layout_and_range(capsys, recording, tmp_path: Path) -> None:
    _, spikes = recording
    raw = tmp_path / "raw" / "stream.dat"
    write_dat(raw, np.concatenate([spikes, np.ones((T, H, 16), np.uint8)], axis=2))  # 16 junk columns
    size = ("--height", H, "--width", W)
    code, _, err = run_cli(capsys, "import", raw, *size, "--out", tmp_path / "x", *ORBIT)
    assert code == 2 and "raw-width" not in err  # columns that fire are no silent sps10 padding
    silent = tmp_path / "silent" / "stream.dat"
    write_dat(silent, np.concatenate([spikes, np.zeros((T, H, 16), np.uint8)], axis=2))
    code, _, err = run_cli(capsys, "import", silent, *size, "--out", tmp_path / "x", *ORBIT)
    assert code == 2 and "pass --raw-width 40" in err and len(err.strip().splitlines()) == 1
    code, _, err = run_cli(
        capsys, "import", raw, *size, "--raw-width", 40, "--range", "5:37", "--out", tmp_path / "ds", *ORBIT
    )
    assert code == 0, err
    ds = load_dataset(tmp_path / "ds")
    np.testing.assert_array_equal(ds.spikes(), spikes[5:37])
    assert ds.config["imported"]["range"] == [5, 37]


@pytest.mark.parametrize("kind", [int, float])  # 13.0: some JSON writers give integral steps as floats
def test_transforms_json_poses_at_their_steps(capsys, recording, tmp_path: Path, kind: type) -> None:
    rec, _ = recording
    truth = _truth()
    keys = np.array([0, 13, 26, 39])
    frames = [{"step": kind(s), "transform_matrix": truth[s].tolist()} for s in keys]
    box = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
    pose_file = tmp_path / "transforms.json"
    pose_file.write_text(json.dumps({"camera_angle_x": 0.7, "scene_box": box, "frames": frames}))
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", pose_file)
    assert code == 0, err
    ds = load_dataset(tmp_path / "ds")
    np.testing.assert_allclose(ds.trajectory.poses[keys], truth[keys], atol=1e-6)  # box already unit
    np.testing.assert_allclose(ds.intrinsics.camera_angle_x, 0.7)
    # between keyframes: slerp/lerp, close to the true orbit
    assert trajectory_errors(ds.trajectory.poses, truth)["rot_max_deg"] < 1.0


def _write_colmap_text(folder: Path, c2w: np.ndarray, steps: np.ndarray, points: np.ndarray) -> None:
    folder.mkdir(parents=True)
    (folder / "cameras.txt").write_text("# camera\n1 PINHOLE 48 16 30 31 24 8\n")
    lines = ["# images"]
    for i, (pose, step) in enumerate(zip(c2w, steps, strict=True)):
        rot_cv = pose[:3, :3] * np.array([1.0, -1.0, -1.0])  # OpenCV axes: +Y down, +Z forward
        q, t = matrix_to_quaternion(rot_cv.T), -rot_cv.T @ pose[:3, 3]  # world-to-camera
        lines += [" ".join(str(v) for v in [i + 1, *q, *t, 1, f"{step:06d}.png"]), "1.0 2.0 -1 3.0 4.0 -1"]
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    rows = [f"{i + 1} {p[0]} {p[1]} {p[2]} 128 128 128 0.5 1 0" for i, p in enumerate(points)]
    (folder / "points3D.txt").write_text("# points\n" + "\n".join(rows) + "\n")


def test_colmap_text_model_normalised_with_points(capsys, recording, tmp_path: Path) -> None:
    rec, _ = recording
    keys = np.arange(0, T, 5)
    c2w = _truth()[keys].copy()
    c2w[:, :3, 3] = c2w[:, :3, 3] * 3 + np.array([5.0, -2.0, 1.0])  # COLMAP's arbitrary frame
    points = np.random.default_rng(1).uniform(-3, 3, (200, 3)) + np.array([5.0, -2.0, 1.0])
    model = tmp_path / "model"
    _write_colmap_text(model, c2w, keys, points)
    found = read_colmap_text(model)
    np.testing.assert_allclose(found.poses, c2w, atol=1e-9)
    assert found.steps.tolist() == keys.tolist() and found.intrinsics.fl_y == 31
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", model)
    assert code == 0, err
    ds = load_dataset(tmp_path / "ds")
    norm = ds.config["imported"]["normalisation"]
    # 2nd–98th percentiles of uniform(-3, 3) (±2.88), widened by the margin
    assert norm["scale"] == pytest.approx(1 / (2.88 * BOX_MARGIN), rel=0.05)
    np.testing.assert_allclose(norm["center"], [5.0, -2.0, 1.0], atol=0.2)
    rotation = np.asarray(norm["rotation"])
    np.testing.assert_allclose(rotation[2], [0, 0, 1], atol=1e-9)  # the orbit's up stays +Z
    np.testing.assert_allclose(ds.trajectory.poses[keys, :3, :3], rotation @ c2w[:, :3, :3], atol=1e-9)
    code, _, err = run_cli(
        capsys, "import", rec, "--out", tmp_path / "kept", "--poses", model, "--orient", "none"
    )
    assert code == 0, err
    kept = load_dataset(tmp_path / "kept")
    assert kept.config["imported"]["normalisation"]["rotation"] == np.eye(3).tolist()
    np.testing.assert_allclose(kept.trajectory.poses[keys, :3, :3], c2w[:, :3, :3], atol=1e-9)
    assert ds.intrinsics.fl_x == pytest.approx(30 * W / 48) and ds.intrinsics.fl_y == pytest.approx(
        31 * H / 16
    )
    assert 0.05 <= ds.near < 4 * 3 * norm["scale"] < ds.far


def _turn(axis: np.ndarray, degrees: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()


def test_normalisation_turns_an_arbitrary_frame_upright_and_fits_the_box() -> None:
    """A COLMAP-like frame (tilted, turned, shifted, scaled) of an orbit around a long flat slab: the upright
    unit box holds all of it, with the cameras' up on +Z and the slab level in it."""
    rng = np.random.default_rng(0)
    slab = rng.uniform([-1.0, -0.3, -0.1], [1.0, 0.3, 0.1], (2000, 3)) @ _turn(np.array([0, 0, 1.0]), 30).T
    cams = orbit(4.0, 30.0).poses[::25]
    turn, shift = _turn(np.array([1.0, 2.0, 0.5]), 70), np.array([3.0, -1.0, 2.0])
    src_cams = cams.copy()
    src_cams[:, :3, :3] = turn @ cams[:, :3, :3]
    src_cams[:, :3, 3] = 2 * cams[:, :3, 3] @ turn.T + shift
    src_slab = 2 * slab @ turn.T + shift
    for orient in ("up", "up-box"):
        up = normalisation(src_cams, src_slab, orient=orient)
        np.testing.assert_allclose(up.rotation @ turn @ [0, 0, 1.0], [0, 0, 1], atol=1e-6)  # world up again
        fitted = up.points(src_slab)
        lo, hi = np.percentile(fitted, [2, 98], axis=0)
        assert (np.abs(fitted).max(0) < 1.0).all()  # nothing of the slab outside the box
        assert (hi - lo).max() == pytest.approx(2 / BOX_MARGIN, rel=1e-6)  # its longest side fills the box
        centres = up.poses(src_cams)[:, :3, 3]
        assert np.ptp(centres[:, 2]) < 1e-6  # the orbit is level
        assert np.ptp(fitted[:, 2]) == pytest.approx(
            2 * 0.2 * up.scale, rel=0.01
        )  # level: z is its thickness
    kept = normalisation(src_cams, src_slab, orient="none")
    np.testing.assert_array_equal(kept.rotation, np.eye(3))
    assert kept.record()["turn"] == "none"

    def largest_side(points: np.ndarray, deg: float) -> float:
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        xy = points[:, :2] @ np.array([[c, s], [-s, c]])
        return float(np.ptp(np.percentile(xy, [2, 98], axis=0), axis=0).max())

    # up-box: turned about +Z for the smallest cube: no other turn gives a smaller largest side (for this
    # 2 × 0.6 slab a turn of about 45°: the diagonal orientation, (2 + 0.6)/√2 < 2)
    boxed = normalisation(src_cams, src_slab, orient="up-box")
    fitted = boxed.points(src_slab)
    assert boxed.turn == "box"
    assert largest_side(fitted, 0) <= min(largest_side(fitted, d) for d in range(1, 90, 3)) + 1e-9
    assert largest_side(fitted, 0) < 0.95 * max(largest_side(fitted, d) for d in range(0, 90, 3))
    # up (the default): the slab's sides are planes, so its edges are put on the axes instead
    planes = normalisation(src_cams, src_slab)
    assert planes.turn == "planes" and planes.plane_score >= PLANE_MIN_SCORE
    long_axis = planes.rotation @ turn @ _turn(np.array([0, 0, 1.0]), 30) @ [1.0, 0, 0]
    assert min(abs(long_axis[0]), abs(long_axis[1])) < np.sin(np.radians(1.5))  # along X or Y within 1.5°
    box = np.array([[-1.0, -1, -1], [1, 1, 1]])
    np.testing.assert_array_equal(normalisation(src_cams, scene_box=box).rotation, np.eye(3))  # a stated box
    with pytest.raises(InputError, match="orient must be one of up, up-box, none"):
        normalisation(src_cams, src_slab, orient="sideways")  # type: ignore[arg-type]


def _box_surfaces(rng: np.random.Generator, boxes: list, n: int) -> np.ndarray:
    """``n`` points on the faces of each axis-aligned box (lo, hi), evenly by area."""
    out = []
    for lo, hi in boxes:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        p = rng.uniform(lo, hi, (n, 3))
        size = hi - lo
        area = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
        axis = rng.choice(3, n, p=area / area.sum())
        side = rng.integers(0, 2, n)
        p[np.arange(n), axis] = np.where(side == 1, hi[axis], lo[axis])
        out.append(p)
    return np.concatenate(out)


def test_plane_turn_puts_a_scenes_walls_on_the_axes() -> None:
    """Points on the faces of boxes (a slab, a block, a tower) and a ball, turned 17° about +Z, with noise:
    the turn back is found within 2° (modulo 90°; the ball adds noise) and clearly; a sphere alone shows no
    planes, so the smallest box decides."""
    rng = np.random.default_rng(1)
    boxes = [((-0.9, -0.9, -0.65), (0.9, 0.9, -0.5)), ((-0.45, -0.45, -0.5), (0.45, 0.45, 0.1)),
             ((-0.2, -0.2, 0.1), (0.2, 0.2, 0.7))]  # fmt: skip
    ball = rng.normal(size=(1500, 3))
    ball = 0.3 * ball / np.linalg.norm(ball, axis=1, keepdims=True) + [0.5, -0.5, -0.2]
    scene = np.concatenate([_box_surfaces(rng, boxes, 1500), ball]) + rng.normal(0, 0.005, (6000, 3))
    turned = scene @ _turn(np.array([0, 0, 1.0]), 17).T
    angle, score = plane_turn(turned)
    back = (np.degrees(angle) + 17 + 45) % 90 - 45  # the residual turn, modulo the walls' 90°
    assert abs(back) < 2.0 and score >= 3 * PLANE_MIN_SCORE
    cams = orbit(4.0, 30.0).poses[::25]
    rotation, rule, _ = orientation(cams, turned)
    assert rule == "planes"
    np.testing.assert_allclose(rotation, _turn(np.array([0, 0, 1.0]), np.degrees(angle)), atol=1e-9)
    golden = np.arange(4000) * np.pi * (3 - np.sqrt(5))  # a sphere of 4000 evenly spread points
    z = np.linspace(-1, 1, 4000)
    sphere = np.stack([np.sqrt(1 - z**2) * np.cos(golden), np.sqrt(1 - z**2) * np.sin(golden), z], -1)
    assert plane_turn(sphere)[1] < PLANE_MIN_SCORE / 2
    assert orientation(cams, sphere)[1] == "box"
    assert plane_turn(ball[:10]) == (0.0, 0.0)  # too few points for a neighbourhood
    with pytest.raises(InputError, match="turn must be one of planes, box"):
        orientation(cams, ball, "diagonal")  # type: ignore[arg-type]


def test_up_direction_of_a_partial_arc_is_its_plane_normal() -> None:
    quarter = orbit(4.0, 30.0).poses[:250]  # 90° of the orbit: the up axes lean towards the centre
    mean_up = quarter[:, :3, 1].mean(0)
    assert np.degrees(np.arccos(mean_up[2] / np.linalg.norm(mean_up))) > 5
    np.testing.assert_allclose(up_direction(quarter), [0, 0, 1], atol=1e-9)
    flipped = quarter.copy()
    flipped[:, :3, :3] = (
        np.diag([1.0, -1, -1]) @ quarter[:, :3, :3]
    )  # upside down: the sign follows the cameras
    flipped[:, :3, 3] = quarter[:, :3, 3] @ np.diag([1.0, -1, -1])
    np.testing.assert_allclose(up_direction(flipped), [0, 0, -1], atol=1e-9)
    grid = np.tile(np.eye(4), (9, 1, 1))  # forward-facing: the cameras' plane is not the ground
    grid[:, :2, 3] = np.stack(np.meshgrid([-0.5, 0, 0.5], [-0.5, 0, 0.5]), -1).reshape(9, 2)
    np.testing.assert_allclose(up_direction(grid), [0, 1, 0])
    for path in (orbit(4.0, 30.0, elevation_sweep_deg=30).poses, orbit(4.0, 30.0).poses[:50]):
        np.testing.assert_allclose(up_direction(path), [0, 0, 1], atol=1e-9)  # a rising path, an 18° arc
    np.testing.assert_allclose(upright(flipped), np.diag([1.0, -1, -1]), atol=1e-9)  # half a turn
    cancelling = np.stack([np.eye(4), np.diag([1.0, -1, -1, 1])])  # one camera upside down: no up
    assert up_direction(cancelling) is None
    np.testing.assert_array_equal(upright(cancelling), np.eye(3))


def test_llff_poses_bounds(capsys, recording, tmp_path: Path) -> None:
    rec, _ = recording
    truth = _truth()[:: T // 4]
    llff = np.stack([truth[:, :3, 1] * -1, truth[:, :3, 0], truth[:, :3, 2], truth[:, :3, 3]], -1)
    hwf = np.broadcast_to(np.array([H, W, 30.0])[None, :, None], (len(truth), 3, 1))
    rows = np.concatenate([np.concatenate([llff, hwf], -1).reshape(-1, 15), np.ones((len(truth), 2))], 1)
    np.save(tmp_path / "poses_bounds.npy", rows)
    code, _, err = run_cli(
        capsys, "import", rec, "--out", tmp_path / "ds", "--poses", tmp_path / "poses_bounds.npy"
    )
    assert code == 0, err
    ds = load_dataset(tmp_path / "ds")
    ends = [0, T - 1]  # spread evenly: the first and last poses sit on the first and last steps
    np.testing.assert_allclose(ds.trajectory.poses[ends, :3, :3], truth[[0, -1], :3, :3], atol=1e-9)
    assert ds.intrinsics.fl_x == 30.0


def test_interpolation_and_focus_point() -> None:
    truth = _truth(400)
    keys = np.arange(0, 400, 20)
    poses = per_step_poses(truth[keys], keys, np.arange(400))
    np.testing.assert_allclose(poses[keys], truth[keys], atol=1e-12)
    inside = slice(0, keys[-1] + 1)
    assert trajectory_errors(poses[inside], truth[inside])["ate_rel"] < 5e-3
    assert trajectory_errors(poses, truth)["ate_rel"] < 0.02  # the last 19 steps: extrapolated
    np.testing.assert_allclose(focus_point(truth), 0.0, atol=1e-9)


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        ("size", "not a multiple of the frame size"),
        ("yaml", "field 'spike_h': expected a positive integer"),
        ("nan", "NaN"),
        ("few", "need at least 2"),
        ("nocolmap", "pip install 'spikenerf[colmap]'"),
        ("empty", "the recording holds no steps"),
        ("fps-neg", "--fps must be a finite number > 0"),
        ("fps-nan", "--fps must be a finite number > 0"),
        ("fps-zero", "--fps must be a finite number > 0"),
        ("threshold-zero", "--threshold must be a finite number > 0"),
        ("width", "--width 12 differs from spike_w 24 in"),  # the config beside it: a typo writes garbage
        ("raw_width", "--raw-width 32 differs from raw_width 40 in"),
    ],
)
def test_bad_input_exits_2_and_leaves_nothing(
    capsys, recording, tmp_path, monkeypatch, setup, message
) -> None:
    rec, _ = recording
    args = ["import", rec, "--out", tmp_path / "ds"]
    if setup == "size":
        rec.write_bytes(rec.read_bytes() + b"\0")
    if setup == "empty":
        rec.write_bytes(b"")
    if setup == "yaml":
        (rec.parent / "config.yaml").write_text("spike_h: eight\nspike_w: 24\n")
    if setup in ("nan", "few"):
        poses = _truth()[:1] if setup == "few" else _truth()[:3].copy()
        if setup == "nan":
            poses[1, 0, 3] = np.nan
        pose_file = tmp_path / "p.json"
        frames = [{"transform_matrix": np.where(np.isnan(p), 0, p).tolist()} for p in poses]
        if setup == "nan":
            frames[1]["transform_matrix"][0][3] = "NaN"
        pose_file.write_text(json.dumps({"frames": frames}).replace('"NaN"', "NaN"))
        args += ["--poses", pose_file, "--fov", 40]
    if setup == "nocolmap":
        monkeypatch.setitem(sys.modules, "pycolmap", None)
    if setup == "width":
        args += [*ORBIT, "--width", 12]
    if setup == "raw_width":
        (rec.parent / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\nraw_width: 40\n")
        args += [*ORBIT, "--raw-width", 32]
    if setup.startswith(("fps", "threshold")):
        name, value = setup.split("-")
        args += [*ORBIT, f"--{name}", {"neg": -5, "nan": "nan", "zero": 0}[value]]
    code, _, err = run_cli(capsys, *args)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert _leftovers(tmp_path) == [p for p in ["p.json"] if (tmp_path / p).exists()]


@pytest.mark.parametrize(
    ("kind", "content", "message"),
    [
        ("json", {"scene_box": [[0, 0, 0], [1, 1]]}, "field 'scene_box'"),
        ("json", {"scene_box": "abc"}, "field 'scene_box'"),
        ("json", {"w": 0, "h": 8, "fl_x": 10, "fl_y": 10, "cx": 4, "cy": 4}, "field 'w'"),
        ("json", {"w": 8, "h": 8, "fl_x": -1, "fl_y": 10, "cx": 4, "cy": 4}, "field 'fl_x'"),
        ("json", {"w": 8, "h": 8, "fl_x": 10, "camera_angle_x": float("nan")}, "field 'camera_angle_x'"),
        ("json", {"fl_x": float("inf")}, "field 'fl_x'"),  # (no w, h: the focal length is not used)
        ("colmap", "1 PINHOLE abc", "malformed camera line"),
        ("colmap", "1 PINHOLE", "malformed camera line"),
        ("colmap", "1 PINHOLE 0 16 30 31 24 8", "must be > 0"),
        ("colmap", "1 PINHOLE 48 16 -30 31 24 8", "must be > 0"),
        ("colmapbin", b"junk", "truncated COLMAP binary file: the record count"),
    ],
)
def test_malformed_pose_sources_exit_2(capsys, recording, tmp_path, kind, content, message) -> None:
    rec, _ = recording
    keys = np.arange(0, T, 13)
    if kind == "json":
        frames = [{"step": int(s), "transform_matrix": _truth()[s].tolist()} for s in keys]
        source = tmp_path / "p.json"
        source.write_text(json.dumps({**content, "frames": frames}))
    else:
        source = tmp_path / "model"
        _write_colmap_text(source, _truth()[keys], keys, np.zeros((1, 3)))
        if kind == "colmapbin":
            pytest.importorskip("pycolmap")
            for name in ("cameras", "images", "points3D"):
                (source / f"{name}.txt").unlink()
                (source / f"{name}.bin").write_bytes(content)
        else:
            (source / "cameras.txt").write_text(content + "\n")
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", source, "--fov", 40)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert str(source.name) in err and not (tmp_path / "ds").exists()


@pytest.mark.parametrize(
    ("steps", "extra", "message"),
    [
        ([1, 2, 3, 4], [], "cover only 4 of the 40 selected steps"),  # frame_00001.png … on a long stream
        ([0, 20, 45], [], "fall outside the selected steps 0..39"),
        ([0, 20, 39], ["--range", "10:40"], "fall outside the selected steps 10..39"),
    ],
)
def test_pose_file_steps_must_fit_the_selection(capsys, recording, tmp_path, steps, extra, message) -> None:
    rec, _ = recording
    frames = [{"file_path": f"frame_{s:05d}.png", "transform_matrix": _truth(60)[s].tolist()} for s in steps]
    (tmp_path / "p.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": frames}))
    code, _, err = run_cli(
        capsys, "import", rec, "--out", tmp_path / "ds", "--poses", tmp_path / "p.json", *extra
    )
    assert code == 2 and message in err and "p.json" in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize(
    ("field", "hint"),
    [
        (False, "if the numbers ending the frame names are not spike steps, give each frame its 'step'"),
        (True, "if the frames' 'step' values are not spike steps, correct them"),
    ],
)
def test_short_pose_steps_hint_at_where_the_steps_came_from(capsys, recording, tmp_path, field, hint) -> None:
    """Steps read from 'step' fields are not fixed by giving 'step' fields: the hint names their source."""
    rec, _ = recording
    frames = [
        {
            "file_path": f"frame_{s:05d}.png",
            "transform_matrix": _truth(60)[s].tolist(),
            **({"step": s} if field else {}),
        }
        for s in [1, 2, 3, 4]
    ]
    (tmp_path / "p.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": frames}))
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", tmp_path / "p.json")
    assert code == 2 and "cover only 4 of the 40" in err and hint in err, err
    assert (hint.startswith("if the numbers")) == ("give each frame its 'step'" in err), err


def test_stale_colmap_work_is_not_published_with_other_poses(capsys, recording, tmp_path) -> None:
    rec, _ = recording
    model = tmp_path / "ds.partial" / "colmap" / "model"
    _write_colmap_text(model, _truth()[[0, 39]], np.array([0, 39]), np.zeros((1, 3)))
    mark(tmp_path / "ds.partial", "dataset")  # an earlier, failed COLMAP attempt
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *ORBIT)
    assert code == 0, err
    assert not (tmp_path / "ds" / "colmap").exists()


def test_a_finished_colmap_model_is_reused_only_for_the_same_keyframe_images(tmp_path, monkeypatch) -> None:
    from spikenerf.importing.colmap import ColmapSettings, colmap_fingerprint, run_colmap

    keys, images = np.array([0, 13, 26, 39]), np.random.default_rng(2).random((4, H, W)).astype(np.float32)
    work = tmp_path / "colmap"
    _write_colmap_text(work / "model", _truth()[keys], keys, np.zeros((1, 3)))
    (work / "steps.json").write_text(colmap_fingerprint(images, keys, ColmapSettings()))
    monkeypatch.setitem(sys.modules, "pycolmap", None)  # a rerun of COLMAP would fail: pycolmap missing
    assert run_colmap(images, keys, work).steps.tolist() == keys.tolist()  # reused
    with pytest.raises(InputError, match="pycolmap"):  # other images at the same steps: not reused
        run_colmap(images[::-1].copy(), keys, work)
    assert not (work / "model").exists()


@pytest.mark.parametrize("command", ["import", "simulate"])
def test_a_foreign_partial_folder_is_refused_untouched(capsys, recording, tmp_path, command) -> None:
    rec, _ = recording
    foreign = tmp_path / "ds.partial"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("mine")
    args = (
        [rec, *ORBIT] if command == "import" else ["--scene", "analytic-orbs", "--frames", 4, "--no-progress"]
    )
    code, _, err = run_cli(capsys, command, *args, "--out", tmp_path / "ds")
    assert code == 2 and "ds.partial" in err and "move it away" in err and len(err.strip().splitlines()) == 1
    assert [p.name for p in foreign.iterdir()] == ["thesis.tex"] and not (tmp_path / "ds").exists()


def test_near_far_from_points_memory_is_bounded() -> None:
    import tracemalloc

    from spikenerf.importing.normalisation import near_far_from_points

    poses = _truth(400)  # 400 cameras on a radius-4 orbit, 30k points in the unit ball
    points = np.random.default_rng(0).normal(size=(30000, 3)) * 0.3
    tracemalloc.start()
    near, far = near_far_from_points(poses, points)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 60e6, peak  # all pairs at once: 400 × 30000 × 3 float64 = 288 MB
    assert 0.8 * 3 < near < 4 < far < 1.2 * 5


def test_one_lock_per_folder_and_a_killed_swap_is_finished(capsys, recording, tmp_path) -> None:
    from spikenerf.core.lock import lock_path
    from spikenerf.core.replacement import retire

    (tmp_path / "d").mkdir()
    assert lock_path(tmp_path / "d" / ".." / "ds") == lock_path(tmp_path / "ds")
    rec, _ = recording
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *ORBIT)
    assert code == 0, err
    retire(tmp_path / "ds")  # killed between the two renames of --overwrite: swapped out, marked retired
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *ORBIT)
    assert code == 2 and "--overwrite" in err  # the earlier dataset is back, so it is not replaced silently
    assert load_dataset(tmp_path / "ds") and not (tmp_path / ".ds.old").exists()
    retire(tmp_path / "ds")
    shutil.copytree(tmp_path / ".ds.old", tmp_path / "ds")  # a retired leftover beside a dataset: deleted
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *ORBIT, "--overwrite")
    assert code == 0 and not (tmp_path / ".ds.old").exists(), err
    (tmp_path / ".ds.old").mkdir()  # the user's own .ds.old: never deleted, so the replacement is refused
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *ORBIT, "--overwrite")
    assert code == 2 and ".ds.old" in err and (tmp_path / ".ds.old").is_dir(), err


def test_a_pycolmap_failure_is_one_input_error(tmp_path, monkeypatch) -> None:
    from unittest import mock

    from spikenerf.importing.colmap import run_colmap

    fake = mock.MagicMock()
    fake.extract_features.side_effect = RuntimeError("Check failed: camera\n(stack trace)")
    monkeypatch.setitem(sys.modules, "pycolmap", fake)
    images = np.random.default_rng(0).random((4, H, W)).astype(np.float32)
    with pytest.raises(InputError, match=r"COLMAP failed on the keyframes \(Check failed: camera\)$"):
        run_colmap(images, np.arange(4) * 10, tmp_path / "colmap")
    assert set(fake.extract_features.call_args.kwargs) >= {"database_path", "image_names", "camera_mode"}


def test_info_and_reconstruct_take_raw_width_from_the_config(capsys, recording, tmp_path) -> None:
    _, spikes = recording
    raw = tmp_path / "raw" / "stream.dat"
    write_dat(raw, np.concatenate([spikes, np.zeros((T, H, 16), np.uint8)], axis=2))
    (raw.parent / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\nraw_width: {W + 16}\n")
    code, out, err = run_cli(capsys, "info", raw)
    assert code == 0 and f"stored rows {W + 16} wide" in out and not err, err
    write_dat(raw, np.concatenate([spikes, np.ones((T, H, 16), np.uint8)], axis=2))  # padding that fires
    code, out, err = run_cli(capsys, "info", raw)
    said = f"the 16 columns that raw_width {W + 16} in {raw.parent / 'config.yaml'} strips from each row fire"
    assert code == 0 and said in err and len(err.strip().splitlines()) == 1, err
    code, out, err = run_cli(capsys, "info", raw, "--raw-width", W + 16)
    assert code == 0 and f"the 16 columns that --raw-width {W + 16} strips from each row fire" in err, err
    code, _, err = run_cli(
        capsys, "reconstruct", raw, "--method", "tfp", "--frame", 20, "--out", tmp_path / "r.png"
    )
    assert code == 0, err
    (raw.parent / "config.yaml").write_text("spike_h: eight\n")  # malformed, but the flags say it all
    code, out, err = run_cli(capsys, "info", raw, "--height", H, "--width", W, "--raw-width", W + 16)
    assert code == 0 and f"{W}×{H} pixels" in out, err


def test_forward_facing_poses_need_a_box_or_llff_bounds(capsys, recording, tmp_path) -> None:
    grid = np.tile(np.eye(4), (9, 1, 1))  # a 3×3 LLFF-style grid, every camera looking down −Z
    grid[:, :2, 3] = np.stack(np.meshgrid([-0.5, 0, 0.5], [-0.5, 0, 0.5]), -1).reshape(9, 2)
    dolly = np.tile(np.eye(4), (5, 1, 1))
    dolly[:, 2, 3] = np.linspace(0, 2, 5)
    for poses in (grid, dolly):
        with pytest.raises(InputError, match="cannot size the scene from the cameras alone"):
            normalisation(poses, camera_angle_x=0.7)
    rec, _ = recording
    llff = np.stack([-grid[:, :3, 1], grid[:, :3, 0], grid[:, :3, 2], grid[:, :3, 3]], -1)
    hwf = np.broadcast_to(np.array([H, W, 30.0])[None, :, None], (9, 3, 1))
    rows = np.concatenate([np.concatenate([llff, hwf], -1).reshape(-1, 15), np.tile([[2.0, 6.0]], (9, 1))], 1)
    np.save(tmp_path / "poses_bounds.npy", rows)
    code, _, err = run_cli(
        capsys, "import", rec, "--out", tmp_path / "ds", "--poses", tmp_path / "poses_bounds.npy"
    )
    assert code == 0, err
    ds = load_dataset(tmp_path / "ds")
    scale = ds.config["imported"]["normalisation"]["scale"]
    assert scale == pytest.approx(2 / 6) and (ds.near, ds.far) == pytest.approx((2 * scale, 6 * scale))


def test_config_reader_types(tmp_path: Path) -> None:
    path = tmp_path / "config.yaml"
    path.write_text("spike_h: 250\nspike_w: 400\nraw_width: 416\nfps: 20000\nthreshold: 2\n")
    cfg = read_spikecv_config(path)
    assert (cfg.height, cfg.width, cfg.raw_width, cfg.fps, cfg.threshold) == (250, 400, 416, 20000.0, 2.0)
    for bad in ("spike_h: 2.5\n", "spike_w: true\n", "fps: -1\n", "- a list\n"):
        path.write_text(bad)
        with pytest.raises(InputError, match=r"config\.yaml"):
            read_spikecv_config(path)


def test_colmap_too_few_registered_names_count_and_flag(capsys, recording, tmp_path: Path) -> None:
    pytest.importorskip("pycolmap")
    rec, _ = recording  # random noise: nothing to match
    code, _, err = run_cli(
        capsys, "import", rec, "--out", tmp_path / "ds", "--keyframe-every", 8, "--window", 5
    )
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "COLMAP registered 0 of 6 keyframes" in err and "--keyframe-every (now 8)" in err
    assert not (tmp_path / "ds").exists()


def test_read_dat_of_the_fixture_is_bottom_up(recording) -> None:
    rec, spikes = recording  # guards the fixture itself: the importer reads the SpikeCV layout
    np.testing.assert_array_equal(read_dat(rec, H, W), spikes)


def test_colmap_recovers_a_textured_orbit(tmp_path: Path) -> None:
    pytest.importorskip("pycolmap")
    from spikenerf.importing.colmap import ColmapSettings, run_colmap
    from spikenerf.scenes.analytic import AnalyticSource

    truth = orbit(4.0, 30.0, turns=0.5, duration=24 / 40000, fps=40000)  # 24 views, 7.5° apart
    source = AnalyticSource("analytic-blocks", 240, 160, truth, supersample=1)
    frames = np.stack(list(source.frames(truth.steps))).mean(-1)
    found = run_colmap(frames, truth.steps, tmp_path / "colmap", ColmapSettings(focal=source.intrinsics.fl_x))
    assert found.steps.tolist() == truth.steps.tolist()  # all registered, steps from the image names
    errors = trajectory_errors(found.poses, truth.poses)
    # measured: 2.6° mean, 6.5° max (3.4°, 5.7° without the final BA; COLMAP on sharp 240×160 checkers);
    # a wrong axis convention gives ~90°+
    assert errors["rot_mean_deg"] < 5.0 and errors["rot_max_deg"] < 10.0 and errors["ate_rel"] < 0.1, errors


def test_a_cut_pose_line_or_a_bad_point_in_a_colmap_model_is_named(tmp_path: Path) -> None:
    keys = np.arange(0, 40, 4)
    model = tmp_path / "model"
    _write_colmap_text(model, _truth()[keys], keys, np.zeros((2, 3)))
    assert len(read_colmap_text(model).poses) == len(keys)
    text = (model / "images.txt").read_text().splitlines()
    cut = [*text[:-2], " ".join(text[-2].split()[:6]), text[-1]]  # the last pose line cut to 6 fields
    (model / "images.txt").write_text("\n".join(cut) + "\n")
    with pytest.raises(InputError, match=r"images.txt: line 20: a pose line with 6 fields, not 10"):
        read_colmap_text(model)
    _write_colmap_text(tmp_path / "m2", _truth()[keys], keys, np.array([[0.0, 0.0, np.nan]]))
    with pytest.raises(InputError, match=r"points3D.txt: points3D.txt holds NaN"):
        read_colmap_text(tmp_path / "m2")
    (tmp_path / "m2" / "points3D.txt").write_text("1 1.0 2.0\n")
    with pytest.raises(InputError, match="point row 1: expected ID X Y Z R G B ERROR"):
        read_colmap_text(tmp_path / "m2")


def test_a_scaled_or_sheared_rotation_is_refused_naming_the_pose_file(tmp_path: Path) -> None:
    from spikenerf.importing.pose_set import check_poses

    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[1, :3, :3] = np.diag([2.0, 0.5, 1.0])  # determinant 1, not a rotation
    with pytest.raises(InputError, match=r"poses.npy: pose 1 is not a rotation: scaled, sheared or mirrored"):
        check_poses(poses, tmp_path / "poses.npy")


def test_an_imports_own_poses_reimport_with_its_range(capsys, recording, tmp_path: Path) -> None:
    """An import's transforms.json counts steps from its range's start; importing it again as the poses of
    the same range gives the same trajectory (before, it was refused, or shifted by the range's start)."""
    rec, _ = recording
    args = ["--keyframe-every", 4, "--window", 5, "--range", "10:30"]
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "a", *ORBIT, *args)
    assert code == 0, err
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "b", "--poses", tmp_path / "a" /
                           "transforms.json", "--fov", 40, "--orient", "none", *args)  # fmt: skip
    assert code == 0, err
    a, b = load_dataset(tmp_path / "a"), load_dataset(tmp_path / "b")
    assert a.config["imported"]["range"] == b.config["imported"]["range"] == [10, 30]
    np.testing.assert_allclose(b.trajectory.poses[:, :3, :3], a.trajectory.poses[:, :3, :3], atol=1e-6)


def test_too_few_registered_keeps_only_the_model_for_a_rerun(tmp_path: Path) -> None:
    from spikenerf.importing import colmap

    images, steps, settings = np.zeros((10, 8, 8)), np.arange(0, 40, 4), colmap.ColmapSettings()
    work = tmp_path / "ds.partial" / "colmap"
    _write_colmap_text(work / colmap.MODEL_DIR, _truth()[:3], np.arange(3), np.zeros((1, 3)))
    (work / "steps.json").write_text(colmap.colmap_fingerprint(images, steps, settings))
    (work / "images").mkdir()
    (work / "database.db").write_bytes(b"x")
    with pytest.raises(InputError, match=r"registered 3 of 10 keyframes.*its model stays in .*ds.partial"):
        colmap.run_colmap(images, steps, work, settings, min_registered=0.5)
    assert sorted(p.name for p in work.iterdir()) == sorted([colmap.MODEL_DIR, "steps.json"])


def test_two_frame_names_with_one_step_number_are_named(tmp_path: Path) -> None:
    from spikenerf.importing.pose_set import steps_from_names

    assert steps_from_names(["a/000120.png", "a/000130.png"]).tolist() == [120, 130]
    assert steps_from_names(["left.png", "right.png"]) is None  # unnumbered: spread evenly
    with pytest.raises(InputError, match=r"p.json: 'cam0_0001.png' and 'cam1_0001.png' name the same step"):
        steps_from_names(["cam0_0001.png", "cam1_0001.png"], tmp_path / "p.json")


def test_a_pose_file_inside_the_work_folder_is_refused(capsys, recording, tmp_path: Path) -> None:
    rec, _ = recording
    (tmp_path / "ds.partial").mkdir()
    (tmp_path / "ds.partial" / "p.json").write_text("{}")
    code, _, err = run_cli(capsys, "import", rec, "--poses", tmp_path / "ds.partial" / "p.json", "--fov", 40,
                           "--out", tmp_path / "ds")  # fmt: skip
    assert code == 2 and "holds the input" in err and (tmp_path / "ds.partial" / "p.json").is_file()


def test_an_import_leaving_one_training_keyframe_says_how_to_train_it(
    capsys, recording, tmp_path: Path
) -> None:
    rec, _ = recording
    args = ["--keyframe-every", 64, "--window", 5, "--out"]
    code, out, err = run_cli(capsys, "import", rec, *ORBIT, *args, tmp_path / "two")
    assert code == 0 and "2 keyframes), 1 test view" in out
    assert err.strip() == (
        "spikenerf: warning: 1 keyframe left after the test views: `train` refines poses between 2 or more, "
        "so train with --no-refine-poses (and --no-holdout where its guard bands leave too few steps), or "
        "import more steps (or with --test-every 0)"
    )
    code, _, err = run_cli(capsys, "import", rec, *ORBIT, "--test-every", 0, *args, tmp_path / "none")
    assert code == 0 and err == ""


@pytest.mark.parametrize(
    ("line", "pinhole", "lens"),
    [
        ("SIMPLE_RADIAL 48 16 30 24 8 -0.1", (30, 30, 24, 8), Distortion(k1=-0.1)),
        ("RADIAL 48 16 30 24 8 -0.1 0.02", (30, 30, 24, 8), Distortion(k1=-0.1, k2=0.02)),
        (
            "OPENCV 48 16 30 31 24 8 -0.1 0.02 0.001 -0.002",
            (30, 31, 24, 8),
            Distortion(k1=-0.1, k2=0.02, p1=0.001, p2=-0.002),
        ),
        (  # fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6: the rational k4-k6 zero
            "FULL_OPENCV 48 16 30 31 24 8 -0.1 0.02 0.001 -0.002 0.003 0 0 0",
            (30, 31, 24, 8),
            Distortion(k1=-0.1, k2=0.02, k3=0.003, p1=0.001, p2=-0.002),
        ),
        (
            "OPENCV_FISHEYE 48 16 30 31 24 8 0.05 -0.01 0.002 -0.0001",
            (30, 31, 24, 8),
            Distortion("OPENCV_FISHEYE", k1=0.05, k2=-0.01, k3=0.002, k4=-0.0001),
        ),
        (
            "RADIAL_FISHEYE 48 16 30 24 8 0.05 -0.01",
            (30, 30, 24, 8),
            Distortion("OPENCV_FISHEYE", 0.05, -0.01),
        ),
        ("SIMPLE_FISHEYE 48 16 30 24 8", (30, 30, 24, 8), Distortion("OPENCV_FISHEYE")),
        ("OPENCV 48 16 30 31 24 8 0 0 0 0", (30, 31, 24, 8), None),  # zero terms: a pinhole
    ],
)
def test_colmap_camera_models_keep_their_lens(tmp_path: Path, line: str, pinhole: tuple, lens) -> None:
    model = tmp_path / "model"
    keys = np.arange(0, T, 13)
    _write_colmap_text(model, _truth()[keys], keys, np.zeros((1, 3)))
    (model / "cameras.txt").write_text(f"# camera\n1 {line}\n")
    k = read_colmap_text(model).intrinsics
    assert (k.width, k.height, k.fl_x, k.fl_y, k.cx, k.cy) == (48, 16, *pinhole)
    assert k.distortion == lens


def test_an_imported_lens_is_written_read_and_carried_through(capsys, recording, tmp_path: Path) -> None:
    """COLMAP OPENCV → the dataset's transforms.json (nerfstudio's keys) → every reader; a transforms.json
    pose file carries its keys through, with or without w/h (a field of view), and under ``--fov``."""
    rec, _ = recording
    keys = np.arange(0, T, 5)
    model = tmp_path / "model"
    _write_colmap_text(model, _truth()[keys], keys, np.random.default_rng(1).uniform(-1, 1, (50, 3)))
    (model / "cameras.txt").write_text("1 OPENCV 48 16 30 31 24 8 -0.1 0.02 0.001 -0.002\n")
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", model)
    assert code == 0, err
    lens = Distortion(k1=-0.1, k2=0.02, p1=0.001, p2=-0.002)
    meta = json.loads((tmp_path / "ds" / "transforms.json").read_text())
    assert {k: meta[k] for k in ("camera_model", "k1", "k2", "p1", "p2")} == lens.as_json()
    ds = load_dataset(tmp_path / "ds")
    assert ds.intrinsics.distortion == lens and ds.intrinsics.fl_x == pytest.approx(30 * W / 48)
    code, text, _ = run_cli(capsys, "info", tmp_path / "ds")
    assert code == 0 and "lens: OPENCV k1=-0.1 k2=0.02 p1=0.001 p2=-0.002" in text
    frames = [{"step": int(s), "transform_matrix": _truth()[s].tolist()} for s in keys]
    box = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
    fisheye = {"camera_model": "OPENCV_FISHEYE", "k1": 0.03, "k2": -0.004}
    for i, (camera, extra) in enumerate(
        [
            ({"w": W, "h": H, "fl_x": 20.0, "cx": 12.0, "cy": 4.0}, []),
            ({"camera_angle_x": 1.2}, []),
            ({}, ["--fov", 60]),
        ]
    ):
        pose_file = tmp_path / f"p{i}.json"
        pose_file.write_text(json.dumps({**camera, **fisheye, "scene_box": box, "frames": frames}))
        out = tmp_path / f"ns{i}"
        code, _, err = run_cli(capsys, "import", rec, "--out", out, "--poses", pose_file, *extra)
        assert code == 0, err
        assert load_dataset(out).intrinsics.distortion == Distortion("OPENCV_FISHEYE", k1=0.03, k2=-0.004)


@pytest.mark.parametrize(
    ("camera", "message"),
    [
        ("1 FULL_OPENCV 48 16 30 31 24 8 -0.1 0.02 0 0 0 0.01 0 0", "its rational terms"),
        (
            "1 THIN_PRISM_FISHEYE 48 16 30 31 24 8 0 0 0 0 0 0 0 0",
            "camera_model THIN_PRISM_FISHEYE is not supported",
        ),
        ("1 FOV 48 16 30 31 24 8 0.5", "camera_model FOV is not supported"),
        ("1 OPENCV 48 16 30 31 24 8 -0.1", "camera_model OPENCV has 8 parameters"),
        ("1 SIMPLE_RADIAL 48 16 30 24 8 nan", "k1 must be a finite number"),
        (
            "1 SIMPLE_RADIAL 48 16 12 24 8 -0.9",
            "the OPENCV k1=-0.9 lens is not invertible over the 48×16 image",
        ),
    ],
)
def test_a_lens_that_cannot_be_applied_is_refused(capsys, recording, tmp_path, camera, message) -> None:
    rec, _ = recording
    keys = np.arange(0, T, 13)
    model = tmp_path / "model"
    _write_colmap_text(model, _truth()[keys], keys, np.zeros((1, 3)))
    (model / "cameras.txt").write_text(camera + "\n")
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", model)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert f"{model / 'cameras.txt'}: camera 1: " in err and not (tmp_path / "ds").exists()


@pytest.mark.parametrize(
    ("lens", "message"),
    [
        ({"camera_model": "EQUIRECTANGULAR"}, "field 'camera_model': 'EQUIRECTANGULAR' is not supported"),
        ({"camera_model": "OPENCV", "k1": "strong"}, "field 'k1': expected a finite number, found 'strong'"),
        ({"camera_model": "OPENCV", "k1": -5}, "fields 'camera_model', 'k1': the OPENCV k1=-5 lens is not"),
    ],
)
def test_a_bad_lens_in_a_pose_file_exits_2_naming_file_and_key(capsys, recording, tmp_path, lens, message):
    rec, _ = recording
    frames = [{"step": int(s), "transform_matrix": _truth()[s].tolist()} for s in (0, 13, 26, 39)]
    pose_file = tmp_path / "p.json"
    pose_file.write_text(json.dumps({"w": W, "h": H, "fl_x": 20.0, **lens, "frames": frames}))
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", pose_file)
    assert code == 2 and f"{pose_file}: {message}" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "ds").exists()

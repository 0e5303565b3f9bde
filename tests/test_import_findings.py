"""``spikenerf import``: a narrow lens on a known orbit, pose files that leave steps (or a test keyframe)
with a held pose, out-of-range orbit numbers, and what ``--keyframe-images`` is for (a review's findings)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from helpers import run_cli, write_recording
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.importing.interpolation import held_steps, per_step_poses
from spikenerf.importing.normalisation import normalisation
from spikenerf.scenes.trajectory import orbit

H, W, T = 8, 24, 200  # defaults: keyframes every 20 steps from step 10, test keyframes 30 and 189
ORBIT = ("--poses", "orbit", "--orbit", "4,30")


@pytest.fixture
def rec(tmp_path: Path) -> Path:
    return write_recording(tmp_path / "rec" / "recording.dat", T, H, W)


def _one_error(code: int, err: str, *words: str) -> None:
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert all(w in err for w in words), err


# ------------------------------------------------------------------------ 1. a narrow lens on an orbit
def test_a_narrow_lens_on_a_known_orbit_is_sized_around_its_centre(capsys, rec, tmp_path) -> None:
    """A 9° lens on a radius-4 orbit: the frustum box is under 5% of the cameras' spread, which used to be
    refused as axes that "do not converge"; the orbit's centre is known, so the box is the view there."""
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *ORBIT, "--fov", 9)
    assert code == 0, err
    norm = load_dataset(tmp_path / "ds").config["imported"]["normalisation"]
    assert norm["scale"] == pytest.approx(1 / (4 * math.tan(math.radians(4.5))))
    np.testing.assert_allclose(norm["center"], 0, atol=1e-9)


def test_cameras_alone_are_refused_for_what_is_actually_wrong() -> None:
    poses = orbit(4.0, 30.0, duration=200 / 40000).poses
    with pytest.raises(InputError, match="too narrow for the path") as narrow:
        normalisation(poses, camera_angle_x=math.radians(9))
    assert "parallel" not in str(narrow.value) and "converge" not in str(narrow.value)
    known = normalisation(poses, camera_angle_x=math.radians(9), focus=np.zeros(3))
    wide = normalisation(poses, camera_angle_x=math.radians(40))  # unchanged where the test passes
    assert wide.scale == pytest.approx(1 / (4 * math.tan(math.radians(20))))
    assert known.scale == pytest.approx(1 / (4 * math.tan(math.radians(4.5))))
    dolly = np.tile(np.eye(4), (5, 1, 1))
    dolly[:, 2, 3] = np.linspace(0, 2, 5)
    with pytest.raises(InputError, match="optical axes are parallel"):
        normalisation(dolly, camera_angle_x=0.7)


# ------------------------------------------------------------- 2. poses that leave steps with a held pose
def _poses_of(capsys, rec: Path, tmp_path: Path, first: int) -> Path:
    """The transforms.json of an orbit import of the recording's steps ``first:`` (one pose a step)."""
    out = tmp_path / f"from{first}"
    code, _, err = run_cli(capsys, "import", rec, "--out", out, *ORBIT, "--fov", 40, "--range", f"{first}:")
    assert code == 0, err
    return out / "transforms.json"


def test_poses_over_exactly_half_the_steps_are_refused(capsys, rec, tmp_path) -> None:
    poses = _poses_of(capsys, rec, tmp_path, 100)  # steps 100..199: 0..98 would keep step 99's pose
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", poses)
    _one_error(code, err, "transforms.json", "cover only 100 of the 200", "--range 100:200")
    assert not (tmp_path / "ds").exists()


def test_a_test_keyframe_at_a_held_pose_is_no_test_view_and_held_steps_are_warned(
    capsys, rec, tmp_path
) -> None:
    """Poses over steps 40..199: test keyframe 30 lies in the held steps 0..38. It was written as a test
    view at step 40's pose (then refused for a pose file, only warned for COLMAP); now, for any pose
    source, it is left out of the test views and the held steps are warned of."""
    poses = _poses_of(capsys, rec, tmp_path, 40)
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", poses)
    assert code == 0 and err.count("spikenerf: warning:") == 1, err
    assert "steps 0..38 (39 of the 200 imported)" in err and "hold no test view" in err, err
    assert "--range 40:200" in err, err
    imported = yaml.safe_load((tmp_path / "ds" / "config.yaml").read_text())["imported"]
    assert imported["test_keyframes"] == [189]  # 30 dropped: 189 is within the poses' steps
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "all", *ORBIT, "--fov", 40)
    assert code == 0 and "warning" not in err, err  # poses at every step: nothing held
    imported = yaml.safe_load((tmp_path / "all" / "config.yaml").read_text())["imported"]
    assert imported["test_keyframes"] == [30, 189]


def test_held_steps_are_those_per_step_poses_holds() -> None:
    truth = orbit(4.0, 30.0, duration=100 / 40000).poses
    for keys in (np.array([50, 60]), np.arange(20, 100), np.array([0, 30, 70, 99])):
        before, after = held_steps(keys, 100)
        poses = per_step_poses(truth[keys], keys, np.arange(100))
        moves = ~np.isclose(poses[1:], poses[:-1]).all((1, 2))  # step i → i+1
        assert not moves[:before].any() and (before == 0 or moves[before])
        assert not moves[99 - after :].any() and (after == 0 or moves[98 - after])


def test_held_out_keyframes_drop_those_at_held_poses_and_need_the_step_count() -> None:
    from spikenerf.importing.keyframes import held_out_keyframes

    keys = np.arange(10, 200, 20)  # test keyframes 30 and 190 (every 8th from the second)
    assert held_out_keyframes(keys, 8).tolist() == [30, 190]
    assert held_out_keyframes(keys, 8, np.arange(200), 200).tolist() == [30, 190]
    assert held_out_keyframes(keys, 8, np.arange(40, 200), 200).tolist() == [190]  # 0..38 held
    with pytest.raises(TypeError, match="needs n"):  # (n = 0 dropped every test view silently)
        held_out_keyframes(keys, 8, np.arange(200))


def test_a_warning_says_when_held_poses_leave_no_test_view(capsys, rec, tmp_path) -> None:
    from spikenerf.cli.import_ import held_pose_warning

    imported = {"pose_steps": list(range(40, 160)), "range": [0, 200], "test_keyframes": []}
    assert "hold no test view (none remains anywhere)" in held_pose_warning(imported, 200)
    imported["test_keyframes"] = [70]
    assert "(none remains" not in held_pose_warning(imported, 200)


# --------------------------------------------------------------------------------- 3. orbit numbers
@pytest.mark.parametrize(
    ("spec", "words"),
    [
        ("1e300,30", ["radius must lie within"]),
        ("1e-300,30", ["radius must lie within"]),
        ("nan,30", ["expected finite"]),
        ("4,inf", ["expected finite"]),
        ("4,30,1,1e300", ["start azimuth must lie within"]),
        ("4,91", ["elevation must lie within"]),
        ("4,89.99999999", ["(nearly) one place"]),
        ("4,30,1e-12", ["(nearly) one place"]),
        ("4,30,1e6", ["(nearly) one place"]),  # 5000 whole turns a step: every view from one place
    ],
)
def test_orbit_numbers_out_of_range_are_one_line(capsys, rec, tmp_path, spec, words) -> None:
    args = ("--poses", "orbit", "--orbit", spec, "--fov", 40)
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *args)
    _one_error(code, err, "--orbit", *words)
    assert not (tmp_path / "ds").exists() and not (tmp_path / "ds.partial").exists()


# ---------------------------------------------------------------------------- 4. --keyframe-images
def test_keyframe_images_says_it_also_makes_the_test_views() -> None:
    """``learned`` is accepted with any poses (tests/test_import_options.py imports an orbit with it): it
    makes the test views and places the keyframes, so the help must not call it a COLMAP setting."""
    from spikenerf.cli.import_ import command

    option = next(p for p in command.params if p.name == "keyframe_images")
    assert "test views" in option.help and "for COLMAP:" not in option.help
    doc = (Path(__file__).resolve().parents[1] / "docs" / "real-data.md").read_text(encoding="utf-8")
    assert "`--keyframe-images\n   learned`, whatever `--poses`" in doc


def test_import_reads_the_recorded_layout_and_refuses_another(capsys, rec, tmp_path) -> None:
    """A ``layout: topdown`` config.yaml was ignored by import (info and reconstruct read it)."""
    with (rec.parent / "config.yaml").open("a") as f:
        f.write("layout: topdown\n")
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *ORBIT, "--fov", 40)
    assert code == 0, err
    assert load_dataset(tmp_path / "ds").config["imported"]["layout"] == "topdown"
    code, _, err = run_cli(
        capsys, "import", rec, "--out", tmp_path / "ds2", *ORBIT, "--fov", 40, "--layout", "spikecv"
    )
    _one_error(code, err, "--layout spikecv differs from layout topdown in")
    assert not (tmp_path / "ds2").exists()


# ------------------------------------------------------------------------- 6. a new user's own pose files
def test_a_colmap_images_txt_without_its_points_lines_is_refused(capsys, rec, tmp_path) -> None:
    """A hand-written images.txt with one line an image (no POINTS2D line after each pose): every second
    pose was taken for a points line and dropped without a word (5 poses of 10)."""
    from test_import import _write_colmap_text

    keys = np.arange(0, T, 20)
    model = tmp_path / "model"
    _write_colmap_text(model, orbit(4.0, 30.0, duration=T / 40000).poses[keys], keys, np.zeros((3, 3)))
    lines = (model / "images.txt").read_text().splitlines()
    (model / "images.txt").write_text("\n".join([lines[0], *lines[1::2]]) + "\n")  # the pose lines alone
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", "--poses", model)
    _one_error(code, err, "images.txt: line 3: expected an image's POINTS2D line", "found 10 fields")
    assert not (tmp_path / "ds").exists()


def test_orbit_flags_say_which_one_is_missing_or_extra(capsys, rec, tmp_path) -> None:
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "a", "--poses", "orbit", "--fov", 40)
    _one_error(code, err, "--orbit R,ELEV[,TURNS[,AZIMUTH]] (the known path) is needed with --poses orbit")
    poses = _poses_of(capsys, rec, tmp_path, 0)
    code, _, err = run_cli(
        capsys, "import", rec, "--out", tmp_path / "b", "--poses", poses, "--orbit", "4,30"
    )
    _one_error(code, err, "--orbit R,ELEV[,TURNS[,AZIMUTH]] is only used with --poses orbit, not")


def test_poses_partly_outside_the_range_say_which_range_holds_them(capsys, rec, tmp_path) -> None:
    """Poses at steps 0..199 with ``--range 100:200``: "fall outside the selected steps" with no way out."""
    poses = _poses_of(capsys, rec, tmp_path, 0)
    code, _, err = run_cli(
        capsys, "import", rec, "--out", tmp_path / "ds", "--poses", poses, "--range", "100:200"
    )
    _one_error(
        code, err, "fall outside the selected steps 100..199: import a range that holds them (--range 0:200)"
    )


def test_a_recording_given_where_a_dataset_goes_says_to_import_it(capsys, rec, tmp_path) -> None:
    """``train rec`` said "missing file (not a dataset folder written by `spikenerf simulate`?)" and ``info
    rec`` "not a dataset folder" for the folder a camera gives (a .dat and its config.yaml)."""
    (rec.parent / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\n")
    for args in (
        ["train", rec.parent, "--out", tmp_path / "run"],
        ["info", rec.parent],
        ["train", rec, "--out", tmp_path / "r2"],
    ):
        code, _, err = run_cli(capsys, *args)
        _one_error(code, err, "spike recording", f"make one with `spikenerf import {rec}`")
    assert not (tmp_path / "run").exists()


def test_a_relative_dataset_in_a_config_file_names_the_file(capsys, tmp_path, monkeypatch) -> None:
    (tmp_path / "cfg").mkdir()
    (tmp_path / "cfg" / "my.yaml").write_text("dataset: d3\niters: 5\n")
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "train", "--config", "cfg/my.yaml", "--out", "r")
    _one_error(code, err, "d3: dataset folder not found (the 'dataset' of cfg/my.yaml, from the folder")


def test_a_field_of_view_that_looks_like_radians_is_warned(capsys, rec, tmp_path) -> None:
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds", *ORBIT, "--fov", 0.69)
    assert (
        code == 0
        and "--fov is in degrees: 0.69° is a very narrow lens (in radians 0.69 would be 39.5°)" in err
    )
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "ds40", *ORBIT, "--fov", 40)
    assert code == 0 and "narrow lens" not in err
    code, _, err = run_cli(capsys, "import", rec, "--out", tmp_path / "no", *ORBIT, "--fov", -1)
    _one_error(code, err, "--fov must be in (0, 180) degrees")  # (the error alone, no warning)


def test_too_few_colmap_keyframes_point_to_a_known_orbit_too() -> None:
    """A simulated recording (docs/real-data.md) registers no keyframe: the error names --poses orbit too."""
    from spikenerf.cli import flag_of
    from spikenerf.importing.colmap import _too_few

    shown = _too_few(0, 10, 20).shown(lambda param: flag_of(param, "import"))
    assert "COLMAP registered 0 of 10 keyframes" in shown and "--keyframe-every (now 20)" in shown
    assert "--poses FILE ('orbit' with the orbit's radius and elevation" in shown, shown
    assert "\n" not in shown

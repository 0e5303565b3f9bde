"""`simulate` defects from a user walkthrough: numbers that overflowed into tracebacks or into datasets its
own loader refused, an estimate that skipped --eval-views, options of the Python API that failed late or
wrote garbage, and an --overwrite that failed after it had succeeded."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli
from spikenerf.capture.options import SimulateOptions, check_options
from spikenerf.capture.simulate import check_bounds_of, simulate_dataset
from spikenerf.core.errors import InputError
from spikenerf.scenes.registry import make_scene_source
from spikenerf.scenes.trajectory import orbit

SIM = ["simulate", "--scene", "analytic-orbs", "--width", 8, "--height", 8, "--blur-fps", 0, "--no-progress"]


def _one_error(capsys, tmp_path: Path, *args: object) -> str:  # type: ignore[no-untyped-def]
    code, _, err = run_cli(capsys, *SIM, *args, "--out", tmp_path / "o")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.partial").exists()
    return err


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--frames", 20, "--radius", "1e20"], "within [1e-06, 1e+09]"),  # exit 0, NaN far
        (["--frames", 20, "--radius", "1e-300"], "--radius must be finite"),  # "eye and target coincide"
        (["--frames", 20, "--fps", "1e-320"], "--fps"),  # "--duration must be finite" (not given)
        (["--duration", "1e308"], "--duration × --fps must give at most"),  # OverflowError
        (["--duration", "1e10", "--fps", "1e300"], "must give at most"),
    ],
)
def test_extreme_orbit_numbers_are_one_line_naming_the_flag(capsys, tmp_path, args, words) -> None:  # type: ignore[no-untyped-def]
    assert words in _one_error(capsys, tmp_path, *args)


def test_eval_views_count_in_the_resource_estimate(capsys, tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """60000 poses in --eval-views were counted as 8 test views: the render started and ran out of memory."""
    monkeypatch.setattr("spikenerf.core.limits.available_memory", lambda: 24 * 2**20)
    assert run_cli(capsys, *SIM, "--frames", 1, "--out", tmp_path / "small")[0] == 0  # 8 views fit
    eye = np.eye(4)
    eye[2, 3] = 4.0
    views = tmp_path / "views.json"
    views.write_text(
        json.dumps({"camera_angle_x": 0.7, "frames": [{"transform_matrix": eye.tolist()}] * 60000})
    )
    err = _one_error(capsys, tmp_path, "--frames", 1, "--eval-views", views)
    assert (
        "--width/--height/--frames/--eval-views: this needs about" in err and "memory" in err
    )  # (not --blur-fps 0)
    missing = _one_error(capsys, tmp_path, "--frames", 1, "--eval-views", tmp_path / "nope.json")
    assert missing.strip().endswith("nope.json: pose file not found")  # (was "not a dataset folder …?")


@pytest.mark.parametrize(
    ("options", "words"),
    [
        ({"colors": None}, "colors must be a list"),  # TypeError
        ({"colors": ("gray", 5)}, "colors: expected gray"),  # TypeError
        ({"colors": "gray,gray"}, "gray is given twice"),  # written as [gray, gray]
        ({"gt_every": 1.5}, "gt_every must be an integer"),  # GT every 3rd step, config said 1
        ({"gt_every": float("nan")}, "gt_every must be an integer"),  # failed after the whole render
        ({"blur_fps": "400"}, "blur_fps must be a finite number"),  # TypeError
        ({"blur_fps": float("nan")}, "blur_fps must be a finite number"),  # ValueError
        ({"raw_width": "16"}, "raw_width must be an integer"),  # TypeError
        ({"extra": {"steps": 5}}, "would replace config.yaml's own keys"),  # info read the wrong steps
        ({"extra": {"x": object()}}, "config.yaml cannot hold it"),  # failed after the render
    ],
)
def test_simulate_options_are_checked_before_anything_is_rendered(options: dict, words: str) -> None:
    with pytest.raises(InputError, match=words) as err:
        check_options(SimulateOptions(**options))
    assert err.value.params == (next(iter(options)),)


def test_jobs_and_far_cameras_are_refused_before_rendering(tmp_path: Path) -> None:
    source = make_scene_source(
        "analytic-orbs", 8, 8, orbit(4.0, 30.0, duration=20 / 40000), np.zeros((0, 4, 4))
    )
    with pytest.raises(InputError, match="jobs must be an integer"):
        simulate_dataset(source, tmp_path / "o", SimulateOptions(), progress=False, jobs=1.5)  # type: ignore[arg-type]
    far = np.eye(4)[None].repeat(2, 0)
    far[:, 2, 3] = [1e20, 1e20]  # the bounds collapse: near = far (a dataset its loader refused)
    with pytest.raises(InputError, match="they lie too far from the scene box") as err:
        check_bounds_of(far, np.array([[-1.0] * 3, [1.0] * 3]))
    assert err.value.params == ("trajectory",)
    far[0, 0, 3] = np.nan
    with pytest.raises(InputError, match="NaN or an infinity"):
        check_bounds_of(far, np.array([[-1.0] * 3, [1.0] * 3]))
    assert not (tmp_path / "o").exists()


def test_an_overwrite_that_cannot_delete_the_old_copy_warns_and_the_next_one_deletes_it(
    capsys, tmp_path: Path, monkeypatch
) -> None:  # type: ignore[no-untyped-def]
    """An immutable file in the old copy: "error: config.yaml: Operation not permitted", exit 2, although the
    new dataset was in place, and the half-deleted copy (its marker gone) blocked every later --overwrite."""
    out = tmp_path / "o"
    assert run_cli(capsys, *SIM, "--frames", 20, "--out", out)[0] == 0
    real = shutil.rmtree

    def stuck(path, *args, **kw):  # type: ignore[no-untyped-def]
        if Path(path).name == ".o.old":
            (Path(path) / ".spikenerf").unlink()  # as rmtree removes the marker before the stuck file
            raise PermissionError(1, "Operation not permitted", "config.yaml")
        return real(path, *args, **kw)

    monkeypatch.setattr(shutil, "rmtree", stuck)
    code, _, err = run_cli(capsys, *SIM, "--frames", 20, "--seed", 5, "--overwrite", "--out", out)
    assert code == 0 and "could not be deleted (Operation not permitted: config.yaml)" in err, err
    assert "seed: 5" in (out / "config.yaml").read_text()
    monkeypatch.setattr(shutil, "rmtree", real)
    code, _, err = run_cli(capsys, *SIM, "--frames", 20, "--seed", 6, "--overwrite", "--out", out)
    assert code == 0 and not (tmp_path / ".o.old").exists(), err


def test_an_orbit_partly_inside_the_scene_box_passes_inside_it(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """At radius 1.5 half the steps were inside the [-1, 1]³ box: the warning said the orbit "lies inside"."""
    code, _, err = run_cli(
        capsys, *SIM, "--frames", 8, "--radius", 1.5, "--test-views", 0, "--out", tmp_path / "o"
    )
    assert code == 0 and "warning: the orbit passes inside the scene box" in err, err


def test_a_path_without_spikes_or_without_motion_is_warned_before_rendering(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``--threshold 3e38`` wrote a silent stream and ``--turns 0`` one still camera, both without a word."""
    code, _, err = run_cli(capsys, *SIM, "--frames", 8, "--threshold", 100, "--out", tmp_path / "a")
    assert code == 0 and "a white pixel fires once every 100 steps, more than the 8-step path" in err, err
    code, _, err = run_cli(
        capsys, *SIM, "--frames", 8, "--turns", 0, "--test-views", 0, "--out", tmp_path / "b"
    )
    assert code == 0 and "--turns 0 without --elevation-sweep: every step has the same pose" in err, err
    code, _, err = run_cli(capsys, *SIM, "--frames", 8, "--test-views", 0, "--out", tmp_path / "c")
    assert code == 0 and "warning" not in err, err


def test_a_retired_copy_that_still_cannot_be_deleted_is_named(capsys, tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The next --overwrite said only "spikes_gray.dat: Operation not permitted" (no folder named)."""
    out = tmp_path / "o"
    assert run_cli(capsys, *SIM, "--frames", 20, "--out", out)[0] == 0
    real = shutil.rmtree

    def stuck(path, *args, **kw):  # type: ignore[no-untyped-def]
        if Path(path).name == ".o.old":
            raise PermissionError(1, "Operation not permitted", "spikes_gray.dat")
        return real(path, *args, **kw)

    monkeypatch.setattr(shutil, "rmtree", stuck)
    assert run_cli(capsys, *SIM, "--frames", 20, "--seed", 5, "--overwrite", "--out", out)[0] == 0
    code, _, err = run_cli(capsys, *SIM, "--frames", 20, "--seed", 6, "--overwrite", "--out", out)
    assert code == 2 and ".o.old: a copy an earlier replacement left cannot be deleted" in err, err
    assert "delete it yourself" in err and "seed: 5" in (out / "config.yaml").read_text()


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "--scene", "analytic-orbs"],
        ["train", "ds"],
        ["recon-data"],
        ["recon-train", "pairs"],
        ["reconstruct", "r.dat", "--method", "tfp"],
        ["import", "r.dat", "--poses", "orbit", "--orbit", "4,30"],
        ["render", "run"],
        ["benchmark"],
        ["demo"],
    ],
)
def test_an_empty_out_is_refused_by_every_command(capsys, argv: list[str]) -> None:  # type: ignore[no-untyped-def]
    """``--out ""`` was read as ``.``, the current folder, and reported as such."""
    code, _, err = run_cli(capsys, *argv, "--out", "")
    assert code == 2 and "'--out': the path is empty" in err and len(err.strip().splitlines()) == 1, err

"""A folded COLMAP model (a trajectory that jumps) is caught: refitted sequentially, or refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli
from spikenerf.camera.io import write_dat
from spikenerf.cli import flag_of
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.importing import colmap
from spikenerf.importing.alignment import trajectory_jump
from spikenerf.importing.pose_set import PoseSet
from spikenerf.scenes.poses import look_at


def _orbit(n: int = 50, flip_from: int | None = None, noise: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Keyframes every 20 steps of a 1000-step orbit (radius 4, 30° up); from ``flip_from`` on, the
    cameras sit half a turn further round (what a fold does)."""
    steps = np.arange(n) * 20
    az = 2 * np.pi * steps / 1000.0
    if flip_from is not None:
        az[flip_from:] += np.pi
    eye = np.stack(
        [4 * np.cos(az) * np.cos(0.52), 4 * np.sin(az) * np.cos(0.52), np.full(n, 4 * np.sin(0.52))], 1
    )
    eye += np.random.default_rng(0).normal(0, noise, eye.shape)
    return np.stack([look_at(e, np.zeros(3)) for e in eye]), steps


def test_a_smooth_orbit_has_no_jump_and_a_fold_is_found_where_it_is():
    poses, steps = _orbit()
    assert trajectory_jump(poses, steps) is None
    assert trajectory_jump(*_orbit(noise=0.02)) is None  # jitter of 0.5% of the radius is no jump
    jump = trajectory_jump(*_orbit(flip_from=30))
    assert jump is not None and (jump.a, jump.b) == (580, 600)
    assert jump.turn_deg > 150 and jump.ratio > 5
    assert "580 and 600" in jump.describe()


def test_a_gap_of_unregistered_keyframes_is_no_jump_and_a_still_camera_is_none():
    poses, steps = _orbit()
    keep = np.r_[0:20, 30:50]  # ten keyframes missing: a long but steady gap
    assert trajectory_jump(poses[keep], steps[keep]) is None
    still = np.repeat(poses[:1], 10, axis=0)
    still[:, :3, 3] += np.random.default_rng(1).normal(0, 1e-4, (10, 3))
    assert trajectory_jump(still, np.arange(10) * 20) is None  # no rate to compare with: tiny moves only


def test_a_camera_that_starts_or_speeds_up_is_no_jump_but_a_single_leap_is():
    eye = np.zeros((50, 3))
    eye[:, 0] = np.r_[np.zeros(30), 0.05 * np.arange(1, 21)]  # still for 30 keyframes, then steady motion
    poses = np.stack([look_at(e, np.array([0.0, 5.0, 0.0])) for e in eye])
    assert trajectory_jump(poses, np.arange(50) * 20) is None
    faster = np.r_[np.arange(25) * 20, 480 + np.arange(1, 26) * 3.3].astype(np.int64)  # 6× faster halfway
    assert trajectory_jump(_orbit()[0], faster) is None
    eye[35:, 0] += 2.0  # one leap of 2 units between two neighbouring keyframes, no turn
    leap = trajectory_jump(
        np.stack([look_at(e, e + np.array([0.0, 5.0, 0.0])) for e in eye]), np.arange(50) * 20
    )
    assert leap is not None and leap.what == "move" and (leap.a, leap.b) == (680, 700)
    assert "it moves 2.05 there" in leap.describe()


#: the threads each faked COLMAP run was given
THREADS: list[int] = []


@pytest.fixture
def fake_colmap(monkeypatch):
    """run_colmap replaced by a lookup: folder name -> poses (folded or not)."""
    calls: list[tuple[str, int]] = []
    models: dict[str, PoseSet] = {}

    def fake(images, steps, work, settings, min_registered, keyframe_every, threads=-1, verbose=False):
        calls.append((Path(work).name, settings.exhaustive_up_to))
        THREADS.append(threads)
        return models[Path(work).name]

    monkeypatch.setattr(colmap, "run_colmap", fake)
    return calls, models


def _run(tmp_path: Path, settings: colmap.ColmapSettings | None = None) -> PoseSet:
    settings = settings or colmap.ColmapSettings()
    folders = (tmp_path / "colmap", tmp_path / "colmap-sequential")
    return colmap.unfolded_colmap(
        np.zeros((50, 8, 8)), np.arange(50) * 20, folders, settings, (0.5, 20, False)
    )


def test_a_folded_loop_model_is_replaced_by_the_sequential_one(tmp_path, fake_colmap):
    calls, models = fake_colmap
    folded, steps = _orbit(flip_from=30)
    models["colmap"] = PoseSet(folded, steps)
    models["colmap-sequential"] = PoseSet(*_orbit())
    found = _run(tmp_path)
    assert calls == [("colmap", colmap.ColmapSettings.exhaustive_up_to), ("colmap-sequential", 0)]
    assert np.allclose(found.poses, models["colmap-sequential"].poses)
    assert "sequential matching" in found.note and "580 and 600" in found.note


def test_a_clean_model_is_kept_without_a_second_run(tmp_path, fake_colmap):
    calls, models = fake_colmap
    models["colmap"] = PoseSet(*_orbit())
    found = _run(tmp_path)
    assert calls == [("colmap", colmap.ColmapSettings.exhaustive_up_to)] and found.note == ""


@pytest.mark.parametrize("loop", [True, False])
def test_a_fold_that_remains_is_refused_naming_the_steps(tmp_path, fake_colmap, loop):
    calls, models = fake_colmap
    models["colmap"] = models["colmap-sequential"] = PoseSet(*_orbit(flip_from=30))
    settings = colmap.ColmapSettings(exhaustive_up_to=colmap.ColmapSettings.exhaustive_up_to if loop else 0)
    with pytest.raises(InputError, match=r"steps 580 and 600.*folded") as err:
        _run(tmp_path, settings)
    assert err.value.params == ("frame_range", "keyframe_every", "poses")
    shown = err.value.shown(lambda name: flag_of(name, "import"))
    assert "another --range or --keyframe-every, or give --poses FILE" in shown
    assert len(calls) == (2 if loop else 1)  # no second fit when the first was sequential already


def test_the_import_keeps_the_sequential_refit_says_so_and_publishes_no_scratch(
    capsys, tmp_path, monkeypatch
):
    t = 400
    rec = tmp_path / "rec" / "stream.dat"
    write_dat(rec, (np.random.default_rng(0).random((t, 8, 24)) < 0.3).astype(np.uint8))
    (rec.parent / "config.yaml").write_text("spike_h: 8\nspike_w: 24\n")

    def fake(images, steps, work, settings, min_registered, keyframe_every, threads=-1, verbose=False):
        work.mkdir(parents=True, exist_ok=True)
        (work / "model").mkdir(exist_ok=True)
        (work / "database.db").write_bytes(b"scratch")  # what COLMAP leaves beside its model
        az = 2 * np.pi * steps / t + (np.pi * (steps > t // 2) if work.name == "colmap" else 0.0)
        eye = np.stack([4 * np.cos(az), 4 * np.sin(az), np.full(len(az), 2.0)], 1)
        return PoseSet(np.stack([look_at(e, np.zeros(3)) for e in eye]), np.asarray(steps))

    monkeypatch.setattr(colmap, "run_colmap", fake)
    out = tmp_path / "ds"
    code, stdout, err = run_cli(capsys, "import", rec, "--out", out, "--keyframe-every", 10, "--fov", 40)
    assert code == 0, err
    assert "; sequential matching (matching all pairs gave a jump between steps" in stdout
    note = load_dataset(out).config["imported"]["pose_note"]
    assert note.startswith("sequential matching") and "it turns 1" in note
    assert sorted(p.relative_to(out).as_posix() for p in out.glob("colmap*/**/*")) == [
        "colmap-sequential/model",
        "colmap/model",
    ]
    monkeypatch.setattr(colmap, "run_colmap", lambda *a, **k: fake(a[0], a[1], a[2].parent / "x", *a[3:]))
    code, _, err = run_cli(capsys, "import", rec, "--out", out, "--overwrite", "--poses", "orbit",
                           "--orbit", "4,30", "--fov", 40)  # fmt: skip
    assert code == 0, err
    assert not list(out.glob("colmap*")) and "pose_note" not in load_dataset(out).config["imported"]


def test_colmap_runs_on_the_threads_spikenerf_was_given(fake_colmap, tmp_path: Path, monkeypatch) -> None:
    """``spikenerf --threads 1`` reaches COLMAP (one thread makes its model repeatable); unset: every core."""
    _, models = fake_colmap
    models["colmap"] = PoseSet(
        np.tile(np.eye(4), (50, 1, 1)), np.arange(50) * 20, None, None, None, tuple(f"{i}" for i in range(50))
    )
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    THREADS.clear()
    _run(tmp_path)
    monkeypatch.delenv("OMP_NUM_THREADS")
    _run(tmp_path)
    assert THREADS[0] == 1 and THREADS[-1] == -1

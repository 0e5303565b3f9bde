"""``simulate --blur-views``: exposure windows, running-sum exposures, the array format and bad inputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from spikenerf.capture.blur import RunningExposures, blur_window_count, blur_windows, check_blur_views
from spikenerf.cli import main
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.data.summary import view_counts
from spikenerf.data.targets import blur_targets
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.poses import pose_at
from spikenerf.scenes.trajectory import novel_views, orbit

STEPS, SIZE = 40, 12
#: 40 steps at 40 kHz, a 4000 fps blur camera: 10 steps per exposure
ARGS = ["--width", str(SIZE), "--height", str(SIZE), "--frames", str(STEPS), "--blur-fps", "4000",
        "--test-views", "1", "--no-progress"]  # fmt: skip


def test_windows_all_frames_and_n() -> None:
    frames = blur_windows(1000, 40000, 400, "frames")
    assert len(frames) == 10 and frames[0] == (0, 100) and frames[-1] == (900, 1000)
    every = blur_windows(1000, 40000, 400, "all")
    assert len(every) == 1000  # one exposure centred on every step, overlapping
    assert (
        every[500] == (450, 550) and every[0] == (0, 50) and every[999] == (949, 1000)
    )  # clipped at the ends
    assert all(b - a == 100 for a, b in every[50:950])
    assert blur_windows(1000, 40000, 400, 10) == frames  # 10 evenly spaced centres = the 10 frames here
    four = blur_windows(1000, 40000, 400, "4")
    assert [(a + b) // 2 for a, b in four] == [125, 375, 625, 875]  # centres floor((j + 0.5)·T/N)
    assert blur_windows(1000, 40000, 400, 1000) == every
    assert blur_windows(10, 40000, 0, "all") == []


@pytest.mark.parametrize("views", ["frames", "all", 7, "3"])
@pytest.mark.parametrize(("steps", "blur_fps"), [(1000, 400), (999, 400), (40, 4000), (10, 0), (7, 40000)])
def test_window_count_is_the_list_length_without_the_list(
    views: str | int, steps: int, blur_fps: float
) -> None:
    windows = blur_windows(steps, 40000, blur_fps, views)
    assert blur_window_count(steps, 40000, blur_fps, views) == len(windows)


def test_window_count_of_a_huge_stream_is_instant() -> None:
    assert blur_window_count(10**11, 40000, 400, "frames") == 10**9  # no list of a billion windows
    with pytest.raises(InputError, match="blur_fps"):
        blur_window_count(100, 400, 4000, "frames")


@pytest.mark.parametrize("views", ["frames", "all", 7])
def test_running_sum_equals_the_mean_of_each_window(views: str | int) -> None:
    rng = np.random.default_rng(0)
    frames = rng.random((STEPS, 3, 4, 3)).astype(np.float32)
    windows = blur_windows(STEPS, 40000, 4000, views)
    reads: list[int] = []

    def frame_at(i: int) -> np.ndarray:
        reads.append(i)
        return frames[i]

    blur = RunningExposures(windows, frame_at)
    got = [item for f in frames for item in blur.push(f)]
    assert [w for w, _ in got] == list(range(len(windows)))
    for (w, image), (a, b) in zip(got, windows, strict=True):
        np.testing.assert_allclose(
            image, frames[a:b].astype(np.float64).mean(0), rtol=1e-12, atol=1e-12, err_msg=f"window {w}"
        )
    assert len(reads) <= STEPS  # each frame leaves the running sum at most once


def test_simulate_all_views_writes_one_array_and_loads_it(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    main(["simulate", "--scene", "analytic-orbs", "--out", str(out), *ARGS, "--blur-views", "all"])
    assert (out / "blur" / "views.npy").is_file() and not list((out / "blur").glob("*.png"))
    assert yaml.safe_load((out / "config.yaml").read_text())["blur_views"] == "all"
    ds = load_dataset(out)
    assert ds.blur is not None and len(ds.blur) == STEPS and ds.blur.images.dtype == np.float16
    windows = blur_windows(STEPS, 40000, 4000, "all")
    np.testing.assert_array_equal(ds.blur.step_ranges, windows)
    src = AnalyticSource(
        "analytic-orbs", SIZE, SIZE, orbit(4.0, 30.0, duration=STEPS / 40000), novel_views(4, 1)
    )
    frames = np.stack(list(src.frames(range(STEPS))))
    for k in (0, 3, 20, STEPS - 1):
        a, b = windows[k]
        np.testing.assert_allclose(ds.blur.images[k], frames[a:b].mean(0), atol=2e-3)
        np.testing.assert_allclose(
            ds.blur.poses[k], pose_at(src.trajectory.poses, (a + b - 1) / 2), atol=1e-6
        )
    counts = view_counts(out)
    assert counts == {"steps": STEPS, "gt": 4, "blur": STEPS, "blur_views": "all"}
    from spikenerf.data.summary import describe

    assert "overlapping exposures, not consecutive frames" in describe(out)  # one centred on each step
    targets = blur_targets(ds, "rgb")
    assert targets.images.shape == (STEPS, SIZE, SIZE, 3) and len(targets) == STEPS
    aware = blur_targets(ds, "gray", samples=4)
    assert tuple(aware.poses.shape) == (STEPS, 4, 4, 4)

    main(
        ["simulate", "--scene", "analytic-orbs", "--out", str(out), *ARGS, "--blur-views", "3", "--overwrite"]
    )
    ds = load_dataset(out)
    assert len(ds.blur) == 3 and view_counts(out)["blur_views"] == 3
    np.testing.assert_array_equal(ds.blur.step_ranges, [[1, 11], [15, 25], [28, 38]])


def test_bad_blur_views(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    kinds = "expected all, frames or a positive integer"
    for bad, words in [("0", "must be ≥ 1"), (str(STEPS + 1), f"exceeds the {STEPS} spike steps"),
                       ("some", kinds), ("-3", "must be ≥ 1")]:  # fmt: skip
        with pytest.raises(SystemExit) as exit_:
            main(
                [
                    "simulate",
                    "--scene",
                    "analytic-orbs",
                    "--out",
                    str(tmp_path / "x"),
                    *ARGS,
                    "--blur-views",
                    bad,
                ]
            )
        assert exit_.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--blur-views" in err and words in err, err
        assert not list(tmp_path.iterdir())  # nothing half-written
    with pytest.raises(InputError, match="exceeds the 1000 spike steps"):
        check_blur_views("1001", 1000)
    assert check_blur_views(" all ", 5) == "all" and check_blur_views("5", 5) == 5


def test_corrupt_blur_array_is_one_input_error(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    main(["simulate", "--scene", "analytic-orbs", "--out", str(out), *ARGS, "--blur-views", "5"])
    good = np.load(out / "blur" / "views.npy")
    np.save(out / "blur" / "views.npy", np.zeros((4, SIZE, SIZE, 3), np.float16))
    with pytest.raises(InputError, match=r"shape \(5, 12, 12, 3\)"):
        load_dataset(out)
    from spikenerf.data.targets import blur_targets

    for view, value in ((3, np.nan), (0, np.inf), (4, -0.5)):  # values the simulator never writes
        bad = good.copy()
        bad[view, 2, 5, 1] = value
        np.save(out / "blur" / "views.npy", bad)
        ds = load_dataset(out)  # (not read whole at every load: the array can be gigabytes)
        for samples in (None, 2):  # as nerf-blur and the exposure-aware methods read them
            with pytest.raises(InputError, match=f"blur view {view} holds a NaN, an infinity or a negative"):
                blur_targets(ds, "gray", samples)
    np.save(out / "blur" / "views.npy", good)
    assert len(blur_targets(load_dataset(out), "gray").images) == 5


def test_blur_array_with_train_filenames_keeps_the_images_of_the_kept_frames(tmp_path: Path) -> None:
    """A blur view file with both ``images_npy`` and a nerfstudio ``train_filenames`` list: the images
    loaded are those of the frames the list keeps, as the poses are (they were the first N of the array)."""
    out = tmp_path / "ds"
    main(["simulate", "--scene", "analytic-orbs", "--out", str(out), *ARGS, "--blur-views", "5"])
    whole = load_dataset(out).blur
    meta_path = out / "transforms_blur.json"
    meta = json.loads(meta_path.read_text())
    for i, frame in enumerate(meta["frames"]):
        frame["file_path"] = f"blur/{i}"
    meta["train_filenames"] = ["blur/1", "blur/3"]
    meta_path.write_text(json.dumps(meta))
    kept = load_dataset(out).blur
    assert kept is not None and whole is not None and len(kept.poses) == 2
    np.testing.assert_array_equal(kept.poses, whole.poses[[1, 3]])
    np.testing.assert_array_equal(np.asarray(kept.images), np.asarray(whole.images)[[1, 3]])
    np.testing.assert_array_equal(kept.step_ranges, whole.step_ranges[[1, 3]])

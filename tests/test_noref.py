"""The real-data path at tiny size: ``simulate --noise realistic --raw-width`` → ``import`` (no poses in the
recording; a known orbit) → ``train`` → ``eval`` with the no-reference checks; good model vs broken ones."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from helpers import run_cli
from spikenerf.camera.io import read_dat
from spikenerf.cli import main
from spikenerf.core.errors import InputError
from spikenerf.data.targets import window_steps
from spikenerf.eval import noref
from spikenerf.eval.evaluate import display
from spikenerf.eval.noref import NoRefOptions, check_steps, noref_metrics, wants_noref
from spikenerf.eval.piqe import piqe
from spikenerf.render import model_from_hparams
from spikenerf.train.config import WINDOW_POSES
from spikenerf.train.run import load_run

SIZE, RAW, STEPS = 24, 40, 80
#: the orbit analytic scenes are simulated on (radius 4, 30° up, one turn) and their field of view
ORBIT = ["--poses", "orbit", "--orbit", "4,30", "--fov", 39.5978]
#: a small grid that learns the tiny scene in a few dozen iterations
TRAIN = ["--iters", 60, "--batch", 1024, "--eval-every", 0, "--eval-views", 1, "--spike-warmup", 30,
         "--spike-window", 8, "--spike-pixels", 32, "--device", "cpu", "--quiet",
         "--field-option", "n_voxels_init=4096", "--field-option", "n_voxels_final=4096",
         "--field-option", "density_shift=-2",
         "--holdout-radius", 4]  # fmt: skip
#: the hold-out (on for imported data) keeps steps 16..24, 36..44 and 56..64 out of training


def _cli(*args: object) -> None:
    main([str(a) for a in args])


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The documented workflow (docs/real-data.md, *Try it on a simulated recording*) at 24×24, 80 steps."""
    root = tmp_path_factory.mktemp("noref")
    _cli("simulate", "--scene", "analytic-blocks", "--width", SIZE, "--height", SIZE, "--frames", STEPS,
         "--noise", "realistic", "--raw-width", RAW, "--test-views", 1, "--blur-fps", 0, "--no-progress",
         "--out", root / "sim")  # fmt: skip
    rec = root / "rec" / "recording.dat"  # the "camera" files alone, away from the simulated truth
    rec.parent.mkdir()
    for name in ("recording.dat", "config.yaml"):
        (rec.parent / name).write_bytes((root / "sim" / "raw" / name).read_bytes())
    _cli("import", rec, *ORBIT, "--keyframe-every", 10, "--test-every", 2, "--out", root / "ds")
    _cli("train", root / "ds", *TRAIN, "--out", root / "run")
    return root


def test_raw_recording_is_the_stream_with_padding_and_no_poses(demo: Path) -> None:
    config = yaml.safe_load((demo / "rec" / "config.yaml").read_text())
    assert config == {"spike_h": SIZE, "spike_w": SIZE, "raw_width": RAW, "fps": 40000.0}
    raw = read_dat(demo / "rec" / "recording.dat", SIZE, RAW)
    assert raw.shape == (STEPS, SIZE, RAW) and not raw[..., SIZE:].any()
    np.testing.assert_array_equal(raw[..., :SIZE], read_dat(demo / "sim" / "spikes_gray.dat", SIZE, SIZE))
    imported = yaml.safe_load((demo / "ds" / "config.yaml").read_text())["imported"]
    assert imported["raw_width"] == RAW and imported["test_keyframes"] == [20, 40, 60]


def test_eval_reports_no_reference_checks_on_imported_data_by_default(demo: Path, capsys) -> None:
    run = demo / "run"
    code, out, err = run_cli(capsys, "eval", run, "--device", "cpu", "--lpips", "none", "--spike-pixels", 64,
                             "--quiet")  # fmt: skip
    assert code == 0, err
    assert "no-reference at 3 check steps (held out)" in out and "interval violations" in out
    nr = json.loads((run / "metrics.json").read_text())["no_reference"]
    assert nr["steps_from"] == "the imported test keyframes" and nr["steps_trained_on"] is False
    assert json.loads((run / "holdout.json").read_text())["check_steps"] == [20, 40, 60]
    assert [r["step"] for r in nr["per_step"]] == [20, 40, 60]
    assert (nr["spike_window"], nr["spike_pixels"]) == (8, 64)
    score = nr["image_score"]
    assert score["name"] == "PIQE" and score["higher_is_worse"] is True and nr["image_score_reason"] is None
    m = nr["mean"]
    assert 0 < m["mask_fraction"] <= 1 and 10 < m["masked_psnr"] < 60 and 0 < m["masked_ssim"] <= 1
    for key in ("interval_violation_rate", "recon_interval_violation_rate"):
        assert 0 <= m[key] <= 1
    for key in (score["render"], score["reconstruction"]):  # piqe_render, piqe_recon: per step and mean
        per_step = [r[key] for r in nr["per_step"]]
        assert all(isinstance(v, float) and 0 <= v <= 100 for v in per_step), (key, per_step)
        assert m[key] == pytest.approx(np.mean(per_step))
    assert f"PIQE {m['piqe_render']:.1f} (reconstruction: {m['piqe_recon']:.1f}; 0-100" in out
    code, out, _ = run_cli(capsys, "info", run)
    assert (
        code == 0
        and f"no-reference at 3 check steps (held out): masked PSNR {m['masked_psnr']:.2f} dB" in out
        and f"PIQE {m['piqe_render']:.1f} (reconstruction" in out
    )
    code, out, err = run_cli(capsys, "eval", run, "--device", "cpu", "--lpips", "none", "--noref", "off",
                             "--quiet")  # fmt: skip
    assert code == 0 and "no-reference" not in out
    assert json.loads((run / "metrics.json").read_text())["no_reference"] is None


def test_the_image_score_of_a_displayed_image() -> None:
    """``piqe_score`` takes eval's displayed (C, H, W) images: grey (1, H, W) as (H, W), RGB as (H, W, 3);
    None where PIQE has no whole block or the render is not finite (as the other scores)."""
    rgb = torch.rand(3, 24, 40, generator=torch.Generator().manual_seed(0))
    assert noref.piqe_score(rgb) == piqe(rgb.numpy().transpose(1, 2, 0)).score
    assert noref.piqe_score(rgb[:1]) == piqe(rgb[0].numpy()).score != noref.piqe_score(rgb)
    assert noref.piqe_score(rgb[:, :15]) is None and "16 px" in noref.SMALL_IMAGE_REASON
    rgb[1, 3, 3] = float("nan")
    assert noref.piqe_score(rgb) is None


def _spy_renders(monkeypatch) -> list[np.ndarray]:  # type: ignore[no-untyped-def]
    """Record the pose of every image render (``render_mean`` renders each of its poses through
    ``render.model.render_image``); the list it fills."""
    import spikenerf.render.model as module

    seen: list[np.ndarray] = []
    real = module.render_image

    def spy(m, pose, *args, **kw):  # type: ignore[no-untyped-def]
        seen.append(np.asarray(pose))
        return real(m, pose, *args, **kw)

    monkeypatch.setattr(module, "render_image", spy)
    return seen


def test_eval_scores_tfp_keyframes_against_the_window_mean_of_a_window_aware_run(
    demo: Path, monkeypatch
) -> None:  # type: ignore[no-untyped-def]
    import spikenerf.eval.evaluate as ev

    _, config, dataset = load_run(demo / "run")
    seen = _spy_renders(monkeypatch)
    result = ev.evaluate_run(demo / "run", lpips_backbone=None, progress=False, noref="off")
    assert result["view_poses"] == config.targets.poses_per_target() == WINDOW_POSES
    window = int(dataset.config["imported"]["window"])
    first = window_steps(len(dataset.trajectory), window, WINDOW_POSES)[20]  # test keyframe 20
    ckpt = torch.load(demo / "run" / "checkpoint.pt", weights_only=True)
    path = ev.refined_dataset(ckpt, config, dataset).trajectory.poses  # the run refined its poses
    assert len(seen) == 3 * WINDOW_POSES and np.allclose(np.stack(seen[:WINDOW_POSES]), path[first])
    # the test-time pose fit moves each keyframe's S poses by one correction and scores their mean render
    seen.clear()
    fit = (3, 2e-3)
    result = ev.evaluate_run(demo / "run", lpips_backbone=None, progress=False, noref="off", test_pose=fit)
    fitted = np.stack(seen[3 * WINDOW_POSES :])
    assert len(fitted) == 3 * WINDOW_POSES and not np.allclose(fitted[:WINDOW_POSES], path[first])
    moved = np.linalg.inv(path[first]) @ fitted[:WINDOW_POSES]  # each pose's camera-frame correction
    assert np.allclose(moved, moved[0], atol=1e-4) and result["test_pose_optimised"]["mean"]["psnr"] > 10
    # the views themselves are not keyframes of the stream (no imported test_keyframes): one render each
    assert ev.keyframe_windows(dataclasses.replace(dataset, config={}), WINDOW_POSES, dataset.test) is None
    assert ev.keyframe_windows(dataset, 1, dataset.test) is None
    older = {**dataset.config, "imported": {**dataset.config["imported"], "window": None}}
    assert ev.keyframe_windows(dataclasses.replace(dataset, config=older), WINDOW_POSES, dataset.test) is None
    # test views that are not the recorded keyframes (an edited dataset): refused, not scored on one render
    fewer = dataclasses.replace(dataset.test, poses=dataset.test.poses[:2], images=dataset.test.images[:2])
    with pytest.raises(InputError, match=r"2 test views but config\.yaml records 3 imported test keyframes"):
        ev.keyframe_windows(dataset, WINDOW_POSES, fewer)
    assert ev.keyframe_windows(dataset, 1, fewer) is None  # a one-pose run does not use the keyframes
    for key, value, says in (("window", 0, "imported.window"), ("window", True, "imported.window"),
                             ("test_keyframes", "abc", "imported.test_keyframes")):  # fmt: skip
        edited = {**dataset.config, "imported": {**dataset.config["imported"], key: value}}
        with pytest.raises(InputError, match=says):
            ev.keyframe_windows(dataclasses.replace(dataset, config=edited), WINDOW_POSES, dataset.test)


def test_info_says_how_a_window_aware_run_trains_and_was_scored(demo: Path, capsys) -> None:
    run = demo / "run"
    code, out, err = run_cli(capsys, "eval", run, "--device", "cpu", "--lpips", "none", "--noref", "off",
                             "--quiet")  # fmt: skip
    assert code == 0, err
    code, out, _ = run_cli(capsys, "info", run)
    # a spike-integral run trains on spike counts: the window-aware renders are eval's, not its targets
    keyframes = "eval's TFP keyframes (the imported dataset's test views): each against the mean of"
    assert code == 0 and f"{keyframes} {WINDOW_POSES} renders" in out
    assert f"metrics.json (test, 3 views, each against the mean of {WINDOW_POSES} renders): PSNR" in out


def test_eval_without_views_to_score_runs_the_checks_alone(demo: Path, capsys) -> None:
    """An imported dataset has no sharp GT frames (and may have no test views): eval still reports the
    no-reference checks instead of refusing the only metrics real data has."""
    run = demo / "run"
    code, out, err = run_cli(capsys, "eval", run, "--split", "train", "--device", "cpu", "--lpips", "none",
                             "--spike-pixels", 16, "--quiet")  # fmt: skip
    assert code == 0, err
    assert "on 0 train views: PSNR n/a" in out and "no-reference at 3 check steps" in out
    result = json.loads((run / "metrics_train.json").read_text())  # (held-out scores stay in metrics.json)
    assert result["views"] == 0 and result["no_reference"]["mean"]["masked_psnr"] is not None
    code, out, _ = run_cli(capsys, "info", run)  # no empty "metrics_train.json (train, 0 views):" line
    assert code == 0 and "metrics_train.json (" not in out, out
    assert "metrics_train.json: no-reference at 3 check steps (held out)" in out, out
    code, _, err = run_cli(capsys, "eval", run, "--split", "train", "--noref", "off", "--quiet")
    assert code == 2 and "no train views" in err


def _sideways(poses: np.ndarray, distance: float) -> np.ndarray:
    """Every camera moved ``distance`` along its own x axis (a misregistered trajectory)."""
    out = poses.copy()
    out[:, :3, 3] += distance * out[:, :3, 0]
    return out


def test_a_good_model_scores_better_than_broken_ones(demo: Path) -> None:
    model, config, dataset = load_run(demo / "run")
    opts = NoRefOptions(spike_pixels=96)

    def scores(m, ds) -> dict:
        return noref_metrics(m, config, ds, opts, 8192, display)["mean"]

    good = scores(model, dataset)
    torch.manual_seed(0)
    untrained = scores(model_from_hparams(model.hparams()).eval(), dataset)
    traj = dataset.trajectory
    moved = dataclasses.replace(traj, poses=_sideways(traj.poses, 0.3))
    shifted = scores(model, dataclasses.replace(dataset, trajectory=moved))
    for name, bad in (("untrained", untrained), ("shifted", shifted)):
        assert good["masked_psnr"] > bad["masked_psnr"] + 1.0, (name, good, bad)
        assert good["masked_ssim"] > bad["masked_ssim"] + 0.05, (name, good, bad)
        assert good["interval_violation_rate"] < bad["interval_violation_rate"], (name, good, bad)
        assert good["interval_violation_mean"] < bad["interval_violation_mean"], (name, good, bad)
        # the reference (the reconstruction held over the window) does not depend on the model
        assert good["recon_interval_violation_rate"] == bad["recon_interval_violation_rate"]
        assert good["piqe_recon"] == bad["piqe_recon"]


def test_masked_scores_render_what_the_run_was_trained_to_match(demo: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    model, config, dataset = load_run(demo / "run")
    assert config.targets.window_poses == WINDOW_POSES > 1  # the default run: window-aware targets
    seen = _spy_renders(monkeypatch)
    step, total = 40, len(dataset.trajectory)
    pixels = torch.tensor([[3, 4], [10, 12]])
    for poses in (WINDOW_POSES, 1):
        seen.clear()
        cfg = dataclasses.replace(config, targets=dataclasses.replace(config.targets, window_poses=poses))
        noref.score_step(model, cfg, dataset, step, 8, pixels, 8192, display)
        want = dataset.trajectory.poses[window_steps(total, config.targets.window, poses)[step]]
        assert len(seen) == poses and np.allclose(np.stack(seen), want)
    seen.clear()  # one pose: the step's own, also at the ends of the stream (where a window is clipped)
    one = dataclasses.replace(config, targets=dataclasses.replace(config.targets, window_poses=1))
    noref.score_step(model, one, dataset, 2, 8, pixels, 8192, display)
    assert len(seen) == 1 and np.allclose(seen[0], dataset.trajectory.poses[2])


def test_noref_defaults_and_steps_of_simulated_data(demo: Path) -> None:
    _, _, dataset = load_run(demo / "run")
    assert wants_noref("auto", dataset) and not wants_noref("off", dataset)
    plain = dataclasses.replace(dataset, config={})  # a simulated dataset: no `imported` section
    assert not wants_noref("auto", plain) and wants_noref("on", plain)
    steps, source = check_steps(plain, 4)
    assert source == "evenly spaced steps" and steps.tolist() == [16, 32, 47, 63]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--spike-pixels", -1], "Invalid value for '--spike-pixels'"),
        (["--noref-steps", 0], "Invalid value for '--noref-steps'"),
        (["--spike-window", 0], "Invalid value for '--spike-window'"),
    ],
)
def test_bad_noref_flags_exit_2(demo: Path, capsys, args: list, message: str) -> None:
    metrics = demo / "run" / "metrics.json"
    before = metrics.stat().st_mtime_ns if metrics.exists() else 0
    code, _, err = run_cli(capsys, "eval", demo / "run", "--lpips", "none", "--quiet", *args)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert (metrics.stat().st_mtime_ns if metrics.exists() else 0) == before  # nothing rewritten


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--raw-width", 20], "--raw-width must be from the image width 24 to 88"),
        (["--raw-width", 25, "--height", 7], "--raw-width: H·raw_width must be a multiple of 8"),
        (["--raw-width", 40, "--color", "rgb"], "--raw-width writes the gray stream"),
    ],
)
def test_bad_raw_width_exits_2_before_anything_is_written(tmp_path: Path, capsys, args, message) -> None:
    base = ["simulate", "--scene", "analytic-orbs", "--width", SIZE, "--height", SIZE, "--frames", 4]
    code, _, err = run_cli(capsys, *base, *args, "--out", tmp_path / "sim")
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


def test_the_learned_reconstructor_is_the_target_of_a_run_that_trained_on_it(demo: Path) -> None:
    model, config, dataset = load_run(demo / "run")
    opts = NoRefOptions(spike_pixels=16)
    learned = dataclasses.replace(
        config, targets=dataclasses.replace(config.targets, recon="learned", window=41)
    )
    tfp41 = dataclasses.replace(config, targets=dataclasses.replace(config.targets, window=41))
    a = noref_metrics(model, learned, dataset, opts, 8192, display)
    b = noref_metrics(model, tfp41, dataset, opts, 8192, display)
    assert a["target"] == "learned (window 41)" and b["target"] == "tfp (window 41)"
    assert 10 < a["mean"]["masked_psnr"] < 60 and a["mean"]["masked_psnr"] != b["mean"]["masked_psnr"]
    assert a["mean"]["interval_violation_rate"] == b["mean"]["interval_violation_rate"]  # the model's, same


def test_render_draws_the_test_views_and_orbit_at_the_poses_the_run_refined(
    demo: Path, monkeypatch, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    import spikenerf.eval.video as video
    from spikenerf.eval.trajectories import refined_poses
    from spikenerf.train.pose_refine import refined_dataset, refined_views

    _, config, dataset = load_run(demo / "run")
    ckpt = torch.load(demo / "run" / "checkpoint.pt", weights_only=True)
    assert ckpt["poses"], "the fixture's run refines its poses"
    refined = refined_views(ckpt, config, dataset, dataset.test).poses
    assert not np.allclose(refined, dataset.test.poses, atol=1e-6)
    seen: list[np.ndarray] = []
    real = video.render_image
    monkeypatch.setattr(
        video, "render_image", lambda m, pose, *a, **k: seen.append(pose) or real(m, pose, *a, **k)
    )
    video.render_run(demo / "run", tmp_path / "r", progress=False)
    assert len(seen) == len(refined) and np.allclose(np.stack(seen), refined, atol=1e-6)
    moved = refined_poses(ckpt, config, dataset)
    assert np.allclose(moved.trajectory.poses, refined_dataset(ckpt, config, dataset).trajectory.poses)


def test_a_spike_window_past_the_guard_band_is_said(demo: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``--spike-window 20`` around steps held out ± 4 reaches trained steps: it printed "(held out)"."""
    run = demo / "run"
    base = ["eval", run, "--device", "cpu", "--lpips", "none", "--spike-pixels", 16, "--quiet"]
    code, out, err = run_cli(capsys, *base)
    assert code == 0 and json.loads((run / "metrics.json").read_text())["no_reference"]["windows_in_guard"]
    code, out, err = run_cli(capsys, *base, "--spike-window", 20)
    assert code == 0, err
    assert "(held out, but their 20-step spike windows reach past ±4 into trained steps)" in out
    assert json.loads((run / "metrics.json").read_text())["no_reference"]["windows_in_guard"] is False
    run_cli(capsys, *base)  # the other tests read the default scores


@pytest.mark.parametrize(
    ("record", "problem"),
    [
        ({"check_steps": [1e999]}, "check_steps: expected a list of integers ≥ 0, found [inf]"),
        ({"check_steps": [30.7]}, "check_steps: expected a list of integers ≥ 0"),
        ({"check_steps": [-5]}, "check_steps: expected a list of integers ≥ 0"),
        ({"check_steps": [20], "radius": "x"}, "radius: expected an integer ≥ 0, found 'x'"),
        ({"radius": 4}, "no check_steps"),
        ([20], "expected an object, found list"),
    ],
)
def test_a_damaged_holdout_record_is_one_line(demo: Path, tmp_path: Path, capsys, record, problem) -> None:  # type: ignore[no-untyped-def]
    """``{"check_steps": [1e999]}`` was a 32-line OverflowError in ``info`` and ``eval``; 30.7 was cut."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(demo / "run", run)
    (run / "holdout.json").write_text(json.dumps(record))
    for command in (["info", run], ["eval", run, "--device", "cpu", "--lpips", "none", "--quiet"]):
        code, _, err = run_cli(capsys, *command)
        assert code == 2 and f"holdout.json: malformed hold-out record ({problem}" in err, err


def test_tfstp_and_tfi_check_steps_are_one_scan_equal_to_one_per_step(demo: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A run on TFI or TFSTP targets: its check steps' reconstructions come from one call (TFSTP: one scan
    from frame 0, not one per step) and score exactly as the reconstruction made at each step."""
    from spikenerf.camera import reconstruct

    model, config, dataset = load_run(demo / "run")
    opts = NoRefOptions(spike_pixels=16)
    calls: list[int] = []
    for recon in ("tfstp", "tfi"):
        calls.clear()
        real = getattr(reconstruct, recon)
        monkeypatch.setattr(reconstruct, recon, lambda *a, _real=real, **k: calls.append(1) or _real(*a, **k))
        cfg = dataclasses.replace(config, targets=dataclasses.replace(config.targets, recon=recon))
        once = noref_metrics(model, cfg, dataset, opts, 8192, display)
        assert len(calls) == 1 and len(once["per_step"]) > 1, (recon, calls)
        with monkeypatch.context() as patch:
            patch.setattr(noref, "step_reconstructions", lambda *a: None)  # one reconstruction a step
            calls.clear()
            each = noref_metrics(model, cfg, dataset, opts, 8192, display)
        assert len(calls) == len(each["per_step"]) and once["per_step"] == each["per_step"], recon

"""Pose refinement (train --refine-poses): the SE(3) exponential, the per-step interpolation, recovery of a
known pose error, resume, defaults and bad input."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import run_cli
from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.importing.alignment import trajectory_errors
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.trajectory import novel_views, orbit
from spikenerf.train.config import TrainConfig
from spikenerf.train.pose_refine import (
    REFINED_POSES,
    PoseRefiner,
    evaluating,
    keyframes_of,
    pose_refinement,
    refined_dataset,
    refined_views,
    se3_exp,
    so3_exp,
)
from spikenerf.train.trainer import Trainer

STEPS = 120
GRID = {
    "n_voxels_init": 16**3,
    "n_voxels_final": 32**3,
    "upsample_steps": [40, 80],
    "occupancy": False,
    "max_samples": 48,
    "iterations": 300,
}


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    traj = orbit(4.0, 30.0, duration=STEPS / 40000)
    source = AnalyticSource("analytic-blocks", 32, 32, traj, novel_views(4.0, 2), supersample=1)
    out = tmp_path_factory.mktemp("data") / "blocks32"
    return simulate_dataset(source, out, SimulateOptions(colors=("gray",), gt_every=6), progress=False)


@pytest.fixture(scope="module")
def dataset(data_dir: Path):  # type: ignore[no-untyped-def]
    return load_dataset(data_dir)


def _config(data_dir: Path, refine: bool | None, iters: int = 300, **kw) -> TrainConfig:  # type: ignore[no-untyped-def]
    cfg = TrainConfig(dataset=str(data_dir), method="nerf-gt", iters=iters, batch=128, eval_every=0,
                      eval_views=1, ckpt_every=iters, device="cpu", **kw)  # fmt: skip
    cfg.field_config = dict(GRID)
    cfg.poses.refine = refine
    cfg.poses.lr, cfg.poses.keyframe_every = 3e-3, 12
    return cfg


def _perturbed(dataset, scale: float = 1.0):  # type: ignore[no-untyped-def]
    """The dataset with every pose moved by a known smooth SE(3) error: keyframes every 12 steps get a
    random rotation of 3° and a shift of 0.12 (3% of the orbit radius), interpolated in between."""
    keys = keyframes_of(dataset, 12)
    rng = np.random.default_rng(7)
    xi = np.concatenate([rng.normal(size=(len(keys), 3)), rng.normal(size=(len(keys), 3))], 1)
    xi[:, :3] *= np.radians(3.0) / np.linalg.norm(xi[:, :3], axis=1, keepdims=True)
    xi[:, 3:] *= 0.12 / np.linalg.norm(xi[:, 3:], axis=1, keepdims=True)
    error = PoseRefiner(keys)
    error.xi.data = torch.as_tensor(scale * xi, dtype=torch.float32)

    def move(poses: np.ndarray, steps: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return error(torch.as_tensor(poses, dtype=torch.float32), steps).double().numpy()

    traj = dataset.trajectory
    moved = dataclasses.replace(traj, poses=move(traj.poses, traj.steps))
    gt = dataclasses.replace(dataset.gt, poses=move(dataset.gt.poses, dataset.gt.steps).astype(np.float32))
    return dataclasses.replace(dataset, trajectory=moved, gt=gt)


def _key_poses(trainer: Trainer) -> tuple[np.ndarray, np.ndarray]:
    """(given, refined) poses of the trainer's keyframes, (N, 4, 4) each."""
    doc = json.loads((trainer.out / REFINED_POSES).read_text())
    frames = doc["keyframes"]
    return np.array([f["given_matrix"] for f in frames]), np.array([f["transform_matrix"] for f in frames])


# ---------------------------------------------------------------------------------------- the exponential
def test_zero_correction_is_exactly_the_identity() -> None:
    assert torch.equal(se3_exp(torch.zeros(5, 6)), torch.eye(4).expand(5, 4, 4))
    refiner = PoseRefiner(np.array([0, 10, 30]))
    poses = torch.randn(40, 4, 4)
    assert torch.equal(refiner(poses, np.arange(40)), poses)
    refiner.xi.data[:, 0] = 0.01
    with torch.autocast("cpu", dtype=torch.bfloat16):  # a mixed-precision step keeps the poses float32
        moved = refiner(poses, np.arange(40))
    assert moved.dtype == torch.float32 and torch.equal(moved, refiner(poses, np.arange(40)))


def test_so3_exp_matches_the_matrix_exponential_and_passes_gradcheck() -> None:
    gen = torch.Generator().manual_seed(0)
    for scale in (1.0, 1e-3, 1e-5):  # the Taylor branch below 1e-4 rad
        omega = scale * torch.randn(6, 3, generator=gen, dtype=torch.float64)
        x, y, z = omega.unbind(-1)
        zero = torch.zeros_like(x)
        skew = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(6, 3, 3)
        got, want = so3_exp(omega), torch.linalg.matrix_exp(skew)
        assert torch.allclose(got, want, atol=1e-12)
        sym = (got + got.mT) / 2 - torch.eye(3, dtype=torch.float64)  # the second-order term, ~θ²
        assert torch.allclose(
            sym, (want + want.mT) / 2 - torch.eye(3, dtype=torch.float64), rtol=1e-3, atol=0
        )
        assert torch.autograd.gradcheck(so3_exp, (omega.clone().requires_grad_(),))
    assert torch.autograd.gradcheck(se3_exp, (torch.zeros(2, 6, dtype=torch.float64, requires_grad=True),))


def test_corrections_are_blended_between_keyframes_and_held_beyond() -> None:
    refiner = PoseRefiner(np.array([10, 20]))
    refiner.xi.data = torch.tensor([[0.1, 0, 0, 1, 0, 0], [0.3, 0, 0, 3, 0, 0]])
    c = refiner.correction(np.array([0, 10, 15, 20, 40]))
    angle = torch.atan2(c[:, 2, 1], c[:, 1, 1])
    assert torch.allclose(angle, torch.tensor([0.1, 0.1, 0.2, 0.3, 0.3]), atol=1e-6)
    assert torch.allclose(c[:, 0, 3], torch.tensor([1.0, 1.0, 2.0, 3.0, 3.0]))


def test_unreached_keyframes_take_the_blend_of_the_nearest_reached_ones() -> None:
    refiner = PoseRefiner(np.array([0, 10, 20, 30, 40]))
    refiner.correction(np.r_[0:11, 30:41])  # a training step (gradients on) reads keyframes 0, 10, 30, 40
    assert refiner.reached.tolist() == [True, True, False, True, True]
    refiner.xi.data[1, 0], refiner.xi.data[3, 0] = 0.1, 0.3
    with evaluating(refiner):  # evaluated, key 20 is halfway between keys 10 and 30; step 15 a quarter
        angle = torch.atan2(*refiner.correction(np.array([10, 15, 20, 25, 30]))[:, [2, 1], 1].T)
    assert torch.allclose(angle, torch.tensor([0.1, 0.15, 0.2, 0.25, 0.3]), atol=1e-6)
    state = refiner.state_dict()
    again = PoseRefiner(refiner.key_steps)
    again.load_state_dict(state)
    assert again.reached.tolist() == refiner.reached.tolist()
    only = PoseRefiner(refiner.key_steps)
    only.correction(np.array([10]))  # one reached keyframe: every other one holds its correction
    only.xi.data[1] = 0.2
    assert torch.equal(only.filled_xi(), torch.full((5, 6), 0.2))
    with pytest.raises(InputError, match="mark 5 keyframes, the dataset has 3"):
        PoseRefiner(np.array([0, 10, 20])).set_extra_state(state["_extra_state"])
    for marks in (state["_extra_state"].float(), state["_extra_state"][:, None]):  # (0.5 read as True before)
        with pytest.raises(InputError, match=r"marks must be a \(N,\) bool tensor"):
            again.set_extra_state(marks)
    with pytest.raises(InputError, match=r"are \(4, 6\), the dataset's 5 keyframes need \(5, 6\)"):
        again.load_state_dict({"xi": torch.zeros(4, 6)})  # (torch's multi-line RuntimeError before)


def test_only_a_training_step_marks_and_only_evaluation_fills() -> None:
    """The mode says what a call is, not the gradient switch alone: a training-mode call without gradients
    (spike-integral's track projection inside a step) reads the corrections as learned, as before the
    marks existed (training unchanged), and an evaluation-mode call with gradients on (a pose fitted
    through the refiner, a render with gradients) marks nothing and reads the filled corrections."""
    refiner = PoseRefiner(np.array([0, 10, 20, 30, 40]))
    refiner.correction(np.r_[0:11, 30:41])
    refiner.xi.data[1, 3], refiner.xi.data[3, 3] = 0.1, 0.3
    with torch.no_grad():  # inside a training step: key 20 keeps its own (zero) correction
        assert refiner.correction(np.array([20]))[0, 0, 3] == 0
    refiner.eval()
    shift = refiner.correction(np.array([20]))[0, 0, 3]  # gradients on
    assert shift.requires_grad and float(shift) == pytest.approx(0.2)
    assert refiner.reached.tolist() == [True, True, False, True, True]
    shift.backward()  # the blend reaches the trained neighbours
    assert refiner.xi.grad is not None and refiner.xi.grad[[1, 3], 3].tolist() == [0.5, 0.5]
    refiner.train()
    with evaluating(refiner):
        assert not refiner.training
    assert refiner.training


def test_a_checkpoint_with_misshapen_pose_state_is_one_line_exit_2(
    data_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """eval on a tampered checkpoint: keyframe marks of another length, dtype or shape, corrections of
    another shape or an unknown entry are one line, exit 2, no metrics.json (a float mark was read as
    trained where nonzero, a misshapen ``xi`` was torch's traceback)."""
    run = tmp_path / "run"
    code, _, err = run_cli(capsys, "--quiet", "train", data_dir, "--method", "nerf-gt", "--refine-poses",
                           "--iters", "1", "--device", "cpu", "--set", "batch=32", "--out", run)  # fmt: skip
    assert code == 0, err
    marks = torch.load(run / "checkpoint.pt", weights_only=True)["poses"]["refiner"]["_extra_state"]
    n = len(marks)
    cases = {
        "short": ({"_extra_state": marks[:-1]}, f"marks are a ({n - 1},) torch.bool tensor, not ({n},) bool"),
        "float": ({"_extra_state": marks.float() / 2}, f"({n},) torch.float32 tensor, not ({n},) bool"),
        "2-d": ({"_extra_state": marks[:, None]}, f"marks are a ({n}, 1) torch.bool tensor"),
        "xi": ({"xi": torch.zeros(n, 5)}, "its corrections 'xi' are not (K, 6) floats"),
        "both": ({"xi": torch.zeros(3, 6), "_extra_state": marks[:3]}, f"are (3, 6), the dataset's {n}"),
        "extra": ({"bias": torch.zeros(1)}, "unknown entries ['bias']"),
    }
    for name, (change, message) in cases.items():
        tampered = tmp_path / name
        shutil.copytree(run, tampered)
        ckpt = torch.load(tampered / "checkpoint.pt", weights_only=True)
        ckpt["poses"]["refiner"].update(change)
        torch.save(ckpt, tampered / "checkpoint.pt")
        code, _, err = run_cli(capsys, "--quiet", "eval", tampered, "--lpips", "none", "--device", "cpu")
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, (name, err)
        assert not (tampered / "metrics.json").exists()


# -------------------------------------------------------------------------------------------- recovery
def test_refinement_recovers_a_known_pose_error(data_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    truth = dataset.trajectory.poses
    moved = _perturbed(dataset)
    trainer = Trainer(_config(data_dir, True), tmp_path / "on", moved, progress=False)
    trainer.train()
    given, refined = _key_poses(trainer)
    keys = trainer.pose_refine.refiner.key_steps
    before = trajectory_errors(given, truth[keys])
    after = trajectory_errors(refined, truth[keys])
    assert before["rot_mean_deg"] > 2.5  # the error put in
    assert after["rot_mean_deg"] < 0.6 * before["rot_mean_deg"], (before, after)
    assert after["ate_rmse"] < 0.85 * before["ate_rmse"], (before, after)
    off = Trainer(_config(data_dir, False, iters=2), tmp_path / "off", moved, progress=False)
    assert off.pose_refine is None
    off.train()
    assert not (tmp_path / "off" / REFINED_POSES).exists()


def test_resume_with_refinement_is_bit_identical(data_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    cfg = _config(data_dir, True, iters=8)
    cfg.poses.warmup_iters, cfg.field_config["upsample_steps"] = 1, [3, 5]
    moved = _perturbed(dataset)
    straight = Trainer(cfg, tmp_path / "a", moved, progress=False)
    straight.train()
    first = Trainer(cfg, tmp_path / "b", moved, progress=False)
    first.train(stop_after=4)
    resumed = Trainer(cfg, tmp_path / "b", moved, resume=True, progress=False)
    resumed.train()
    assert straight.pose_refine.refiner.xi.abs().max() > 0
    assert torch.equal(straight.pose_refine.refiner.xi, resumed.pose_refine.refiner.xi)
    sa, sb = straight.model.state_dict(), resumed.model.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert (tmp_path / "a" / REFINED_POSES).read_bytes() == (tmp_path / "b" / REFINED_POSES).read_bytes()


# ----------------------------------------------------------------------------------- defaults and inputs
def test_on_by_default_for_imported_only_and_test_keyframes_left_out(dataset) -> None:  # type: ignore[no-untyped-def]
    info = {"keyframe_every": 20, "window": 21, "test_keyframes": [30], "pose_steps": [10, 30, 50, 70, 90]}
    imported = dataclasses.replace(dataset, config={**dataset.config, "imported": info})
    assert keyframes_of(imported, 12).tolist() == [10, 50, 70, 90]
    del info["pose_steps"]  # older imports: the importer's keyframe rule (every 20 where the window fits)
    assert keyframes_of(imported, 12).tolist() == [10, 50, 70, 90, 109]
    assert keyframes_of(dataset, 50).tolist() == [0, 50, 100, 119]
    default = _config(dataset.root, None, iters=2)
    default.poses = TrainConfig().poses  # the default: on for an imported dataset, off for a simulated one
    assert default.poses.refine is None
    assert (
        Trainer(default, dataset.root.parent / "run-default", imported, progress=False).pose_refine
        is not None
    )
    assert (
        Trainer(default, dataset.root.parent / "run-default-sim", dataset, progress=False).pose_refine is None
    )
    # … but not for nerf-bad, which learns its own exposure poses (decided before targets are looked at)
    assert pose_refinement(TrainConfig(method="nerf-bad"), imported, None, "cpu", None) is None
    cfg = _config(dataset.root, True, iters=2)
    trainer = Trainer(cfg, dataset.root.parent / "run-imported", imported, progress=False)
    assert trainer.pose_refine is not None
    assert (
        Trainer(
            _config(dataset.root, False, iters=2), dataset.root.parent / "run-plain", dataset, progress=False
        ).pose_refine
        is None
    )
    # a test view on the trajectory gets the refined pose of its step; a novel view keeps its pose
    trainer.pose_refine.refiner.xi.data[:, 0] = 0.1
    views = torch.as_tensor(
        np.stack([dataset.trajectory.poses[30], dataset.test.poses[0]]), dtype=torch.float32
    )
    out = trainer.pose_refine.eval_poses(views)
    assert not torch.allclose(out[0], views[0]) and torch.equal(out[1], views[1])
    posed = dataclasses.replace(dataset.test, poses=views.numpy())  # what `spikenerf eval` scores
    state = {"poses": trainer.pose_refine.state_dict()}
    assert np.array_equal(refined_views(state, cfg, imported, posed).poses, out.numpy())
    assert refined_views({"poses": None}, cfg, imported, posed) is posed
    # eval's no-reference checks render the path at the refined poses too
    moved = refined_dataset(state, cfg, imported)
    np.testing.assert_allclose(moved.trajectory.poses[30], out[0].numpy(), atol=1e-6)
    assert not np.allclose(moved.trajectory.poses[30], imported.trajectory.poses[30])
    assert refined_dataset({"poses": None}, cfg, imported) is imported


def test_bad_input_is_one_line_exit_2(
    data_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    traj = orbit(4.0, 30.0, duration=1 / 40000)  # one step: one keyframe
    source = AnalyticSource("analytic-blocks", 8, 8, traj, novel_views(4.0, 1), supersample=1)
    one = simulate_dataset(
        source, tmp_path / "one", SimulateOptions(colors=("gray",), gt_every=1), progress=False
    )
    cases = [
        ((one, "--method", "nerf-gt", "--refine-poses"), "--refine-poses needs at least 2 keyframes"),
        ((data_dir, "--method", "nerf-gt", "--set", "poses.lr=-1"), "poses.lr must be"),
        ((data_dir, "--method", "nerf-gt", "--set", "poses.keyframe_every=0"), "poses.keyframe_every"),
    ]
    for i, (args, message) in enumerate(cases):
        out = tmp_path / f"run{i}"
        code, _, err = run_cli(capsys, "train", *args, "--iters", "2", "--device", "cpu", "--out", out)
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
        assert not (out / "checkpoint.pt").exists()
    with pytest.raises(InputError, match="no spike steps"):
        moved = load_dataset(data_dir)
        gt = dataclasses.replace(moved.gt, steps=None)
        Trainer(_config(data_dir, True, iters=2), tmp_path / "nostep", dataclasses.replace(moved, gt=gt))

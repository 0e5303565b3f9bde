"""Targets, samplers, the trainer (every method and ablation), checkpoints, resume and the train CLI."""

from __future__ import annotations

import csv
import dataclasses
import json
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.core.color import rgb_to_gray
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.data.samplers import RaySampler, WindowSampler
from spikenerf.data.targets import (
    blur_targets,
    build_spike_targets,
    exposure_steps,
    gt_targets,
    masked_reconstruction,
    stream_targets,
    window_steps,
)
from spikenerf.render import build_model, render_spike_window
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.trajectory import novel_views, orbit
from spikenerf.train.checkpoint import CHECKPOINT, load_checkpoint
from spikenerf.train.config import WINDOW_POSES, TrainConfig
from spikenerf.train.config_file import load_config, load_run_config, save_config
from spikenerf.train.evaluate import read_curves
from spikenerf.train.logger import RunningMeans
from spikenerf.train.losses import spike_interval_loss
from spikenerf.train.methods import METHOD_CLASSES, make_method, unused_keys
from spikenerf.train.run import load_run
from spikenerf.train.trainer import Trainer, train

STEPS = 120
#: a small grid so that every run takes a second: two upsamplings and an occupancy update within 6 iterations
TINY_GRID = {
    "n_voxels_init": 12**3,
    "n_voxels_final": 20**3,
    "upsample_steps": [2, 4],
    "occupancy_start": 3,
    "occupancy_every": 3,
    "occupancy_threshold": 0.0,
    "iterations": 6,
}


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    traj = orbit(4.0, 30.0, duration=STEPS / 40000)
    source = AnalyticSource("analytic-orbs", 16, 16, traj, novel_views(4.0, 2), supersample=1)
    out = tmp_path_factory.mktemp("data") / "orbs16"
    options = SimulateOptions(colors=("gray", "rgb"), gt_every=10, blur_fps=1000.0)
    return simulate_dataset(source, out, options, progress=False)


@pytest.fixture(scope="module")
def dataset(dataset_dir: Path):  # type: ignore[no-untyped-def]
    return load_dataset(dataset_dir)


def _config(dataset_dir: Path, **kw) -> TrainConfig:  # type: ignore[no-untyped-def]
    spike = kw.pop("spike", {})
    kw.setdefault("method", "spike-nerf")  # these tests exercise spike-nerf's parts (train's default differs)
    kw.setdefault("device", "cpu")
    kw.setdefault("batch", 64)
    cfg = TrainConfig(
        dataset=str(dataset_dir),
        iters=6,
        eval_every=3,
        eval_views=1,
        ckpt_every=3,
        **kw,
    )
    cfg.field_config = dict(TINY_GRID) if cfg.field == "grid" else {**_TINY_MLP}
    cfg.spike.window, cfg.spike.pixels, cfg.spike.warmup_iters, cfg.spike.ramp_iters = 8, 8, 1, 2
    for key, value in spike.items():
        setattr(cfg.spike, key, value)
    return cfg


_TINY_MLP = {"depth": 2, "width": 16, "skip": 0, "xyz_freqs": 3, "dir_freqs": 1, "dir_width": 8}
_TINY_MLP.update({"n_coarse": 8, "n_fine": 8})


# ------------------------------------------------------------------------------------------------ targets
def test_mask_window_is_exactly_2n_plus_1_frames() -> None:
    spikes = np.zeros((40, 2, 3), np.uint8)
    spikes[20, 0, 0] = 1
    masked = masked_reconstruction(spikes, "tfp", window=41, mask=True, mask_n=5)
    lit = np.flatnonzero(masked[:, 0, 0] > 0)
    assert lit.tolist() == list(range(15, 26))  # steps 20-5 … 20+5
    assert not masked[:, 1:, :].any() and not masked[:, :, 1:].any()
    unmasked = masked_reconstruction(spikes, "tfp", window=41, mask=False)
    assert (unmasked[:, 0, 0] > 0).all()  # TFP spreads the spike over its whole 41-frame window
    assert np.allclose(masked[lit, 0, 0], unmasked[lit, 0, 0])


def test_targets_gray_and_rgb(dataset) -> None:  # type: ignore[no-untyped-def]
    h, w = dataset.intrinsics.height, dataset.intrinsics.width
    gray = stream_targets(dataset, "gray")
    rgb = stream_targets(dataset, "rgb")
    assert gray.images.shape == (STEPS, h, w, 1) and rgb.images.shape == (STEPS, h, w, 3)
    assert gray.images.dtype == torch.float16 and gray.poses.shape == (STEPS, 1, 4, 4)
    stream = dataset.spikes("rgb")
    expected = masked_reconstruction(stream, "tfp", 41, dataset.threshold, True, 5)
    assert torch.allclose(rgb.images.float(), torch.from_numpy(expected).permute(0, 2, 3, 1), atol=1e-3)
    recon = make_method(TrainConfig(method="nerf-recon", color="gray"))
    recon.build_targets(dataset)
    assert recon.targets is not None and recon.spikes is None
    no_mask = stream_targets(dataset, "gray", mask=False)
    assert torch.equal(recon.targets.images, no_mask.images) and (no_mask.images >= gray.images).all()
    assert (no_mask.images > gray.images).any()  # some pixels are masked out (target 0)
    spk = build_spike_targets(dataset, "rgb")
    assert spk.spikes.shape == (STEPS, h, w, 3) and spk.spikes.dtype == torch.uint8
    assert torch.equal(spk.spikes[:, :, :, 1], torch.from_numpy(stream[:, 1]))


def test_baseline_targets(dataset) -> None:  # type: ignore[no-untyped-def]
    gt = gt_targets(dataset, "gray")
    assert len(gt) == len(dataset.gt) == STEPS // 10
    want = rgb_to_gray(torch.from_numpy(dataset.gt.images), channel_axis=-1)
    assert torch.allclose(gt.images[..., 0].float(), want, atol=1e-3)
    blur = blur_targets(dataset, "rgb")
    assert len(blur) == len(dataset.blur) and blur.poses.shape[1] == 1
    aware = blur_targets(dataset, "rgb", samples=4)
    assert aware.poses.shape == (len(dataset.blur), 4, 4, 4)
    start, end = dataset.blur.step_ranges[0]
    steps = exposure_steps(dataset.blur.step_ranges[0], 4)
    assert ((steps >= start) & (steps < end)).all() and len(set(steps.tolist())) == 4
    assert torch.allclose(
        aware.poses[0], torch.as_tensor(dataset.trajectory.poses[steps], dtype=torch.float32)
    )


def test_window_steps_spread_over_the_clipped_tfp_window() -> None:
    idx = window_steps(100, 41, 4)
    assert idx.shape == (100, 4)
    assert idx[50].tolist() == [35, 45, 55, 65]  # window 30..70: centres of four parts of 41 steps
    assert idx[0].tolist() == [2, 7, 13, 18]  # clipped to 0..20 as tfp clips it
    assert idx[99].tolist() == [81, 86, 92, 97]
    assert (idx >= np.maximum(np.arange(100) - 20, 0)[:, None]).all()
    assert (idx <= np.minimum(np.arange(100) + 20, 99)[:, None]).all()
    assert (window_steps(100, 41, 1)[20:80, 0] == np.arange(20, 80)).all()  # S = 1: the step itself


def test_window_aware_stream_targets(dataset) -> None:  # type: ignore[no-untyped-def]
    plain = stream_targets(dataset, "gray", window=11)
    aware = stream_targets(dataset, "gray", window=11, window_poses=3)
    assert torch.equal(aware.images, plain.images) and torch.equal(aware.steps, plain.steps)
    assert aware.poses.shape == (STEPS, 3, 4, 4) and aware.pose_steps is not None
    k = 60
    assert aware.pose_steps[k].tolist() == window_steps(STEPS, 11, 3)[k].tolist() == [56, 60, 64]
    want = torch.as_tensor(dataset.trajectory.poses[[56, 60, 64]], dtype=torch.float32)
    assert torch.allclose(aware.poses[k], want)
    with pytest.raises(InputError, match="window_poses"):
        stream_targets(dataset, "gray", recon="tfi", window_poses=2)
    with pytest.raises(InputError, match="window_poses"):
        stream_targets(dataset, "gray", window_poses=0)
    cfg = TrainConfig(method="nerf-recon")
    cfg.targets.window_poses, cfg.targets.recon = 4, "tfi"
    with pytest.raises(InputError, match=r"targets\.window_poses"):
        cfg.validate()
    cfg.targets.window_poses = 0
    with pytest.raises(InputError, match=r"targets\.window_poses must be ≥ 1"):
        cfg.validate()
    cfg.targets.window_poses, cfg.targets.recon = 4, "tfp"
    assert make_method(cfg.validate()).poses_per_view() == 4
    cfg.targets.window_poses = None  # the default: window-aware for TFP, one pose for the others
    assert make_method(cfg.validate()).poses_per_view() == WINDOW_POSES > 1
    cfg.targets.recon = "tfi"
    assert make_method(cfg.validate()).poses_per_view() == 1


def test_a_run_config_from_before_window_poses_resumes_with_one_pose(tmp_path: Path) -> None:
    cfg = TrainConfig(method="spike-nerf")
    data = cfg.to_dict()
    del data["targets"]["window_poses"]  # a run's config.yaml written before the key existed
    (tmp_path / "old.yaml").write_text(yaml.safe_dump(data))
    assert load_run_config(tmp_path / "old.yaml").targets.poses_per_target() == 1
    # a hand-written --config file without the key gets today's default
    (tmp_path / "mine.yaml").write_text(yaml.safe_dump({"method": "spike-nerf", "targets": {"window": 81}}))
    assert load_config(tmp_path / "mine.yaml").targets.poses_per_target() == WINDOW_POSES
    save_config(cfg.resolved(), tmp_path / "new.yaml")  # a run written now records the resolved count
    assert load_run_config(tmp_path / "new.yaml").targets.window_poses == WINDOW_POSES
    tfi = TrainConfig(method="nerf-recon")
    tfi.targets.recon = "tfi"
    assert tfi.resolved().targets.window_poses == 1 and tfi.targets.window_poses is None
    for method in ("nerf-gt", "nerf-blur", "nerf-blur-aware", "nerf-bad"):  # no stream targets: one pose
        other = TrainConfig(method=method)  # type: ignore[arg-type]
        assert other.window_poses() == 1 and other.resolved().targets.window_poses == 1, method


def test_runs_record_their_pose_count_and_older_runs_resume_with_theirs(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    cfg = _config(dataset_dir, method="nerf-recon")
    assert cfg.targets.window_poses is None
    Trainer(cfg, tmp_path / "new", dataset, progress=False).train(stop_after=3)
    stored = yaml.safe_load((tmp_path / "new" / "config.yaml").read_text())
    assert stored["targets"]["window_poses"] == WINDOW_POSES  # resolved, not null
    again = Trainer(cfg, tmp_path / "new", dataset, resume=True, progress=False)
    assert again.method.poses_per_view() == WINDOW_POSES
    # an older run: its config.yaml has no window_poses; resumed with a fresh config it keeps one pose
    Trainer(_config(dataset_dir, method="nerf-recon"), tmp_path / "old", dataset, progress=False).train(
        stop_after=3
    )
    stored = yaml.safe_load((tmp_path / "old" / "config.yaml").read_text())
    del stored["targets"]["window_poses"]
    (tmp_path / "old" / "config.yaml").write_text(yaml.safe_dump(stored))
    old = Trainer(_config(dataset_dir, method="nerf-recon"), tmp_path / "old", dataset, resume=True,
                  progress=False)  # fmt: skip
    assert old.method.poses_per_view() == 1 and old.config.targets.window_poses == 1
    asked = _config(dataset_dir, method="nerf-recon")
    asked.targets.window_poses = WINDOW_POSES
    with pytest.raises(InputError, match="window_poses"):  # asking for another count is refused
        Trainer(asked, tmp_path / "old", dataset, resume=True, progress=False)


def test_runs_record_their_masks_and_older_runs_resume_with_theirs(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """Masks default to on for the paper's targets and off for window-aware ones; a run records the
    resolved choice, and a run written before (``mask: true`` with window-aware targets) keeps its masks."""
    assert TrainConfig(method="spike-nerf").resolved().targets.mask is False
    paper = TrainConfig(method="spike-nerf")
    paper.targets.window_poses = 1
    assert paper.resolved().targets.mask is True
    cfg = _config(dataset_dir, method="spike-nerf")
    assert cfg.targets.mask is None
    Trainer(cfg, tmp_path / "run", dataset, progress=False).train(stop_after=2)
    stored = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    assert stored["targets"]["mask"] is False and stored["targets"]["window_poses"] == WINDOW_POSES
    stored["targets"]["mask"] = True  # as every run before this default recorded it
    (tmp_path / "run" / "config.yaml").write_text(yaml.safe_dump(stored))
    again = Trainer(_config(dataset_dir, method="spike-nerf"), tmp_path / "run", dataset, resume=True,
                    progress=False)  # fmt: skip
    assert again.method.uses_mask and again.config.targets.mask is True


def test_missing_stream_is_input_error(dataset) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(InputError, match=r"bayer|color"):
        stream_targets(dataset, "bayer")


# ----------------------------------------------------------------------------------------------- samplers
def test_ray_sampler_seeded_and_resumable() -> None:
    a, b = RaySampler(5, 7, 9, seed=3), RaySampler(5, 7, 9, seed=3)
    ia, pa = a.sample(1000)
    ib, pb = b.sample(1000)
    assert torch.equal(ia, ib) and torch.equal(pa, pb)
    assert ia.min() >= 0 and ia.max() < 5 and pa[:, 0].max() < 9 and pa[:, 1].max() < 7
    assert len(torch.unique(ia)) == 5
    state = a.state_dict()
    first = a.sample(10)
    a.load_state_dict(state)
    assert all(torch.equal(x, y) for x, y in zip(first, a.sample(10), strict=True))
    assert not torch.equal(
        RaySampler(5, 7, 9, seed=4).sample(50)[1], RaySampler(5, 7, 9, seed=3).sample(50)[1]
    )


@pytest.mark.parametrize("order", ["sequential", "random"])
def test_windows_contiguous_and_inside(order: str) -> None:
    sampler = WindowSampler(50, 4, 6, length=16, seed=1, order=order)
    starts = []
    for _ in range(20):
        start, pixels = sampler.sample(8)
        assert start >= 0 and start + 16 <= 50
        assert pixels.shape == (8, 2) and pixels[:, 0].max() < 6 and pixels[:, 1].max() < 4
        starts.append(start)
    if order == "sequential":
        # consecutive windows; the last one ends at the stream's end (its last 2 steps are drawn too),
        # then a new pass
        assert starts[:5] == [0, 16, 32, 34, 0]
    state = sampler.state_dict()
    nxt = sampler.sample(8)
    sampler.load_state_dict(state)
    again = sampler.sample(8)
    assert nxt[0] == again[0] and torch.equal(nxt[1], again[1])
    with pytest.raises(InputError):
        WindowSampler(10, 4, 4, length=11)


@pytest.mark.parametrize(("steps", "length", "stride"), [(50, 16, 16), (48, 16, 16), (30, 4, 3), (30, 8, 5)])
def test_sequential_windows_visit_every_step_and_wrap(steps: int, length: int, stride: int) -> None:
    """A pass of the sequential order covers every step of the stream (the T mod L last ones too), ends at
    the last window position and starts again at 0; restricted to every start it draws the same."""
    free = WindowSampler(steps, 2, 2, length, order="sequential", stride=stride)
    listed = WindowSampler(steps, 2, 2, length, order="sequential", stride=stride,
                           starts=torch.arange(steps - length + 1))  # fmt: skip
    starts = [free.sample(1)[0] for _ in range(3 * steps)]
    assert starts == [listed.sample(1)[0] for _ in range(3 * steps)]
    one_pass = starts[: starts.index(0, 1)]
    covered = {s + k for s in one_pass for k in range(length)}
    assert covered == set(range(steps)) and one_pass[-1] == steps - length
    assert starts[len(one_pass) : 2 * len(one_pass)] == one_pass  # the next pass is the same


# ------------------------------------------------------------------------------------------------ training
@pytest.mark.parametrize("fires", [True, False])
def test_spike_loss_gradient_moves_the_field(dataset, fires: bool) -> None:  # type: ignore[no-untyped-def]
    """Recorded spikes at every step (silence) demand more (less) light: one descent step gives it."""
    torch.manual_seed(0)
    model = build_model("grid", 1, dataset.scene_box, {**TINY_GRID, "density_shift": 0.0})
    spk = build_spike_targets(dataset, "gray")
    pixels = torch.tensor([[8, 8], [5, 9], [10, 4]])
    recorded = torch.full((16, 3, 1), 1.0 if fires else 0.0)

    def intensity() -> torch.Tensor:
        poses, k = spk.poses[:16], dataset.intrinsics
        return render_spike_window(
            model, poses, k, pixels, torch.zeros(3, 1), 1.0, dataset.near, dataset.far
        ).intensity

    before = intensity()
    loss = spike_interval_loss(before, recorded, 1.0)
    loss.backward()
    grads = [p.grad for p in model.parameters() if p.grad is not None]
    assert loss.item() > 0 and grads and any(g.abs().sum() > 0 for g in grads)
    with torch.no_grad():
        for p in model.parameters():
            if p.grad is not None:
                p -= 0.05 * p.grad / p.grad.abs().max().clamp_min(1e-12)
        after = intensity()
    assert (after.mean() > before.mean()) == fires


RUNS = [
    ("spike-nerf", {}),
    ("spike-nerf", {"no_mask": True}),
    ("spike-nerf", {"no_spike": True}),
    ("spike-nerf", {"paper": True}),
    ("nerf-recon", {}),
    ("nerf-recon", {"window_poses": 3}),
    ("spike-nerf", {"window_poses": 2}),
    ("nerf-gt", {}),
    ("nerf-blur", {}),
    ("nerf-blur-aware", {}),
    ("nerf-bad", {}),
]


@pytest.mark.parametrize(("method", "flags"), RUNS)
def test_every_method_trains_and_writes_a_run(
    dataset_dir: Path, dataset, tmp_path: Path, method, flags
) -> None:  # type: ignore[no-untyped-def]
    cfg = _config(
        dataset_dir, method=method, color="rgb" if method in ("nerf-blur-aware", "nerf-bad") else "gray"
    )
    cfg.targets.mask = not flags.get("no_mask", False)
    cfg.spike.enabled = not flags.get("no_spike", False)
    cfg.spike.kind = "paper" if flags.get("paper") else "interval"
    cfg.targets.blur_samples = 2
    cfg.targets.window_poses = flags.get("window_poses", 1)
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    assert trainer.method.targets is not None
    if method != "nerf-bad":  # (nerf-bad interpolates its S poses from learned endpoints)
        assert trainer.method.targets.poses.shape[1] == trainer.method.poses_per_view()
    before = {k: v.clone() for k, v in trainer.model.state_dict().items()}
    summary = trainer.train()
    assert summary.iteration == 6 and np.isfinite(summary.train_psnr) and np.isfinite(summary.test_psnr)
    for name in (CHECKPOINT, "config.yaml", "curves.csv", "summary.json"):
        assert (tmp_path / "run" / name).is_file()
    ckpt = torch.load(tmp_path / "run" / CHECKPOINT, weights_only=True)
    assert ckpt["iteration"] == 6 and ckpt["config"]["method"] == method
    assert load_config(tmp_path / "run" / "config.yaml") == cfg
    with open(tmp_path / "run" / "curves.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["iteration"]) for r in rows] == [3, 6] and list(rows[0]) == [
        *("iteration", "seconds", "train_psnr", "test_psnr"),
        *("loss", "recon", "spike", "reg", "lambda"),
    ]
    assert all(float(r["recon"]) > 0 and float(r["loss"]) >= float(r["recon"]) for r in rows)
    assert trainer.model.field.resolution == 20  # upsampled twice
    after = trainer.model.state_dict()
    assert any(not torch.equal(before[k], after[k]) for k in before if "decoder" in k)
    rays_spike = trainer.method.uses_spike_loss and trainer.rays > 6 * 64
    assert rays_spike == (method == "spike-nerf" and not flags.get("no_spike", False))


@pytest.mark.parametrize("field", ["grid", "mlp"])
def test_resume_matches_an_uninterrupted_run(dataset_dir: Path, dataset, tmp_path: Path, field: str) -> None:  # type: ignore[no-untyped-def]
    cfg = _config(dataset_dir, field=field)
    straight = Trainer(cfg, tmp_path / "a", dataset, progress=False)
    straight.train()
    first = Trainer(cfg, tmp_path / "b", dataset, progress=False)
    assert first.train(stop_after=3).iteration == 3  # "interrupted" after 3 of 6 iterations
    with pytest.raises(InputError, match="pass resume"):
        Trainer(cfg, tmp_path / "b", dataset, progress=False)
    resumed = Trainer(cfg, tmp_path / "b", dataset, resume=True, progress=False)
    assert resumed.iteration == 3
    resumed.train()
    assert resumed.iteration == straight.iteration == 6
    sa, sb = straight.model.state_dict(), resumed.model.state_dict()
    assert sa.keys() == sb.keys()
    for key in sa:
        assert torch.equal(sa[key], sb[key]), key
    written = (tmp_path / "b" / "summary.json").read_bytes()
    again = Trainer(cfg, tmp_path / "b", dataset, resume=True, progress=False).train()  # already finished
    assert (tmp_path / "b" / "summary.json").read_bytes() == written  # not re-rounded from curves.csv
    assert dataclasses.asdict(again) == json.loads(written)


def test_resume_from_plain_layout_adam_state_matches(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A checkpoint from before the channels-last grid factors holds Adam's moments in the plain layout; the
    resumed run must still equal an uninterrupted one (fused Adam needs parameter and state layouts equal)."""
    cfg = _config(dataset_dir)
    straight = Trainer(cfg, tmp_path / "a", dataset, progress=False)
    straight.train()
    first = Trainer(cfg, tmp_path / "b", dataset, progress=False)
    first.train(stop_after=3)
    path = tmp_path / "b" / CHECKPOINT
    ckpt = torch.load(path, weights_only=True)
    state = ckpt["optimizer"]["state"]
    plain = [k for k, v in state.items() for t in v.values() if torch.is_tensor(t) and not t.is_contiguous()]
    assert plain, "no channels-last state to convert: the test would not test anything"
    ckpt["optimizer"]["state"] = {
        k: {n: t.contiguous() if torch.is_tensor(t) else t for n, t in v.items()} for k, v in state.items()
    }
    torch.save(ckpt, path)
    resumed = Trainer(cfg, tmp_path / "b", dataset, resume=True, progress=False)
    resumed.train()
    sa, sb = straight.model.state_dict(), resumed.model.state_dict()
    for key in sa:
        assert torch.equal(sa[key], sb[key]), key


def test_resume_keeps_the_fp16_loss_scale(dataset_dir: Path, dataset, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """The GradScaler state is in the checkpoint: a resumed --amp fp16 run continues with the same scale."""
    cfg = _config(dataset_dir, amp="fp16")
    first = Trainer(cfg, tmp_path / "b", dataset, progress=False)
    said = (
        "spikenerf: warning: --amp fp16 is meant for CUDA (with its gradient scaler); on cpu use --amp bf16"
    )
    assert capsys.readouterr().err.splitlines() == [said]  # it runs on a CPU, but a user meant bf16 there
    first.train(stop_after=2)
    first.scaler.update(new_scale=1024.0)  # as after some overflow back-offs
    first.checkpoint()
    resumed = Trainer(cfg, tmp_path / "b", dataset, resume=True, progress=False)
    assert resumed.scaler.get_scale() == 1024.0
    assert resumed.scaler.state_dict() == first.scaler.state_dict()


def test_load_run_renders(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    train(_config(dataset_dir, method="nerf-gt"), tmp_path / "run", dataset, progress=False)
    model, config, ds = load_run(tmp_path / "run")
    assert config.method == "nerf-gt" and ds.intrinsics == dataset.intrinsics and not model.training
    from spikenerf.render import render_image

    img = render_image(model, ds.test.poses[0], ds.intrinsics, ds.near, ds.far).color
    assert img.shape == (16, 16, 1) and torch.isfinite(img).all()


def test_the_checkpoint_holds_no_path_of_the_dataset(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """config.yaml names the dataset; the checkpoint kept the trainer's path too, in its binary, where
    shipping a run (``benchmark --ray-ship-results``) or moving it could not rewrite it."""
    run = tmp_path / "run"
    train(_config(dataset_dir, method="nerf-gt"), run, dataset, progress=False, stop_after=3)
    assert str(dataset_dir.resolve()) in (run / "config.yaml").read_text()
    assert str(dataset_dir.resolve()).encode() not in (run / "checkpoint.pt").read_bytes()
    assert load_checkpoint(run / "checkpoint.pt")["config"]["dataset"] == ""
    assert train(_config(dataset_dir, method="nerf-gt"), run, resume=True, progress=False).iteration == 6


#: a value other than the test config's for each method-specific key (``methods.METHOD_KEYS``)
_CHANGED = {
    "targets.recon": "tfi",
    "targets.mask": False,
    "targets.window_poses": 2,
    "targets.blur_samples": 3,
    "spike.lam": 0.25,
    "spike.pixels": 4,
    "integral.samples": 2,
    "exposure.lr": 0.05,
}


@pytest.mark.parametrize("method", list(METHOD_CLASSES))
def test_keys_a_method_does_not_read_leave_its_training_unchanged(
    dataset_dir: Path, dataset, tmp_path: Path, method: str
) -> None:  # type: ignore[no-untyped-def]
    """What ``train`` warns of as unused is unused: the run's weights are the same to the bit; and changing
    the keys the method does read changes them (so the comparison can fail)."""

    def trained(changes: list[str], name: str) -> dict[str, torch.Tensor]:
        cfg = _config(dataset_dir, method=method)
        cfg.iters, cfg.eval_every, cfg.targets.blur_samples, cfg.targets.window_poses = 3, 0, 2, 1
        data = cfg.to_dict()
        for key in changes:
            section, field = key.split(".")
            data[section][field] = _CHANGED[key]
        torch.manual_seed(0)
        trainer = Trainer(TrainConfig.from_dict(data).validate(), tmp_path / name, dataset, progress=False)
        trainer.train()
        return trainer.model.state_dict()

    unused = unused_keys(method, _CHANGED)
    read = [key for key in _CHANGED if key not in unused and key != "targets.recon"]  # (tfi: one pose)
    base, other = trained([], "base"), trained(unused, "unused")
    assert unused and all(torch.equal(base[k], other[k]) for k in base)
    if read:
        changed = trained(read, "read")
        assert any(not torch.equal(base[k], changed[k]) for k in base)


def test_a_resumed_run_computes_with_the_kernels_it_was_given(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:
    """The model rebuilt from the checkpoint takes the resume's lookup (gather here, on a CPU), and the next
    checkpoint and config.yaml record it, so eval builds the same."""
    from spikenerf.train.checkpoint import load_checkpoint

    cfg = _config(dataset_dir, method="nerf-gt")
    cfg.iters, cfg.eval_every = 2, 0
    train(cfg, tmp_path / "run", dataset, progress=False)
    again = dataclasses.replace(cfg, iters=3, field_config={**cfg.field_config, "lookup": "gather"})
    trainer = Trainer(again, tmp_path / "run", dataset, resume=True, progress=False)
    assert trainer.model.field.config.lookup == "gather"
    trainer.train()
    ckpt = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    assert ckpt["hparams"]["config"]["lookup"] == "gather"
    assert "lookup: gather" in (tmp_path / "run" / "config.yaml").read_text()


def test_a_resume_may_choose_other_kernels_but_not_another_model(tmp_path: Path) -> None:
    """lookup, composite and march choose how the same model is computed: a run trained with Triton kernels
    on a GPU resumes with the torch ones elsewhere (given again), keeps its choice when not given, and any
    other field option still has to match."""
    from spikenerf.train.resume import check_resume

    stored = TrainConfig(field_config={"march": "triton", "composite": "triton", "static_samples": 48})
    given = TrainConfig(field_config={"march": "torch", "static_samples": 48})
    out = check_resume(stored, given, tmp_path / "config.yaml")
    assert out.field_config == {"march": "torch", "composite": "triton", "static_samples": 48}
    kept = check_resume(stored, TrainConfig(field_config={"static_samples": 48}), tmp_path / "config.yaml")
    assert kept.field_config == stored.field_config
    with pytest.raises(InputError, match="different options"):
        check_resume(stored, TrainConfig(field_config={"march": "torch", "static_samples": 64}), tmp_path)


def test_a_resume_ignores_what_the_method_does_not_read(dataset_dir: Path, dataset, tmp_path: Path) -> None:
    """The same command with --resume works even where ``train`` said a flag was ignored (the run stores
    nerf-gt's window poses resolved to 1, and no spike settings matter to it)."""
    cfg = _config(dataset_dir, method="nerf-gt")
    cfg.iters, cfg.eval_every, cfg.targets.window_poses, cfg.spike.lam = 2, 0, 4, 0.25
    train(cfg, tmp_path / "run", dataset, progress=False)
    again = dataclasses.replace(cfg, iters=3, spike=dataclasses.replace(cfg.spike, lam=0.5))
    assert train(again, tmp_path / "run", dataset, resume=True, progress=False).iteration == 3
    other = dataclasses.replace(again, iters=4, seed=5)  # what it reads still counts
    with pytest.raises(InputError, match=r"different options \(seed: run has 0, asked 5\)"):
        train(other, tmp_path / "run", dataset, resume=True, progress=False)
    other = dataclasses.replace(
        again, iters=4, color="rgb", targets=dataclasses.replace(cfg.targets, mask_n=3)
    )
    with pytest.raises(InputError) as err:  # a section's changed entry alone, dotted (a flag in the CLI)
        train(other, tmp_path / "run", dataset, resume=True, progress=False)
    assert "(color: run has 'gray', asked 'rgb', targets.mask_n: run has 5, asked 3)" in err.value.message
    assert err.value.params[:2] == ("color", "targets.mask_n")


def test_train_warns_in_one_line_of_each_flag_its_method_does_not_use(
    dataset_dir: Path, dataset, tmp_path: Path, capsys, monkeypatch
) -> None:  # type: ignore[no-untyped-def]
    from helpers import run_cli

    called: list[tuple[TrainConfig, list[str]]] = []
    monkeypatch.setattr(
        "spikenerf.train.trainer.train", lambda c, *a, **k: called.append((c, k["notes"])) or sys.exit(0)
    )
    flags = [
        "--lambda",
        "0.5",
        "--integral-window",
        "3",
        "--no-mask",
        "--window",
        "11",
        "--blur-samples",
        "3",
    ]
    flags += ["--set", "spike.pixels=4", "--set", "spike.window=8"]
    checks = "does not change how --method nerf-gt trains; it only sets eval's no-reference checks and the"
    for method, unused, checks_only in [
        ("nerf-gt", ("--blur-samples", "--integral-window", "--lambda", "--no-mask", "--set spike.pixels"),
         ("--window", "--set spike.window")),
        ("spike-nerf", ("--blur-samples", "--integral-window"), ()),
    ]:  # fmt: skip  # --window and spike.window set eval's checks and the hold-out guard band of every method
        code, _, _ = run_cli(
            capsys, "train", dataset_dir, "--out", tmp_path / method, "--method", method, *flags
        )
        config, notes = called[-1]
        assert code == 0 and config.spike.lam == 0.5  # (kept in the config, unused)
        said = [f"{flag} is not used by --method {method}; ignored" for flag in unused]
        assert notes[: len(said)] == said
        assert [n.partition(" does not")[0] for n in notes[len(said) :]] == list(checks_only)
        assert all(checks in n for n in notes[len(said) :])
    code, _, _ = run_cli(
        capsys, "train", dataset_dir, "--out", tmp_path / "mlp", "--field", "mlp", "--batch", 8
    )
    assert code == 0 and called[-1][1][-1].startswith("--field mlp on a CPU: the paper's MLP runs 64 + 192")
    assert "a step of 8 rays can take minutes" in called[-1][1][-1]
    for method, said in (("nerf-gt", True), ("nerf-recon", False)):  # nerf-gt reads no reconstruction
        code, _, _ = run_cli(capsys, "train", dataset_dir, "--out", tmp_path / f"r-{method}", "--method",
                             method, "--recon", "tfi")  # fmt: skip
        recon = (
            f"--recon does not change how --method {method} trains; it only sets the reconstruction eval's"
        )
        assert code == 0 and [n.startswith(recon) for n in called[-1][1]] == ([True] if said else [])
    for method, said in (("spike-integral", True), ("spike-nerf", False)):  # spike-integral: eval's S only
        code, _, _ = run_cli(capsys, "train", dataset_dir, "--out", tmp_path / f"p-{method}", "--method",
                             method, "--window-poses", 2)  # fmt: skip
        poses = f"--window-poses does not change how --method {method} trains; it only sets how many renders"
        assert code == 0 and called[-1][0].targets.window_poses == 2
        assert [n.startswith(poses) for n in called[-1][1]] == ([True] if said else [])
    for recon, said in (("tfi", True), ("tfp", False)):  # TFI's targets have no window
        code, _, _ = run_cli(capsys, "train", dataset_dir, "--out", tmp_path / recon, "--method",
                             "nerf-recon", "--recon", recon, "--window", "21")  # fmt: skip
        tfi = "--window does not change --recon tfi's targets (TFI has no window); it only sets the hold-out"
        assert code == 0 and [n.startswith(tfi) for n in called[-1][1]] == ([True] if said else [])
    for warmup, said in ((6, True), (5, False)):  # a warm-up as long as the run: the spike loss never starts
        code, _, _ = run_cli(capsys, "train", dataset_dir, "--out", tmp_path / f"w{warmup}", "--method",
                             "spike-nerf", "--iters", 6, "--spike-warmup", warmup)  # fmt: skip
        never = "--spike-warmup 6 is not below --iters 6: the spike loss never switches on"
        assert code == 0 and called[-1][1] == ([never] if said else [])
    monkeypatch.undo()
    cfg = _config(dataset_dir, method="nerf-gt")
    cfg.iters, cfg.eval_every = 1, 0
    train(cfg, tmp_path / "run", dataset, progress=False, notes=["--lambda is not used"])
    assert capsys.readouterr().err.splitlines()[0] == "spikenerf: warning: --lambda is not used"
    with pytest.raises(InputError):  # a refused setup: its error alone
        train(
            _config(dataset_dir, method="nerf-gt"), tmp_path / "run", dataset, notes=["--lambda is not used"]
        )
    assert "warning" not in capsys.readouterr().err


def test_cli_train_and_errors(dataset_dir: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.cli import main

    out = tmp_path / "run"
    args = ["train", str(dataset_dir), "--method", "nerf-recon", "--field", "mlp", "--iters", "2"]
    args += ["--batch", "32", "--eval-every", "0", "--device", "cpu", "--quiet"]
    args += [f"--field-option={k}={v}" for k, v in _TINY_MLP.items()] + ["--out", str(out)]
    main(args)
    said = capsys.readouterr()
    assert "trained 2 iterations" in said.out and "resuming" not in said.err  # a fresh run says no such line
    assert load_config(out / "config.yaml").method == "nerf-recon"
    assert load_config(out / "config.yaml").field_config == _TINY_MLP
    bad_runs = [
        args,  # the run exists: needs --resume
        ["train", str(tmp_path / "nope"), "--out", str(tmp_path / "x")],  # no dataset
        [*args[:-2], "--field-option", "no-equals-sign", "--out", str(tmp_path / "y")],
        [*args[:-2], "--field-option", "no_such_key=1", "--out", str(tmp_path / "z")],
    ]
    for bad in bad_runs:
        with pytest.raises(SystemExit) as exit_:
            main(bad)
        assert exit_.value.code == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("spikenerf: error:") and "\n" not in err
    with pytest.raises(SystemExit):  # a run folder given as the dataset is named as such
        main(["train", str(out), "--out", str(tmp_path / "w")])
    assert capsys.readouterr().err.strip().endswith("run: is a run folder, not a dataset folder")
    main([*args[:-2], "--iters", "3", "--out", str(out), "--resume"])  # extends the run by one iteration
    assert torch.load(out / CHECKPOINT, weights_only=True)["iteration"] == 3
    said = capsys.readouterr()  # where it resumes, first (the last line counts the whole run: 3 iterations)
    assert said.err.startswith(f"spikenerf: resuming {out} at iteration 2 of 3 (checkpoint written 20")
    assert " s of training)\n" in said.err and "trained 3 iterations" in said.out
    main(["info", str(out)])
    info = capsys.readouterr().out
    assert "method: nerf-recon" in info and "iterations: 3 of 3" in info and "field: mlp" in info


def test_an_early_occupancy_update_does_not_stop_training(dataset_dir: Path, tmp_path: Path) -> None:
    """Regression: an occupancy update before any density exists used to cull every cell, for good."""
    cfg = _config(dataset_dir, method="nerf-gt")
    cfg.iters, cfg.eval_every, cfg.batch = 60, 10, 256
    cfg.field_config = {"n_voxels_init": 16**3, "n_voxels_final": 32**3}
    cfg.field_config.update(occupancy_start=1, iterations=60)  # an update after the first step
    trainer = Trainer(cfg, tmp_path / "run", progress=False)
    trainer.train()
    assert trainer.model.field.occupancy.occupied_fraction() > 0.0
    assert trainer.curves[-1]["test_psnr"] > trainer.curves[0]["test_psnr"] + 3.0


def test_default_spike_schedule_scales_with_the_run(dataset_dir: Path, tmp_path: Path) -> None:
    """Regression: a fixed 300-iteration warm-up meant runs of ≤ 300 iterations never used the spike loss."""
    assert TrainConfig().spike.schedule(1500) == (300, 300) and TrainConfig().spike.schedule(300) == (60, 60)
    params = {}
    for enabled in (True, False):
        cfg = _config(dataset_dir, method="spike-nerf")
        cfg.iters, cfg.spike.enabled = 10, enabled
        cfg.spike.warmup_iters = cfg.spike.ramp_iters = None  # the defaults: 2 and 2 for 10 iterations
        trainer = Trainer(cfg, tmp_path / f"run-{enabled}", progress=False)
        trainer.train()
        params[enabled] = torch.cat([p.detach().flatten() for p in trainer.model.parameters()])
    assert not torch.equal(params[True], params[False])


def test_tensorboard_log_holds_every_scalar_and_the_test_renders(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    cfg = _config(dataset_dir, log="tensorboard", log_every=2)
    cfg.iters, cfg.eval_every = 12, 6
    reads, syncs = [], []
    real_read = RunningMeans.read
    monkeypatch.setattr(RunningMeans, "read", lambda self: reads.append(1) or real_read(self))
    real = {m: getattr(torch.Tensor, m) for m in ("item", "cpu")}
    for method in real:  # device → host transfers made by the training code itself

        def counted(self: torch.Tensor, *a: object, _m: str = method, **k: object) -> object:
            frame = traceback.extract_stack(limit=2)[0]
            if "spikenerf/train/" in frame.filename.replace("\\", "/"):
                syncs.append(f"{frame.filename.rsplit('/', 1)[-1]}:{frame.name}")
            return real[_m](self, *a, **k)

        monkeypatch.setattr(torch.Tensor, method, counted)
    Trainer(cfg, tmp_path / "run", dataset, progress=False).train()
    assert len(reads) == 12 // 2 + 2 + 1  # the per-step values are read every 2 steps, at evals, at the end
    # no transfer in the training step itself: one per read of the sums, the rest in evaluation/logging
    assert 0 < syncs.count("logger.py:read") <= len(reads), sorted(syncs)  # an empty read transfers nothing
    assert {s.split(":")[0] for s in syncs} == {"logger.py", "evaluate.py"}, sorted(syncs)
    events = EventAccumulator(str(tmp_path / "run" / "tensorboard"), size_guidance={"images": 0}).Reload()
    tags = set(events.Tags()["scalars"])
    want = {"loss/loss", "loss/recon", "loss/spike", "loss/reg", "lambda", "rays_per_s", "psnr/train"}
    assert want | {"psnr/test", "lr/grid", "lr/network"} <= tags, tags
    assert [e.step for e in events.Scalars("loss/recon")] == [2, 4, 6, 8, 10, 12]
    assert [e.step for e in events.Scalars("psnr/test")] == [6, 12]
    lam = [e.value for e in events.Scalars("lambda")]
    assert lam[0] == 0.5 and lam[-1] == 1.0  # warm-up 1, ramp 2: λ(1) = 0.5, then 1
    lr = [e.value for e in events.Scalars("lr/network")]
    assert lr[0] > lr[-1] > 0  # exponential decay
    rows = read_curves(tmp_path / "run" / "curves.csv")
    assert [r["iteration"] for r in rows] == [6, 12] and rows[-1]["spike"] > 0 and rows[-1]["lambda"] == 1.0
    assert events.Tags()["images"] == ["test/view0"] and len(events.Images("test/view0")) == 2


def test_tensorboard_after_resume_has_each_step_once(tmp_path: Path) -> None:
    """Steps logged after the last checkpoint and logged again by the resumed run are purged."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from spikenerf.train.logger import TensorBoardLog

    log = TensorBoardLog(tmp_path)
    for step in range(1, 9):  # interrupted after 8 steps; the checkpoint is at 4
        log.scalars(step, {"loss/recon": float(step)})
    log.close()
    time.sleep(1.1)  # a new event file name (SummaryWriter names files by the second)
    log = TensorBoardLog(tmp_path, start=4)
    for step in range(5, 11):
        log.scalars(step, {"loss/recon": 10.0 * step})
    log.close()
    events = EventAccumulator(str(tmp_path / "tensorboard")).Reload()
    got = [(e.step, e.value) for e in events.Scalars("loss/recon")]
    assert got == [(s, float(s)) for s in range(1, 5)] + [(s, 10.0 * s) for s in range(5, 11)]


def test_tensorboard_missing_is_one_line_with_the_install_hint(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)
    with pytest.raises(InputError, match=r"pip install 'spikenerf\[tensorboard\]'"):
        Trainer(_config(dataset_dir, log="tensorboard"), tmp_path / "run", dataset, progress=False).train()
    assert not (tmp_path / "run").exists()  # nothing half-written


def test_cli_config_file_and_set_reach_every_field(dataset_dir: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.cli import main

    first = tmp_path / "a"
    sets = [f"field_config.{k}={v}" for k, v in _TINY_MLP.items()]
    sets += ["spike.lam=0.25", "spike.pairs=window", "targets.mask_n=3", "lr_final_ratio=0.5", "lr=1e-3"]
    args = [
        "train",
        str(dataset_dir),
        "--method",
        "spike-nerf",
        "--field",
        "mlp",
        "--iters",
        "2",
        "--batch",
        "32",
    ]
    args += ["--eval-every", "0", "--device", "cpu", "--quiet", "--out", str(first)]
    main(args + [f"--set={s}" for s in sets])
    cfg = load_config(first / "config.yaml")
    assert (cfg.spike.lam, cfg.spike.pairs, cfg.targets.mask_n, cfg.lr_final_ratio, cfg.lr) == (
        0.25, "window", 3, 0.5, 0.001
    )  # fmt: skip
    assert cfg.field_config == _TINY_MLP and cfg.field == "mlp" and cfg.iters == 2
    # a run folder's config.yaml is a valid --config (no DATASET needed); options and --set override it
    second = tmp_path / "b"
    main(["train", "--config", str(first / "config.yaml"), "--iters", "3", "--set", "spike.every=2",
          "--field-option", "width=24", "--quiet", "--out", str(second)])  # fmt: skip
    again = load_config(second / "config.yaml")  # --field-option merges into the file's field_config
    spike = dataclasses.replace(cfg.spike, every=2)
    assert again == dataclasses.replace(cfg, iters=3, spike=spike, field_config={**_TINY_MLP, "width": 24})
    capsys.readouterr()
    for bad, message in [
        ("spike.kind=nope", "spike.kind must be one of interval, paper, found 'nope'"),
        ("iters=many", "iters must be an integer, found 'many'"),
        ("spike.lamda=1", "unknown spike keys ['lamda']"),
        ("iters.x=1", "'iters' is not a section"),
        ("no-equals", "override expects KEY=VALUE"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            main(
                ["train", "--config", str(first / "config.yaml"), "--set", bad, "--out", str(tmp_path / "c")]
            )
        err = capsys.readouterr().err.strip()
        assert exit_.value.code == 2 and message in err and "\n" not in err, err
    assert not (tmp_path / "c").exists()


def test_config_errors_name_the_key_and_the_cli_the_flag(dataset_dir: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.cli import main

    with pytest.raises(InputError, match=r"^targets\.window must be an odd"):
        TrainConfig(targets=dataclasses.replace(TrainConfig().targets, window=4)).validate()
    with pytest.raises(SystemExit):
        main(["train", str(dataset_dir), "--window", "4", "--out", str(tmp_path / "r")])
    assert (
        capsys.readouterr().err.strip()
        == "spikenerf: error: --window must be an odd number of steps ≥ 1 (K = 2h+1, centred), found 4"
    )


def test_a_config_value_of_another_type_names_its_key_and_type() -> None:
    """``TrainConfig(iters=np.float64(2.5))`` (a numpy scalar: a Python number to the check) and a string are
    named with the key; a numpy integer is an integer (test_api_inputs)."""
    import numpy as np

    for value, found in (
        (np.float64(2.5), r"found 2.5$"),
        ("many", r"found 'many'$"),
        ({1}, r"found \{1\} \(set\)$"),
    ):
        with pytest.raises(InputError, match=f"^iters must be an integer, {found}") as err:
            TrainConfig(iters=value).validate()  # type: ignore[arg-type]
        assert err.value.params == ("iters",)


def test_set_coerces_number_strings_by_the_key_type() -> None:
    """``1e-3`` (a string to YAML 1.1) becomes a float for a float key only; a string key keeps it."""
    from spikenerf.fields import field_config
    from spikenerf.train.config import TrainConfig
    from spikenerf.train.config_file import apply_overrides

    sets = ["dataset=1e3", "lr=1e-3", "field_config.lr=2e-2"]
    cfg = TrainConfig.from_dict(apply_overrides(TrainConfig().to_dict(), sets)).validate()
    assert cfg.dataset == "1e3" and cfg.lr == 1e-3
    assert field_config("grid", cfg.field_config).lr == 2e-2


def test_info_of_a_run_prints_the_psnr_that_train_printed(dataset_dir: Path, tmp_path: Path) -> None:
    """curves.csv keeps 4 decimals, so a value such as 21.39503 rounded there to 21.3950 printed as 21.39 in
    ``info`` while ``train`` printed 21.40: ``info`` reads the finished run's summary.json."""
    from spikenerf.train.run import describe_run

    out = tmp_path / "run"
    train(_config(dataset_dir, method="nerf-gt"), out, progress=False)
    summary = json.loads((out / "summary.json").read_text())
    summary.update(train_psnr=21.395028, test_psnr=18.004999)
    (out / "summary.json").write_text(json.dumps(summary))
    line = next(x for x in describe_run(out).splitlines() if x.startswith("last evaluation"))
    assert "train PSNR 21.40 dB (against its training targets), test PSNR 18.00 dB (on 1 of 2" in line
    (out / "summary.json").write_text(json.dumps({**summary, "test_psnr": None}))  # no test views scored
    line = next(x for x in describe_run(out).splitlines() if x.startswith("last evaluation"))
    assert line.endswith("test PSNR n/a")  # as train printed it (it read "nan dB")
    assert (summary["test_views"], summary["dataset_views"]) == (1, 2)  # eval_views 1 of the 2 test views
    old = {k: v for k, v in summary.items() if k not in ("test_views", "dataset_views")}
    (out / "summary.json").write_text(json.dumps(old))  # a summary.json written before the counts
    line = next(x for x in describe_run(out).splitlines() if x.startswith("last evaluation"))
    assert line.endswith("test PSNR 18.00 dB")
    kept = (out / "curves.csv").read_text()
    (out / "curves.csv").write_text("iteration,seconds\n3,x\n")  # garbled: refused, naming the file
    with pytest.raises(InputError, match="not a training curve table"):
        describe_run(out)
    (out / "curves.csv").unlink()  # removed: summary.json's line
    assert "train PSNR 21.40 dB (against its training targets), test PSNR 18.00 dB (from summary.json)" in (
        next(x for x in describe_run(out).splitlines() if x.startswith("last evaluation"))
    )
    (out / "curves.csv").write_text(kept)
    (out / "summary.json").unlink()  # an unfinished or older run: curves.csv's values
    line = next(x for x in describe_run(out).splitlines() if x.startswith("last evaluation"))
    assert "train PSNR 21.40" not in line


def test_info_names_eval_keyframes_only_for_a_dataset_that_has_them(tmp_path: Path) -> None:
    """A spike-integral run's "eval's TFP keyframes" line is about an imported dataset's test views; a
    simulated dataset (sharp test renders) or a dataset that is gone gets no such line."""
    from spikenerf.train.config import TrainConfig
    from spikenerf.train.run import _tfp_keyframes

    config = TrainConfig(dataset=str(tmp_path))
    assert not _tfp_keyframes(config)  # no config.yaml
    (tmp_path / "config.yaml").write_text("fps: 40000\n")  # simulated
    assert not _tfp_keyframes(config)
    (tmp_path / "config.yaml").write_text("imported: {test_keyframes: [3, 9], window: 21}\n")
    assert _tfp_keyframes(config)
    (tmp_path / "config.yaml").write_text("imported: {test_keyframes: [3], keyframe_images: learned}\n")
    assert not _tfp_keyframes(config)
    (tmp_path / "config.yaml").write_text("imported: [unclosed\n")  # unreadable: info still describes the run
    assert not _tfp_keyframes(config)


def test_the_fused_kernels_first_build_is_not_training_time(
    dataset_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The trainer calls ``Field.prepare`` before its clock starts: a first build of the CPU kernel (about a
    minute, stood in for by a 1.5 s wait on the first call) no longer counts as the first step's time."""
    import time

    import spikenerf.fields.grid as grid

    real, calls = grid.available, []

    def slow_first(*args: object) -> bool:
        if not calls:
            time.sleep(1.5)
        calls.append(1)
        return real()

    monkeypatch.setattr(grid, "available", slow_first)
    config = _config(dataset_dir, method="nerf-gt")
    config.iters, config.eval_every = 2, 0
    summary = train(config, tmp_path / "run", progress=False)
    assert calls and summary.seconds < 1.5


def test_more_eval_views_than_the_dataset_has_are_named(
    dataset_dir: Path, dataset, tmp_path: Path, capsys
) -> None:  # type: ignore[no-untyped-def]
    held = len(dataset.test.images)
    cfg = _config(dataset_dir, method="nerf-gt")
    cfg.eval_views = held + 5
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    said = (
        f"spikenerf: warning: --eval-views {held + 5}: the dataset has {held} test views; evaluating {held}"
    )
    assert capsys.readouterr().err.splitlines() == [said] and len(trainer.test_views.images) == held
    cfg.eval_views = held
    Trainer(cfg, tmp_path / "other", dataset, progress=False)
    assert capsys.readouterr().err == ""


def test_hold_out_settings_without_a_hold_out_are_named(
    dataset_dir: Path, dataset, tmp_path: Path, capsys
) -> None:  # type: ignore[no-untyped-def]
    cfg = _config(dataset_dir, method="nerf-gt")
    cfg.holdout_steps, cfg.holdout_radius = 3, 10  # a simulated dataset holds out nothing by default
    Trainer(cfg, tmp_path / "run", dataset, progress=False)
    said = (
        "spikenerf: warning: --holdout-steps, --holdout-radius: this run holds out no steps (--holdout turns"
    )
    assert capsys.readouterr().err.startswith(said)
    cfg.holdout = True
    Trainer(cfg, tmp_path / "held", dataset, progress=False)
    assert "holds out no steps" not in capsys.readouterr().err


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("10,1.0,20.0,21.0\n20,2.0,22\n", "line 3 is not a row of numbers"),  # cut short
        ("10,1.0,abc,21.0\n", "line 2 is not a row of numbers"),
        ("iteration;seconds\n", "no column 'iteration'"),
        ("10,1.0,20.0,21.0\n\xff\xfe\n", "UnicodeDecodeError"),
    ],
)
def test_a_garbled_curve_table_names_its_line_and_what_to_do(tmp_path: Path, text: str, words: str) -> None:
    path = tmp_path / "curves.csv"
    header = "" if text.startswith("iteration") else "iteration,seconds,train_psnr,test_psnr\n"
    path.write_bytes(
        (header + text).encode("utf-8", "surrogateescape").replace(b"\xc3\xbf\xc3\xbe", b"\xff\xfe")
    )
    with pytest.raises(InputError, match="move it aside") as err:
        read_curves(path)
    assert (
        words in str(err.value) and str(path) in str(err.value) and str(err.value).count("move it aside") == 1
    )


def test_a_dataset_given_twice_is_refused(dataset_dir: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``train DS --set dataset=OTHER`` trained on DS silently, although --set is applied last."""
    from helpers import run_cli

    code, _, err = run_cli(capsys, "train", dataset_dir, "--set", "dataset=nowhere", "--out", tmp_path / "r")
    assert code == 2 and "give the dataset once: as DATASET or as --set dataset=PATH" in err
    assert not (tmp_path / "r").exists()

"""spike-integral: count targets over any window, stratified steps, the window-mean loss (smoke, exception,
gradcheck, unbiasedness), the sampler's hold-out and resume, the gradient reaching the field, and the CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import test_train
from spikenerf.camera.firing import fire
from spikenerf.camera.reconstruct import tfp
from spikenerf.core.errors import InputError
from spikenerf.data.integral import (
    CountTargets,
    WindowTargetSampler,
    count_targets,
    stratified_steps,
)
from spikenerf.data.rays import pixel_rays
from spikenerf.render import RenderOutput
from spikenerf.train.checkpoint import CHECKPOINT, load_checkpoint
from spikenerf.train.losses import window_mean_loss
from spikenerf.train.pose_refine import REFINED_POSES, PoseRefiner, refined_dataset
from spikenerf.train.trainer import Trainer

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures


def _stream(steps: int = 60, h: int = 3, w: int = 4, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    light = rng.uniform(0, 1, (steps, h, w)).astype(np.float32)
    acc, spikes = torch.as_tensor(rng.uniform(0, 1, (h, w)).astype(np.float32)), []
    for step in torch.as_tensor(light):  # the camera's own rule, from a random start in [0, φ)
        fired, acc = fire(acc, step, 1.0)
        spikes.append(fired)
    return torch.stack(spikes).to(torch.uint8).numpy(), light


def test_count_window_mean_is_tfp_for_a_centred_window_and_within_the_interval() -> None:
    spikes, light = _stream()
    poses = np.tile(np.eye(4, dtype=np.float32), (len(spikes), 1, 1))
    counts = count_targets(spikes, poses, 1.0)
    assert counts.steps == 60 and counts.counts.dtype == torch.int16
    xs, ys = np.meshgrid(np.arange(4), np.arange(3))
    pixels = torch.as_tensor(np.stack([xs.ravel(), ys.ravel()], -1))
    k, window = 30, 11
    start = torch.full((len(pixels),), k - window // 2)
    mean = counts.window_mean(start, start + window, pixels)[:, 0]
    expected = tfp(spikes, window=window, threshold=1.0, frames=slice(k, k + 1))[0]
    assert torch.allclose(mean, torch.as_tensor(expected[ys.ravel(), xs.ravel()]), atol=1e-6)
    truth = light[k - 5 : k + 6, ys.ravel(), xs.ravel()].mean(axis=0)  # |mean − truth| < φ / L
    assert np.all(np.abs(mean.numpy() - truth) < 1.0 / window)


def _constant_stream(rates: tuple[float, ...], steps: int = 400) -> np.ndarray:
    acc = torch.as_tensor(np.random.default_rng(1).uniform(0, 1, (1, len(rates))).astype(np.float32))
    light, spikes = torch.as_tensor(rates, dtype=torch.float32)[None], []
    for _ in range(steps):
        fired, acc = fire(acc, light, 1.0)
        spikes.append(fired)
    return torch.stack(spikes).to(torch.uint8).numpy()  # (T, 1, len(rates))


def test_aligned_windows_hold_whole_spikes_and_are_exact_to_the_pixels_own_light() -> None:
    rates = (0.07, 0.8)
    spikes = _constant_stream(rates)
    counts = count_targets(spikes, np.tile(np.eye(4, dtype=np.float32), (len(spikes), 1, 1)), 1.0)
    g = torch.Generator().manual_seed(0)
    start = torch.randint(0, 360, (400,), generator=g)  # room for two dark spikes after each start
    pixels = torch.stack([torch.arange(400) % 2, torch.zeros(400, dtype=torch.int64)], dim=1)
    a, b = counts.align(start, start + 11, pixels, g, longest=88)
    col = counts.counts[:, 0, :, 0].long()
    assert torch.all(a >= start) and not torch.equal(b - a, torch.full_like(a, 11))
    for i in range(400):
        x, lo, hi = int(pixels[i, 0]), int(a[i]), int(b[i])
        assert spikes[hi - 1, 0, x] == 1 and col[lo, x] == col[lo - 1, x] + 1  # from a spike to a spike
    fixed = counts.window_mean(start, start + 11, pixels)[:, 0]
    aligned = counts.window_mean(a, b, pixels)[:, 0]
    truth = torch.as_tensor(rates)[pixels[:, 0]]
    assert torch.all((aligned - truth).abs() <= truth / (b - a).float() + 1e-6)  # ± I / L', not ± φ / L
    dark = pixels[:, 0] == 0
    assert (aligned - truth)[dark].abs().max() < 0.3 * (fixed - truth)[dark].abs().max()
    assert int((b - a)[dark].float().mean().round()) == 14  # one spike of a 0.07 pixel: about 1 / 0.07 steps


def test_aligned_windows_keep_their_place_without_enough_spikes_or_past_the_bound() -> None:
    spikes = _constant_stream((0.0, 0.01), steps=300)  # no spike; about three spikes
    counts = count_targets(spikes, np.tile(np.eye(4, dtype=np.float32), (300, 1, 1)), 1.0)
    start = torch.tensor([10, 20, 250])
    pixels = torch.tensor([[0, 0], [1, 0], [1, 0]])
    a, b = counts.align(start, start + 11, pixels, torch.Generator().manual_seed(0), longest=50)
    assert torch.equal(a, start) and torch.equal(b, start + 11)  # 0 spikes; 100-step gaps > 50; too few left


def test_count_targets_refuse_poses_of_another_length() -> None:
    spikes, _ = _stream()
    with pytest.raises(InputError, match="poses"):
        count_targets(spikes, np.zeros((5, 4, 4), np.float32), 1.0)


def test_stratified_steps_cover_each_window_uniformly() -> None:
    gen = torch.Generator().manual_seed(0)
    start, end = torch.full((20000,), 10), torch.full((20000,), 22)  # L = 12, S = 3 divides it
    steps = stratified_steps(start, end, 3, gen)
    assert steps.shape == (20000, 3) and bool((steps >= 10).all() and (steps < 22).all())
    assert bool((steps[:, 1:] >= steps[:, :-1]).all())
    freq = torch.bincount(steps.reshape(-1) - 10, minlength=12).double() / steps.numel()
    assert torch.allclose(freq, torch.full((12,), 1 / 12, dtype=torch.float64), atol=0.01)
    with pytest.raises(InputError, match="samples"):
        stratified_steps(start, end, 0, gen)


def test_window_mean_loss_smoke_and_exceptions() -> None:
    t = torch.tensor([[0.2], [0.5]])
    assert float(window_mean_loss(t[:, None], t)) == 0.0
    assert float(window_mean_loss(t[:, None] + 0.1, t)) == pytest.approx(0.01)
    band = torch.tensor([[0.05], [0.2]])  # errors inside ± band are free; beyond it, the distance
    assert float(window_mean_loss(t[:, None] + 0.1, t, band)) == pytest.approx(0.05**2 / 2)
    with pytest.raises(ValueError, match="means must be"):
        window_mean_loss(t, t)


def test_gradcheck_window_mean_loss() -> None:
    gen = torch.Generator().manual_seed(1)
    target = torch.rand(5, 2, generator=gen, dtype=torch.float64)
    band = torch.full((5, 1), 0.01, dtype=torch.float64)
    for groups in (1, 3):
        means = torch.rand(5, groups, 2, generator=gen, dtype=torch.float64).requires_grad_()
        assert torch.autograd.gradcheck(lambda m: window_mean_loss(m, target), (means,))
        assert torch.autograd.gradcheck(lambda m: window_mean_loss(m, target, band), (means,))


def test_two_groups_are_unbiased_and_one_group_adds_the_variance() -> None:
    """Renders inside a window vary; E[loss] with G = 2 is the squared bias alone, with G = 1 plus Var."""
    gen = torch.Generator().manual_seed(2)
    renders = torch.tensor([0.1, 0.3, 0.5, 0.9], dtype=torch.float64)  # one window, four steps
    target = torch.tensor([[0.35]], dtype=torch.float64)
    bias2 = float((renders.mean() - target) ** 2)
    draws = renders[torch.randint(0, 4, (200000, 2), generator=gen)]  # S = 1 step per group
    unbiased = window_mean_loss(draws[:, :, None], target.expand(200000, 1))
    single = window_mean_loss(draws[:, :1, None], target.expand(200000, 1))
    assert float(unbiased) == pytest.approx(bias2, abs=2e-3)
    assert float(single) == pytest.approx(bias2 + float(renders.var(unbiased=False)), abs=2e-3)


def test_sampler_resumes_and_keeps_out_of_held_out_windows() -> None:
    starts = {5: torch.tensor([0, 1, 2, 40]), 11: torch.tensor([3, 30])}
    a = WindowTargetSampler(60, 3, 4, [5, 11], 2, 2, seed=7, starts=starts)
    first = a.sample(64)
    state = a.state_dict()
    second = a.sample(64)
    b = WindowTargetSampler(60, 3, 4, [5, 11], 2, 2, seed=99, starts=starts)
    b.load_state_dict(state)
    assert all(torch.equal(x, y) for x, y in zip(second, b.sample(64), strict=True))
    start, end, pixels, steps = first
    length = end - start
    assert set(length.tolist()) <= {5, 11} and steps.shape == (64, 4)
    for s, n in zip(start.tolist(), length.tolist(), strict=True):
        assert s in starts[n].tolist()
    assert bool((steps >= start[:, None]).all() and (steps < end[:, None]).all())
    assert bool((pixels[:, 0] < 4).all() and (pixels[:, 1] < 3).all())
    with pytest.raises(InputError, match="lengths"):
        WindowTargetSampler(60, 3, 4, [61], 2)


def _grads(dataset_dir: Path, dataset, out: Path, **integral) -> dict[str, torch.Tensor]:  # type: ignore[no-untyped-def]
    cfg = test_train._config(dataset_dir, method="spike-integral")
    for key, value in integral.items():
        setattr(cfg.integral, key, value)
    trainer = Trainer(cfg, out, dataset, progress=False)
    trainer.train(stop_after=1)
    return {n: p.grad.clone() for n, p in trainer.model.named_parameters() if p.grad is not None}


def test_window_loss_reaches_the_field_through_the_trainer_step(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """The only data term of spike-integral: its gradient reaches the grid, and the window and group
    settings change it (a ``.detach()`` before the loss would leave the regulariser's gradient alone)."""
    one = _grads(dataset_dir, dataset, tmp_path / "a", lengths=[5], samples=2, groups=1)
    again = _grads(dataset_dir, dataset, tmp_path / "b", lengths=[5], samples=2, groups=1)
    other = _grads(dataset_dir, dataset, tmp_path / "c", lengths=[3], samples=2, groups=2)
    phased = _grads(dataset_dir, dataset, tmp_path / "d", lengths=[5], samples=2, groups=1, interpolate=True)
    grid = [k for k in one if "planes" in k or "lines" in k]
    assert grid and all(torch.equal(one[k], again[k]) for k in one)
    for changed in (other, phased):  # the interpolated counts are other targets: another gradient
        assert sum(float((one[k] - changed[k]).abs().sum()) for k in grid) > 1e-3 * sum(
            float(one[k].abs().sum()) for k in grid
        )


def test_a_one_step_track_is_the_steps_count_at_the_pixel(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    cfg = test_train._config(dataset_dir, method="spike-integral")
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    counts = trainer.method.counts
    _, _, pixels, steps = trainer.method.draw(trainer)
    step = steps[:, 0]
    origins, dirs = pixel_rays(counts.poses[step], dataset.intrinsics, pixels)
    points = origins + 2.5 * dirs  # any depth: the point lies on the pixel's ray
    one = counts.track_mean(points, step, 0, dataset.intrinsics)
    torch.testing.assert_close(one, counts.window_mean(step, step + 1, pixels), atol=0, rtol=0)
    longer = counts.track_mean(points, step, 3, dataset.intrinsics)
    assert longer.shape == one.shape and not torch.equal(longer, one)
    assert torch.all((longer >= 0) & (longer <= counts.threshold))  # a mean of 0/1 spikes
    behind = counts.track_mean(origins - dirs, step, 3, dataset.intrinsics)  # behind every camera: no step
    assert torch.equal(behind, torch.zeros_like(behind))


def test_track_targets_start_at_track_after_and_reach_the_field(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    plain = _grads(dataset_dir, dataset, tmp_path / "a", lengths=[3], samples=1, groups=1)
    later = _grads(
        dataset_dir, dataset, tmp_path / "b", lengths=[3], samples=1, groups=1, track=4, track_after=3
    )
    track = _grads(
        dataset_dir, dataset, tmp_path / "c", lengths=[3], samples=1, groups=1, track=4, track_after=0
    )
    grid = [k for k in plain if "planes" in k or "lines" in k]
    assert grid and all(torch.equal(plain[k], later[k]) for k in plain)  # iteration 0 < 3: plain windows
    assert all(float(track[k].abs().sum()) > 0 for k in grid)
    assert sum(float((plain[k] - track[k]).abs().sum()) for k in grid) > 1e-3 * sum(
        float(plain[k].abs().sum()) for k in grid
    )


def _track_draw(dataset_dir: Path, dataset, tmp_path: Path, refine: bool = False):  # type: ignore[no-untyped-def]
    """A spike-integral trainer with 7-step tracks (pose refinement on with ``refine``), its method, counts
    and one drawn batch: (trainer, method, counts, pixels (B, 2), steps (B,))."""
    cfg = test_train._config(dataset_dir, method="spike-integral")
    cfg.integral.samples, cfg.integral.groups, cfg.integral.track = 1, 1, 3
    cfg.poses.refine = refine or None
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    if refine:
        assert trainer.pose_refine is not None
        trainer.pose_refine.refiner.xi.data[:, 0] = 0.1  # a rotation of 0.1 rad: pixels move by several px
    method = trainer.method
    _, _, pixels, steps = method.draw(trainer)
    return trainer, method, method.counts, pixels, steps[:, 0]


def test_a_ray_that_hits_nothing_is_compared_with_its_pixels_own_window(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """Depth 0 (nothing hit, the white background) has no point to track: the target of such a ray is its
    pixel's window over the track's steps, so the background's loss stays at its count noise (it read the
    camera's centre before, 0 almost everywhere: a loss of 1 a ray and a train PSNR near 0 dB)."""
    trainer, method, counts, pixels, step = _track_draw(dataset_dir, dataset, tmp_path)

    def background(poses, pixels, perturb=True):  # type: ignore[no-untyped-def]
        n = len(pixels)
        return RenderOutput(torch.ones(n, 1, requires_grad=True), torch.zeros(n), torch.zeros(n))

    trainer.render_rays = background  # type: ignore[method-assign]
    term = method.track_term(trainer, pixels, step)
    own = counts.window_mean((step - 3).clamp_min(0), (step + 4).clamp_max(counts.steps), pixels)
    torch.testing.assert_close(term.loss, window_mean_loss(torch.ones(len(step), 1, 1), own, None))
    behind = counts.track_mean(*pixel_rays(counts.poses[step], dataset.intrinsics, pixels)[:1], step, 3,
                               dataset.intrinsics)  # fmt: skip
    assert float(term.loss) < float(window_mean_loss(torch.ones(len(step), 1, 1), behind, None))


def test_a_refined_run_tracks_along_the_poses_it_renders_from(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """With pose refinement the render at step k uses the refined pose; the track projected its point into
    the recorded poses, so even its own step read another pixel. A one-step track of a point on pixel p's
    (refined) ray is step k's spike at p."""
    trainer, method, counts, pixels, step = _track_draw(dataset_dir, dataset, tmp_path, refine=True)
    method.config.integral.track = 0  # one-step tracks

    def surface(poses, pixels, perturb=True):  # type: ignore[no-untyped-def]
        n = len(pixels)
        return RenderOutput(torch.full((n, 1), 0.3, requires_grad=True), torch.full((n,), 3.0), torch.ones(n))

    trainer.render_rays = surface  # type: ignore[method-assign]
    term = method.track_term(trainer, pixels, step)
    own = counts.window_mean(step, step + 1, pixels)
    torch.testing.assert_close(term.loss, window_mean_loss(torch.full((len(step), 1, 1), 0.3), own, None))
    origins, dirs = pixel_rays(trainer.pose_refine(counts.poses[step], method.step_numbers[step]),
                               dataset.intrinsics, pixels)  # fmt: skip
    recorded = counts.track_mean(origins + 3.0 * dirs, step, 0, dataset.intrinsics)  # the recorded poses'
    assert not torch.allclose(recorded, own)  # (the old target: other pixels, so the check above can fail)


def test_learned_prior_adds_its_weighted_term_and_its_gradient(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """``integral.prior=learned``: a weighted reconstruction term on learned targets at each step's pose,
    over its own rays, whose gradient reaches the grid; its targets are cached in the run folder."""
    base = _grads(dataset_dir, dataset, tmp_path / "a", lengths=[5])
    cfg = test_train._config(dataset_dir, method="spike-integral")
    cfg.integral.lengths, cfg.integral.prior, cfg.integral.prior_rays = [5], "learned", 32
    trainer = Trainer(cfg, tmp_path / "b", dataset, progress=False)
    step = trainer.method.losses(trainer, 0)
    assert set(step.terms) == {"recon", "reg", "prior"} and step.weights["prior"] == 1.0
    assert step.rays == cfg.rays_per_step() + 32
    trainer.train(stop_after=1)
    prior = {n: p.grad.clone() for n, p in trainer.model.named_parameters() if p.grad is not None}
    grid = [k for k in base if "planes" in k or "lines" in k]
    assert sum(float((prior[k] - base[k]).abs().sum()) for k in grid) > 1e-3 * sum(
        float(base[k].abs().sum()) for k in grid
    )
    assert list((tmp_path / "b" / "targets").glob("learned-*.npy"))
    cfg.integral.prior_weight = 0.0  # weight 0: the window means' gradient alone
    zero = _grads_of(Trainer(cfg, tmp_path / "c", dataset, progress=False))
    assert all(torch.allclose(zero[k], base[k]) for k in grid)


def test_prior_weight_is_constant_or_falls_linearly_to_zero() -> None:
    from spikenerf.train.config import TrainConfig
    from spikenerf.train.methods import SpikeIntegral

    config = TrainConfig(dataset="d", iters=11)
    config.integral.prior, config.integral.prior_weight = "learned", 2.0
    method = SpikeIntegral(config)
    assert [method.prior_weight(i) for i in (0, 5, 10)] == [2.0, 2.0, 2.0]
    config.integral.prior_decay = True
    assert [method.prior_weight(i) for i in (0, 5, 10)] == [2.0, 1.0, 0.0]


def _grads_of(trainer: Trainer) -> dict[str, torch.Tensor]:
    trainer.train(stop_after=1)
    return {n: p.grad.clone() for n, p in trainer.model.named_parameters() if p.grad is not None}


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "spikenerf", *args], capture_output=True, text=True, timeout=300
    )


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (["--integral-window", "0"], "--integral-window"),
        (["--integral-window", "5,abc"], "--integral-window"),
        (["--integral-window", "100000"], "--integral-window"),
        (["--integral-samples", "0"], "--integral-samples"),
        (["--set", "integral.groups=-1"], "integral.groups"),
        (["--set", "integral.lengths=[]"], "--set integral.lengths"),
        (["--recon", "learned"], "--recon"),
        (["--integral-window", "5", "--integral-samples", "6"], "--integral-samples"),  # more than it holds
        (["--batch", "1", "--integral-samples", "2"], "--batch"),
        (["--set", "integral.align=true", "--holdout"], "--holdout"),
        (["--set", "integral.prior=tfp"], "integral.prior"),
        (["--set", "integral.weight=gamma"], "integral.weight"),
        (["--set", "integral.prior_weight=-1"], "integral.prior_weight"),
        (["--set", "integral.prior_weight=nan"], "integral.prior_weight"),
        (["--set", "integral.prior_rays=0"], "integral.prior_rays"),
        (["--set", "integral.interpolate=maybe"], "integral.interpolate"),
        (["--set", "integral.interpolate=true", "--holdout"], "--holdout"),
        (["--set", "integral.interpolate_span=4"], "integral.interpolate_span"),  # without interpolate
        (["--set", "integral.track=-1"], "--set integral.track"),
        (["--integral-track", "-1"], "--integral-track"),
        (["--integral-track", "3", "--integral-samples", "2"], "--integral-track"),
        (
            ["--set", "integral.interpolate=true", "--set", "integral.interpolate_span=-1"],
            "integral.interpolate_span",
        ),
    ],
)
def test_bad_window_settings_are_one_line(
    dataset_dir: Path, tmp_path: Path, flags: list[str], named: str
) -> None:
    out = tmp_path / "run"
    run = _cli("train", str(dataset_dir), "--iters", "2", "--out", str(out), *flags)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and named in lines[0] and "Traceback" not in run.stderr
    assert not out.exists()


def test_default_method_trains_and_records_its_windows(dataset_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    run = _cli("train", str(dataset_dir), "--iters", "3", "--batch", "64", "--integral-window", "3,5",
               "--out", str(out), "--quiet")  # fmt: skip
    assert run.returncode == 0, run.stderr
    text = (out / "config.yaml").read_text()
    assert "method: spike-integral" in text and "- 3" in text and "- 5" in text


@pytest.mark.parametrize(("method", "given", "rays"), [
    ("spike-integral", None, 4096), ("nerf-gt", None, 1024), ("spike-nerf", None, 1024),
    ("spike-integral", 512, 512),
])  # fmt: skip
def test_default_batch_is_per_method_and_recorded_resolved(method: str, given: int | None, rays: int) -> None:
    from spikenerf.train.config import TrainConfig

    config = TrainConfig(dataset="d", method=method, batch=given).validate()  # type: ignore[arg-type]
    assert config.rays_per_step() == rays and config.resolved().batch == rays
    assert TrainConfig.from_dict(config.resolved().to_dict()).batch == rays  # a resumed run keeps it


def test_spike_integral_renders_its_default_batch_of_windows(dataset_dir: Path, tmp_path: Path) -> None:
    """Without --batch a spike-integral step renders 4096 rays: 4096 windows × 1 step."""
    out = tmp_path / "run"
    run = _cli("train", str(dataset_dir), "--iters", "1", "--out", str(out), "--quiet", "--eval-every", "0")
    assert run.returncode == 0, run.stderr
    assert "batch: 4096" in (out / "config.yaml").read_text()


def test_counts_move_to_the_device_and_give_the_same_means() -> None:
    spikes, _ = _stream()
    counts = count_targets(spikes, np.tile(np.eye(4, dtype=np.float32), (60, 1, 1)), 1.0)
    moved = counts.on("cpu")
    args = (torch.tensor([3, 10]), torch.tensor([14, 15]), torch.tensor([[1, 2], [3, 0]]))
    assert torch.equal(moved.window_mean(*args), counts.window_mean(*args))


@pytest.mark.cuda
def test_counts_stay_on_the_training_gpu(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    cfg = test_train._config(dataset_dir, method="spike-integral", device="cuda")
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    assert "counts" in trainer.resident and trainer.method.counts.counts.is_cuda
    assert trainer.train().iteration == cfg.iters


def _anchors(spikes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last anchor (the step after a spike) of each pixel of a (T, 1, W) stream."""
    fired = spikes[:, 0, :].astype(bool)
    steps = np.arange(1, len(spikes) + 1)[:, None]
    first = np.where(fired, steps, len(spikes) + 1).min(axis=0)
    return first, np.where(fired, steps, -1).max(axis=0)


def test_interpolated_counts_are_exact_to_one_steps_light_on_steady_pixels() -> None:
    rates = (0.07, 0.3, 0.8)
    spikes = _constant_stream(rates)
    poses = np.tile(np.eye(4, dtype=np.float32), (len(spikes), 1, 1))
    plain, fine = count_targets(spikes, poses, 1.0), count_targets(spikes, poses, 1.0, interpolate=True)
    assert plain.phase is None and fine.phase.dtype == torch.uint8 and fine.phase.shape == fine.counts.shape
    assert fine.nbytes == plain.nbytes + fine.phase.nbytes
    first, last = _anchors(spikes)
    phase = fine.phase[:, 0, :, 0]
    for x in range(3):  # 0 outside the pixel's first and last anchors and on each anchor
        assert not phase[: first[x] + 1, x].any() and not phase[last[x] :, x].any()
    g = torch.Generator().manual_seed(0)
    for length in (1, 3, 11):
        x = torch.randint(0, 3, (600,), generator=g)
        lo = torch.as_tensor(first)[x]
        start = lo + (torch.rand(600, generator=g) * (torch.as_tensor(last)[x] - length - lo)).long()
        pixels = torch.stack([x, torch.zeros_like(x)], dim=1)
        truth = torch.as_tensor(rates)[x]
        error = (fine.window_mean(start, start + length, pixels)[:, 0] - truth).abs()
        assert torch.all(error <= (truth + 1 / 256) / length + 1e-6), float(error.max())
        raw = (plain.window_mean(start, start + length, pixels)[:, 0] - truth).abs()
        dark = x == 0
        assert raw[dark].max() > 5 * error[dark].max()  # ± φ / L without the phases


def test_a_span_limit_interpolates_only_between_close_spikes() -> None:
    rates = (0.07, 0.3, 0.8)  # spikes about 14, 3.3 and 1.25 steps apart
    spikes = _constant_stream(rates)
    poses = np.tile(np.eye(4, dtype=np.float32), (len(spikes), 1, 1))
    every = count_targets(spikes, poses, 1.0, interpolate=True)
    close = count_targets(spikes, poses, 1.0, interpolate=True, max_span=5)
    assert torch.equal(close.counts, every.counts)
    assert not close.phase[:, 0, 0].any() and every.phase[:, 0, 0].any()  # the dark pixel: plain counts
    for x in (1, 2):  # spans of 3–4 and 1–2 steps: interpolated as without a limit
        assert torch.equal(close.phase[:, 0, x], every.phase[:, 0, x])
    assert torch.equal(count_targets(spikes, poses, 1.0, interpolate=True, max_span=0).phase, every.phase)


def test_interpolated_counts_stay_within_two_thresholds_and_beat_the_plain_counts() -> None:
    spikes, light = _stream(steps=400, h=4, w=6, seed=3)
    light = light * np.linspace(0.05, 0.6, 6, dtype=np.float32)  # dark to bright columns
    acc, fired = torch.zeros(4, 6), []
    for step in torch.as_tensor(light):
        f, acc = fire(acc, step, 1.0)
        fired.append(f)
    spikes = torch.stack(fired).to(torch.uint8).numpy()
    poses = np.tile(np.eye(4, dtype=np.float32), (400, 1, 1))
    plain, fine = count_targets(spikes, poses, 1.0), count_targets(spikes, poses, 1.0, interpolate=True)
    g = torch.Generator().manual_seed(1)
    for length in (1, 5):
        start = torch.randint(60, 340 - length, (3000,), generator=g)
        pixels = torch.stack(
            [torch.randint(0, 6, (3000,), generator=g), torch.randint(0, 4, (3000,), generator=g)], 1
        )
        sums = np.concatenate([np.zeros((1, 4, 6), np.float32), np.cumsum(light, axis=0)])
        x, y = pixels[:, 0].numpy(), pixels[:, 1].numpy()
        truth = torch.as_tensor((sums[start + length, y, x] - sums[start, y, x]) / length)
        error = fine.window_mean(start, start + length, pixels)[:, 0] - truth
        raw = plain.window_mean(start, start + length, pixels)[:, 0] - truth
        assert error.abs().max() < 2.0 / length
        assert error.pow(2).mean() < 0.5 * raw.pow(2).mean()


@pytest.mark.parametrize(
    ("motion", "samples", "length"),
    [(0.179, 1, 5), (0.3, 1, 5), (0.31, 1, 4), (0.48, 1, 3), (0.6, 1, 2), (3.0, 1, 2), (0.48, 4, 4),
     (math.nan, 1, 5), (0.0, 1, 5)],
)  # fmt: skip
def test_the_default_window_spans_at_most_its_pixels_of_motion(
    motion: float, samples: int, length: int
) -> None:
    from spikenerf.train.methods import default_window
    from spikenerf.train.settings import INTEGRAL_SPAN_PX

    assert default_window(motion, samples) == length
    if samples == 1 and 2 * motion <= INTEGRAL_SPAN_PX < 5 * motion:  # the longest window that fits the span
        assert length * motion <= INTEGRAL_SPAN_PX < (length + 1) * motion


def test_a_run_records_the_window_its_dataset_chose_and_resumes_with_it(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.scenes.projection import image_motion
    from spikenerf.train.methods import default_window

    motion = image_motion(dataset.trajectory.poses, dataset.intrinsics, dataset.scene_box)
    expected = default_window(motion)
    cfg = test_train._config(dataset_dir, method="spike-integral")
    assert cfg.integral.lengths is None
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    assert trainer.config.integral.lengths == [expected]
    trainer.train(stop_after=1)
    assert f"- {expected}" in (tmp_path / "run" / "config.yaml").read_text()
    again = Trainer(cfg, tmp_path / "run", dataset, resume=True, progress=False)  # not asked: the run's own
    assert again.config.integral.lengths == [expected]
    given = test_train._config(dataset_dir, method="spike-integral")
    given.integral.lengths = [7]
    assert Trainer(given, tmp_path / "other", dataset, progress=False).config.integral.lengths == [7]


@pytest.mark.parametrize(
    ("motion", "options", "half"),
    [(0.179, {}, 0), (0.3, {}, 0), (0.31, {}, 5), (0.48, {}, 5), (3.0, {}, 5), (math.nan, {}, 0),
     (0.48, {"samples": 2}, 0), (0.48, {"groups": 2}, 0)],
)  # fmt: skip
def test_tracks_are_the_default_where_the_motion_shortens_the_window(
    motion: float, options: dict, half: int
) -> None:
    from spikenerf.train.methods import default_track
    from spikenerf.train.settings import TRACK_HALF

    assert TRACK_HALF == 5 and default_track(motion, **options) == half


def test_a_run_records_its_default_track_and_a_run_from_before_tracks_resumes_without(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """An image that moves 0.48 px a step (3-step windows; the fixture's, 16 px wide, moves less): tracks on
    by default (held-out steps too), recorded; off where it moves less; a run whose config.yaml has no
    ``track`` (written before it existed) resumes with none."""
    import spikenerf.train.methods.integral as methods

    cfg = test_train._config(dataset_dir, method="spike-integral")
    assert cfg.integral.track is None
    assert Trainer(cfg, tmp_path / "slow", dataset, progress=False).config.integral.track == 0
    monkeypatch.setattr(methods, "image_motion", lambda *args: 0.48)
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    assert trainer.config.integral.track == 5 and trainer.config.integral.lengths == [3]
    trainer.train(stop_after=1)
    config = tmp_path / "run" / "config.yaml"
    assert "  track: 5\n" in config.read_text()
    assert Trainer(cfg, tmp_path / "run", dataset, resume=True, progress=False).config.integral.track == 5
    held = test_train._config(dataset_dir, method="spike-integral", holdout=True, holdout_radius=2)
    held.integral.track_after = 0
    run = Trainer(held, tmp_path / "held", dataset, progress=False)
    assert run.config.integral.track == 5 and run.method.holdout is not None
    usable = run.method.counts.usable  # tracks skip the hold-out's bands
    assert usable is not None and torch.equal(usable.cpu(), torch.as_tensor(~run.method.holdout.band()))
    assert math.isfinite(run.train(stop_after=1).train_psnr)
    config.write_text(config.read_text().replace("  track: 5\n", ""))  # a run from before track windows
    assert Trainer(cfg, tmp_path / "run", dataset, resume=True, progress=False).config.integral.track == 0


def test_still_tracks_are_clipped_windows_and_tracks_skip_unusable_steps(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """``still_mean`` is the pixel's window over the track's steps; with ``usable`` (a hold-out's bands
    excluded) neither mean reads an excluded step: a stream whose spikes all lie in excluded steps reads 0."""
    import dataclasses

    cfg = test_train._config(dataset_dir, method="spike-integral")
    counts = Trainer(cfg, tmp_path / "run", dataset, progress=False).method.counts
    step = torch.tensor([0, 1, 7, counts.steps - 2, counts.steps - 1])
    pixels = torch.tensor([[0, 0], [3, 5], [15, 15], [8, 2], [4, 4]])
    for half in (0, 2, 5):
        window = counts.window_mean(
            (step - half).clamp_min(0), (step + half + 1).clamp_max(counts.steps), pixels
        )
        torch.testing.assert_close(counts.still_mean(pixels, step, half), window)
    origins, dirs = pixel_rays(counts.poses[step], dataset.intrinsics, pixels)
    points = origins + 3.0 * dirs
    usable = torch.rand(counts.steps, generator=torch.Generator().manual_seed(0)) < 0.5
    usable[step] = True
    masked = dataclasses.replace(counts, usable=usable)
    spikes = counts.counts[1:].int() - counts.counts[:-1].int()  # (T, H, W, C)

    def keep(steps: torch.Tensor) -> CountTargets:  # the stream with the spikes of ``steps`` only
        kept = counts.counts.clone()
        kept[1:] = torch.cumsum(spikes * steps[:, None, None, None], dim=0).to(kept.dtype)
        return dataclasses.replace(masked, counts=kept)

    means = (
        lambda c: c.still_mean(pixels, step, 4),
        lambda c: c.track_mean(points, step, 4, dataset.intrinsics),
    )
    for fn in means:
        assert torch.equal(fn(keep(~usable)), torch.zeros_like(fn(masked)))  # reads no unusable step
        torch.testing.assert_close(fn(keep(usable)), fn(masked), atol=0, rtol=0)
        assert not torch.equal(fn(dataclasses.replace(keep(usable), usable=None)), fn(counts))


def test_a_track_follows_its_point_while_the_camera_moves() -> None:
    """A camera sliding sideways sees the world origin at a different pixel each step; one spike fires exactly
    there each step. The origin's track reads every one of them; the still window at its middle pixel
    reads only the steps where the origin stood on that pixel."""
    from spikenerf.scenes.poses import look_at
    from spikenerf.scenes.projection import project_points
    from spikenerf.scenes.trajectory import Intrinsics

    intrinsics, steps = Intrinsics.from_fov(16, 16, 0.8), 11
    eyes = [np.array([0.1 * k - 0.5, 0.0, 3.0]) for k in range(steps)]
    poses = np.stack([look_at(e, e * np.array([1.0, 0.0, 0.0])) for e in eyes]).astype(np.float32)
    origin = torch.zeros(1, 3)
    u, v, _ = project_points(torch.as_tensor(poses), origin.expand(steps, 3), intrinsics)
    x, y = torch.floor(u).long(), torch.floor(v).long()
    assert len(set(x.tolist())) > 5  # the origin crosses the image
    spikes = np.zeros((steps, 16, 16), np.uint8)
    spikes[np.arange(steps), y.numpy(), x.numpy()] = 1
    counts = count_targets(spikes, poses, 1.0)
    middle = torch.tensor([5])
    assert counts.track_mean(origin, middle, 5, intrinsics).item() == pytest.approx(1.0)
    still = counts.still_mean(torch.stack([x[5:6], y[5:6]], dim=1), middle, 5).item()
    assert still == pytest.approx(float((x == x[5]).sum()) / steps) and still < 0.5


def test_stratified_steps_draw_one_step_in_each_part() -> None:
    start = torch.full((500,), 10)
    steps = stratified_steps(start, start + 12, 3, torch.Generator().manual_seed(0))
    assert ((steps - 10) // 4 == torch.arange(3)).all()  # step k lies in part k of the 12-step window
    assert all(len(set(steps[:, k].tolist())) == 4 for k in range(3))  # and takes each of its 4 steps


def test_counts_on_a_device_keep_their_phases_and_usable_steps() -> None:
    spikes, _ = _stream()
    made = count_targets(spikes, np.tile(np.eye(4, dtype=np.float32), (60, 1, 1)), 1.0, interpolate=True)
    usable = torch.arange(60) % 7 != 3
    counts = CountTargets(made.counts, made.poses, made.threshold, made.phase, usable)
    moved = counts.on("cpu")
    assert made.phase is not None and moved.phase is not None and moved.usable is not None
    assert torch.equal(moved.phase, made.phase) and torch.equal(moved.usable, usable)
    assert moved.threshold == counts.threshold and torch.equal(moved.poses, counts.poses)
    pixels, steps = torch.tensor([[1, 0], [3, 0]]), torch.tensor([10, 20])
    assert torch.equal(moved.still_mean(pixels, steps, 4), counts.still_mean(pixels, steps, 4))


def test_held_out_steps_take_the_correction_of_the_nearest_trained_keyframes(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """spike-integral's windows never reach the hold-out's bands, so the keyframes inside one get no
    gradient. They are marked unreached, and eval's poses there blend the nearest trained keyframes'
    corrections (before: the recorded pose, while the field followed the refined path). The stored state,
    refined_poses.json and a checkpoint without the mark (older runs) agree."""
    cfg = test_train._config(dataset_dir, method="spike-integral")
    cfg.iters, cfg.eval_every, cfg.ckpt_every = 8, 0, 8
    cfg.poses.refine, cfg.poses.warmup_iters, cfg.poses.lr = True, 0, 1e-2
    cfg.holdout, cfg.holdout_steps, cfg.holdout_radius = True, 1, 30
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    trainer.train()
    refiner = trainer.pose_refine.refiner
    keys, reached = refiner.key_steps, refiner.reached
    check = trainer.holdout["check_steps"][0]
    band = np.abs(keys - check) <= 10  # no trained step within 20 of these keyframes
    assert band.any() and not reached[band].any() and reached[~band].all(), (keys, reached, check)
    xi = refiner.xi.detach()
    assert (xi[torch.as_tensor(~reached)] == 0).all() and (xi[torch.as_tensor(reached)] != 0).any(1).all()
    filled = refiner.filled_xi().detach()
    lo, hi = np.flatnonzero(keys < check)[-1], np.flatnonzero(keys > check)[0]
    lo, hi = max(i for i in range(lo + 1) if reached[i]), min(i for i in range(hi, len(keys)) if reached[i])
    t = (keys[band] - keys[lo]) / (keys[hi] - keys[lo])
    want = (1 - torch.as_tensor(t, dtype=torch.float32)[:, None]) * xi[lo] + torch.as_tensor(t).float()[
        :, None
    ] * xi[hi]
    torch.testing.assert_close(filled[torch.as_tensor(band)], want)
    # eval renders the held-out step at the blended correction, not at the recorded pose
    given = torch.as_tensor(dataset.trajectory.poses[check], dtype=torch.float32)[None]
    moved = trainer.pose_refine.eval_poses(given)
    assert not torch.allclose(moved, given, atol=1e-6)
    ckpt = load_checkpoint(tmp_path / "run" / CHECKPOINT)
    from_ckpt = refined_dataset(ckpt, cfg, dataset).trajectory.poses[check]
    np.testing.assert_allclose(from_ckpt, moved[0].numpy(), atol=1e-6)
    old = {k: v for k, v in ckpt["poses"]["refiner"].items() if k != "_extra_state"}  # an older run's state
    again = PoseRefiner(keys)
    again.load_state_dict(old)
    assert np.array_equal(again.reached, reached)
    doc = json.loads((tmp_path / "run" / REFINED_POSES).read_text())["keyframes"]
    assert [f["trained"] for f in doc] == reached.tolist()
    np.testing.assert_allclose([f["omega"] for f in doc], filled[:, :3].numpy(), atol=1e-6)

"""spike-integral's learned per-pixel sensor response (``integral.pixel_gain``): a smoke run, the gradient
reaching the map, the mean-zero prior, the checkpoint round trip and resume, the sensor map file, eval
without it, the option off changing nothing, bad values named by their key, each render scaled and cut at φ
(gray and rgb, several estimates a window) and the compiled step learning the map as the eager one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from torch._dynamo.utils import counters

import test_train
from spikenerf.core.errors import InputError
from spikenerf.train import compiled_step
from spikenerf.train.checkpoint import CHECKPOINT, load_checkpoint
from spikenerf.train.compiled_step import CompiledStep
from spikenerf.train.config import TrainConfig
from spikenerf.train.run import describe_run
from spikenerf.train.sensor_response import SENSOR_MAP, SensorLearner, SensorResponse, read_sensor_map
from spikenerf.train.trainer import Trainer

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures


def _config(dataset_dir: Path, **integral) -> TrainConfig:  # type: ignore[no-untyped-def]
    cfg = test_train._config(dataset_dir, method="spike-integral", color=integral.pop("color", "gray"))
    cfg.integral.lengths = [5]
    for key, value in integral.items():
        setattr(cfg.integral, key, value)
    return cfg


def _sensor(trainer: Trainer) -> SensorLearner:
    sensor = trainer.learners["sensor_response"]
    assert isinstance(sensor, SensorLearner)
    return sensor


def test_the_map_gets_the_gradient_and_its_own_prior_term(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    trainer = Trainer(_config(dataset_dir, pixel_gain=True), tmp_path / "run", dataset, progress=False)
    step = trainer.method.losses(trainer, 0)
    assert set(step.terms) == {"recon", "reg", "sensor"} and step.weights["sensor"] == 1e-3
    summary = trainer.train(stop_after=2)  # (the map's rate warms up from 0 at iteration 0)
    assert summary.iteration == 2
    m = _sensor(trainer).response.log_response
    assert m.grad is not None and float(m.grad.abs().sum()) > 0  # the window means' gradient reached it
    assert float(m.detach().abs().max()) > 0  # and the second step moved it
    assert m.shape == (1, dataset.intrinsics.height, dataset.intrinsics.width)
    # the field's gradient now passes through the response too: another run's differs from it
    plain = Trainer(_config(dataset_dir), tmp_path / "plain", dataset, progress=False)
    plain.train(stop_after=2)
    a, b = dict(trainer.model.named_parameters()), dict(plain.model.named_parameters())
    assert any(not torch.equal(a[k], b[k]) for k in a)


def test_the_map_is_centred_and_the_l2_term_pulls_it_to_nominal() -> None:
    response = SensorResponse(1, 3, 4)
    with torch.no_grad():
        response.log_response.copy_(torch.randn(1, 3, 4, generator=torch.Generator().manual_seed(0)) + 5.0)
    centred = response.centred()
    assert abs(float(centred.detach().mean())) < 1e-6  # the brightness offset of 5 is not the map's
    pixels = torch.tensor([[0, 0], [3, 2], [1, 2]])  # (x, y)
    expect = torch.exp(centred[0, pixels[:, 1], pixels[:, 0]])[:, None]
    assert torch.allclose(response.factor(pixels), expect)
    with torch.no_grad():
        response.log_response.add_(7.0)  # a constant: the same responses
    assert torch.allclose(response.factor(pixels), expect)
    assert torch.allclose(response.penalty(), centred.square().mean())
    # the gradient of any loss through the centred map sums to 0: it cannot move the map's mean
    (response.factor(pixels)[:, 0] * torch.tensor([1.0, 2.0, 3.0])).sum().backward()
    assert abs(float(response.log_response.grad.sum())) < 1e-5  # type: ignore[union-attr]
    rgb = SensorResponse(3, 2, 2)
    assert rgb.factor(torch.tensor([[1, 1]])).shape == (1, 3) and rgb.sensor_map().shape == (3, 2, 2)


def test_a_heavy_prior_keeps_the_map_near_nominal(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    spreads = []
    for name, weight in (("light", 0.0), ("heavy", 1e4)):
        cfg = _config(dataset_dir, pixel_gain=True, pixel_gain_weight=weight, pixel_gain_lr=0.05)
        trainer = Trainer(cfg, tmp_path / name, dataset, progress=False)
        trainer.train()
        centred = _sensor(trainer).response.centred().detach()
        assert abs(float(centred.mean())) < 1e-6
        spreads.append(float(centred.std()))
    assert spreads[1] < 0.5 * spreads[0], spreads


def test_checkpoint_round_trip_resume_and_sensor_map(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    cfg = _config(dataset_dir, pixel_gain=True, pixel_gain_lr=0.05)
    straight = Trainer(cfg, tmp_path / "a", dataset, progress=False)
    straight.train()
    first = Trainer(cfg, tmp_path / "b", dataset, progress=False)
    assert first.train(stop_after=3).iteration == 3
    stored = load_checkpoint(tmp_path / "b" / CHECKPOINT)  # weights_only=True
    assert torch.equal(
        stored["sensor_response"]["refiner"]["log_response"], _sensor(first).response.log_response.detach()
    )
    resumed = Trainer(cfg, tmp_path / "b", dataset, resume=True, progress=False)
    assert torch.equal(_sensor(resumed).response.log_response, _sensor(first).response.log_response)
    resumed.train()
    sa, sb = _sensor(straight).state_dict(), _sensor(resumed).state_dict()
    assert torch.equal(sa["refiner"]["log_response"], sb["refiner"]["log_response"])
    for key, value in straight.model.state_dict().items():
        assert torch.equal(value, resumed.model.state_dict()[key]), key
    written = read_sensor_map(tmp_path / "b" / SENSOR_MAP)
    assert written.dtype == np.float32 and written.shape == (16, 16)
    expect = torch.exp(_sensor(resumed).response.centred()).detach().numpy()[0]
    np.testing.assert_allclose(written, expect, rtol=1e-6)
    assert abs(float(np.log(written).mean())) < 1e-5
    info = describe_run(tmp_path / "b")
    assert "learned per-pixel response" in info and f"sensor map: {tmp_path / 'b' / SENSOR_MAP}" in info


def test_eval_renders_without_the_map(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    trainer = Trainer(_config(dataset_dir, pixel_gain=True), tmp_path / "run", dataset, progress=False)
    before = trainer.evaluate()
    with torch.no_grad():
        _sensor(trainer).response.log_response.normal_(0.0, 0.5)
    assert trainer.evaluate() == before


def test_colour_runs_learn_one_map_per_channel(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    cfg = _config(dataset_dir, pixel_gain=True, color="rgb")
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    trainer.train(stop_after=1)
    assert read_sensor_map(tmp_path / "run" / SENSOR_MAP).shape == (3, 16, 16)


def _losses(trainer: Trainer, steps: int) -> list[float]:
    losses = []
    for it in range(steps):
        step = trainer.method.losses(trainer, it)
        losses.append(float(step.total().detach()))
        trainer.train(stop_after=1)
    return losses


def test_off_is_unchanged_and_a_frozen_nominal_map_changes_nothing(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """Off (the default): no map, no term, no learner. On with the map held at its start (every pixel
    nominal, exp(0) = 1 exactly, L2 term 0): the same losses and parameters bit for bit, so the option
    enters the step only through the response factor and its own term."""
    off = Trainer(_config(dataset_dir), tmp_path / "off", dataset, progress=False)
    assert not off.config.integral.pixel_gain
    assert "sensor_response" not in off.learners and off.method.sensor is None  # type: ignore[attr-defined]
    off_losses = _losses(off, 3)
    assert set(off.method.losses(off, 3).terms) == {"recon", "reg"}
    monkeypatch.setattr(SensorLearner, "begin", _frozen)
    frozen = Trainer(_config(dataset_dir, pixel_gain=True), tmp_path / "on", dataset, progress=False)
    frozen_losses = _losses(frozen, 3)
    frozen.method.losses(frozen, 3)  # (the same draws as off's)
    assert float(_sensor(frozen).response.log_response.detach().abs().max()) == 0.0
    assert frozen_losses == off_losses
    for key, value in off.model.state_dict().items():
        assert torch.equal(value, frozen.model.state_dict()[key]), key
    assert not (tmp_path / "off" / SENSOR_MAP).exists() and (tmp_path / "on" / SENSOR_MAP).exists()


def _frozen(self: SensorLearner, iteration: int) -> None:
    """:meth:`SensorLearner.begin` at rate 0: Adam adds exactly 0 to the map."""
    for group in self.optimizer.param_groups:
        group["lr"] = 0.0
    self.optimizer.zero_grad(set_to_none=True)


@pytest.mark.parametrize(
    ("key", "value"),
    [("pixel_gain", "yes"), ("pixel_gain_weight", -1.0), ("pixel_gain_lr", 0.0), ("pixel_gain_lr", "fast")],
)
def test_bad_values_name_their_key(key: str, value: object) -> None:
    cfg = TrainConfig(dataset="d")
    setattr(cfg.integral, key, value)
    with pytest.raises(InputError) as err:
        cfg.validate()
    assert err.value.params == (f"integral.{key}",) and "--" not in str(err.value)


def test_the_response_scales_each_render_and_clips_it_at_one_spike_a_step(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """A pixel fires at most once a step, so it reports at most φ a step: each render is scaled by the
    pixel's response and cut at φ before the window mean (a pixel of response 1.5 that sees white reports
    φ, not 1.5 φ); without the option the mean is the renders' own."""
    on = Trainer(_config(dataset_dir, pixel_gain=True), tmp_path / "on", dataset, progress=False)
    factors = torch.tensor([[1.5], [0.5]])  # (B, C): two pixels
    monkeypatch.setattr(_sensor(on).response, "factor", lambda pixels: factors)
    colors = torch.tensor([[0.9, 0.2], [0.9, 0.2]])[:, None, :, None]  # (B, G=1, S=2, C=1)
    pixels = torch.zeros(2, 2, dtype=torch.long)
    sensed = on.method.sensed(colors, pixels, 1.0)  # type: ignore[attr-defined]
    assert sensed.shape == (2, 1, 1)
    assert torch.allclose(sensed[:, 0, 0], torch.tensor([(1.0 + 0.3) / 2, (0.45 + 0.1) / 2]))
    assert torch.allclose(on.method.sensed(colors, pixels, 2.0)[0, 0, 0], torch.tensor((1.35 + 0.3) / 2))
    off = Trainer(_config(dataset_dir), tmp_path / "off", dataset, progress=False)
    assert torch.equal(off.method.sensed(colors, pixels, 1.0), colors.mean(dim=2))  # type: ignore[attr-defined]


def test_each_channel_and_estimate_is_cut_by_its_own_response_and_the_coarse_renders_too(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """rgb with two estimates a window: each channel scaled by its own factor and cut at φ, every estimate
    alike; the MLP field's coarse renders go through the same sensing as its fine ones."""
    cfg = _config(dataset_dir, pixel_gain=True, color="rgb")
    on = Trainer(cfg, tmp_path / "rgb", dataset, progress=False)
    factors = torch.tensor([[2.0, 1.0, 0.5], [1.0, 1.0, 1.0]])  # (B, C): two pixels
    monkeypatch.setattr(_sensor(on).response, "factor", lambda pixels: factors)
    colors = torch.full((2, 2, 2, 3), 0.6)  # (B, G=2, S=2, C=3)
    sensed = on.method.sensed(colors, torch.zeros(2, 2, dtype=torch.long), 1.0)  # type: ignore[attr-defined]
    assert sensed.shape == (2, 2, 3)
    expect = torch.tensor([[1.0, 0.6, 0.3], [0.6, 0.6, 0.6]])[:, None].expand(2, 2, 3)
    assert torch.allclose(sensed, expect)
    cfg = test_train._config(dataset_dir, method="spike-integral", field="mlp")
    cfg.integral.lengths, cfg.integral.pixel_gain = [5], True
    mlp = Trainer(cfg, tmp_path / "mlp", dataset, progress=False)
    calls: list[tuple[int, ...]] = []
    sense = mlp.method.sensed  # type: ignore[attr-defined]
    monkeypatch.setattr(mlp.method, "sensed", lambda c, p, t: calls.append(tuple(c.shape)) or sense(c, p, t))
    mlp.method.integral_term(mlp)  # type: ignore[attr-defined]
    assert len(calls) == 2 and calls[0] == calls[1]  # the fine and the coarse renders (B, G, S, C)


@pytest.mark.usefixtures("fresh_dynamo")
def test_the_compiled_step_learns_the_map_as_the_eager_step(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """``train --compile`` (grid ``static_samples``: ``method.step_losses`` as one graph, traced here by
    ``aot_eager``) reads the map's parameter inside the graph: the same losses as the eager step, and the map
    gets its gradient and moves as there."""
    monkeypatch.setattr(compiled_step, "BACKEND", "aot_eager")
    runs = {}
    for compiled in (False, True):
        cfg = _config(dataset_dir, pixel_gain=True, pixel_gain_lr=0.05)
        cfg.field_config = {**cfg.field_config, "static_samples": 24}
        cfg.compile = compiled
        trainer = Trainer(cfg, tmp_path / str(compiled), dataset, progress=False)
        runs[compiled] = (trainer, _losses(trainer, 4))
    trainer, losses = runs[True]
    step = vars(trainer.method)["step_losses"]
    assert isinstance(step, CompiledStep) and step.failed is None and counters["stats"]["unique_graphs"] >= 1
    assert losses == pytest.approx(runs[False][1], rel=1e-4)
    m, eager = _sensor(trainer).response.log_response, _sensor(runs[False][0]).response.log_response
    assert m.grad is not None and float(m.grad.abs().sum()) > 0
    assert float(m.detach().abs().max()) > 0
    assert torch.allclose(m.detach(), eager.detach(), atol=1e-5)

"""The device part of a training step (issue 27): with the grid's ``static_samples`` the forward and loss of
nerf-gt, spike-integral and spike-nerf (its spike window too) after their host draws (``TrainMethod.draw``,
``SpikeNeRF.draw_window``, the samplers' own generators) trace as one graph with no break under
``torch._dynamo.explain`` (the CPU proxy for "no host sync"), and give the default path's loss when every
sample fits."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

import test_train
from spikenerf.fields import grid as grid_module
from spikenerf.train.trainer import Trainer

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures
METHODS = ("nerf-gt", "spike-integral", "spike-nerf")


def _draw(trainer: Trainer) -> tuple[torch.Tensor, ...]:
    """A step's host draws: spike-nerf's with a spike window (as at the steps where λ > 0)."""
    drawn = trainer.method.draw(trainer)
    if trainer.config.method == "spike-nerf":
        drawn = (*drawn, *trainer.method.draw_window(trainer))
    return drawn


def _trainer(dataset_dir: Path, dataset, out: Path, method: str, static: int) -> Trainer:  # type: ignore[no-untyped-def]
    cfg = test_train._config(dataset_dir, method=method)
    cfg.field_config = {**cfg.field_config, "static_samples": static}
    return Trainer(cfg, out, dataset, progress=False)


def _all_fit(trainer: Trainer) -> int:
    """A ``static_samples`` that holds every ray's march: the box's diagonal in steps, and one more."""
    field = trainer.model.field
    diagonal = float((field.scene_box[1] - field.scene_box[0]).norm())
    return math.ceil(diagonal / field.step_size) + 1


@pytest.mark.parametrize("method", METHODS)
def test_the_step_after_its_draws_traces_as_one_graph(
    dataset_dir: Path, dataset, tmp_path: Path, method: str, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    # the fused VM kernel (CPU only: a C++ extension that dynamo cannot trace) stays outside any graph
    monkeypatch.setattr(grid_module, "usable", lambda *_: False)
    trainer = _trainer(dataset_dir, dataset, tmp_path / "run", method, 24)
    drawn = _draw(trainer)  # on the host; no render has run (the box size is read at build)
    torch._dynamo.reset()
    try:
        explained = torch._dynamo.explain(lambda: trainer.method.step_losses(trainer, 0, drawn).total())()
    finally:
        torch._dynamo.reset()
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons
    assert explained.op_count > 50  # the render, the loss and the prior are in it


@pytest.mark.parametrize("method", METHODS)
def test_the_static_step_gives_the_default_loss_when_every_sample_fits(
    dataset_dir: Path, dataset, tmp_path: Path, method: str
) -> None:  # type: ignore[no-untyped-def]
    default = _trainer(dataset_dir, dataset, tmp_path / "default", method, 0)
    static = _trainer(dataset_dir, dataset, tmp_path / "static", method, _all_fit(default))
    losses = []
    for trainer in (default, static):
        torch.manual_seed(1)  # the jitter: every slot is kept at the first step (an unculled grid), so the
        # static path's draws begin with the packed path's
        step = trainer.method.step_losses(trainer, 0, _draw(trainer))
        losses.append((step.total().detach(), step.srgb_mse, step.rays))
        if method == "spike-nerf":  # the spike term is in the total (weights 1) and in the rays
            assert set(step.terms) == {"recon", "reg", "spike"} and step.rays == 64 + 8 * 8
    (loss, mse, rays), (static_loss, static_mse, static_rays) = losses
    assert rays == static_rays and loss > 0
    torch.testing.assert_close(static_loss, loss, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(static_mse, mse, atol=1e-5, rtol=1e-5)

"""The training losses (``train/losses.py``, kornia style): a smoke test, the refusals (InputError naming the
parameter) and a float64 ``gradcheck`` for each differentiable loss; the spike loss's and the interval
loss's existing gradchecks live in ``test_gradients.py``, the window-mean loss's in ``test_integral.py``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import torch

from helpers import refusal_test
from spikenerf.train import losses as L

D = torch.float64


def _rand(*shape: int, seed: int = 0, scale: float = 1.0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(*shape, generator=gen, dtype=D) * scale).requires_grad_()


def _spikes(*shape: int, seed: int = 1) -> torch.Tensor:
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed)) < 0.4


def test_smoke() -> None:
    pred = torch.full((4, 3), 0.5)
    assert L.recon_loss(pred, torch.zeros(4, 3)) == 0.25
    assert L.recon_loss(pred, np.zeros((4, 3))) == 0.25  # a numpy target (before: AttributeError on .to)
    intensity, spikes = torch.full((4, 2, 1), 0.5), torch.tensor([0, 1, 0, 1]).view(4, 1, 1).expand(4, 2, 1)
    assert L.spike_prefix(intensity, spikes, 1.0)[:, 0, 0].tolist() == [0.0, 0.5, 0.0, 0.5, 0.0]
    violation, length, valid = L.spike_interval_violation(intensity, spikes, 1.0)
    assert violation.shape == valid.shape == (10, 2, 1) and length.shape == (10,) and violation.eq(0).all()
    assert L.spike_interval_loss(intensity, spikes, 1.0) == 0
    assert L.spike_interval_loss(intensity * 4, spikes, 1.0) > 0
    means, target = torch.full((3, 2, 1), 0.5), torch.full((3, 1), 0.25)
    assert torch.isclose(L.window_mean_loss(means, target), torch.tensor(0.0625))
    assert L.window_mean_loss(means, target, torch.full((3, 1), 0.5)) == 0  # inside the band
    assert torch.isclose(L.window_mean_loss(means[:, :1], target, weight="srgb"), torch.tensor(0.0625))
    assert torch.allclose(L.srgb_weights(torch.rand(5, 3)).mean(), torch.tensor(1.0))
    loss = L.paper_spike_loss(intensity, spikes, 1.0, torch.zeros(2, 1), warmup=0)
    assert 0 <= loss <= 1 and not loss.requires_grad
    assert L.spike_weight(5, 0.5, 2, 4) == 0.5


def test_a_window_of_one_step_or_no_pixels_gives_zero_not_nan() -> None:
    """The interval loss's defined empty value: a window that constrains nothing (no pixel, or no pair whose
    bounds apply) is 0 with a gradient of zeros, so the step trains on its other terms."""
    for shape, max_intensity in (((1, 2, 1), 1.0), ((4, 0, 1), 1.0), ((3, 2, 1), None)):
        x = torch.zeros(shape, requires_grad=True)
        spikes = torch.ones(shape, dtype=torch.bool)  # (all fired: with max_intensity None no pair applies)
        loss = L.spike_interval_loss(
            x, spikes if max_intensity is None else ~spikes, 1.0, "all", max_intensity
        )
        assert loss == 0 and loss.requires_grad
        loss.backward()
        assert x.grad is not None and x.grad.shape == shape and x.grad.eq(0).all()


_z = torch.zeros

REFUSALS: list[tuple[str, Callable[[], object], str]] = [
    ("recon pred array", lambda: L.recon_loss(np.zeros((2, 3)), _z(2, 3)), "pred"),  # type: ignore[arg-type]
    ("recon target shape", lambda: L.recon_loss(_z(2, 3), _z(2, 1)), "target"),
    # empty batches: the mean of nothing was a NaN loss (a training step always draws rays and windows)
    ("recon no rays", lambda: L.recon_loss(_z(0, 3), _z(0, 3)), "pred"),
    ("recon no channels", lambda: L.recon_loss(_z(2, 0), _z(2, 0)), "pred"),
    ("window no windows", lambda: L.window_mean_loss(_z(0, 2, 3), _z(0, 3)), "means"),
    ("window no windows srgb", lambda: L.window_mean_loss(_z(0, 1, 3), _z(0, 3), weight="srgb"), "means"),
    ("window no channels", lambda: L.window_mean_loss(_z(2, 1, 0), _z(2, 0)), "means"),
    ("paper no pixels", lambda: L.paper_spike_loss(_z(3, 0, 1), _z(3, 0, 1), 1.0, _z(0, 1)), "intensity"),
    ("prefix 0-d", lambda: L.spike_prefix(torch.tensor(1.0), torch.tensor(1.0), 1.0), "intensity"),
    ("prefix spikes shape", lambda: L.spike_prefix(_z(3, 2, 1), _z(3, 2), 1.0), "spikes"),
    ("prefix threshold", lambda: L.spike_prefix(_z(3, 2, 1), _z(3, 2, 1), 0.0), "threshold"),
    ("prefix spike floats", lambda: L.spike_prefix(_z(3, 1), torch.full((3, 1), 0.5), 1.0), "spikes"),
    ("interval 0-d", lambda: L.spike_interval_loss(torch.tensor(1.0), torch.tensor(1.0), 1.0), "intensity"),
    (
        "interval max",
        lambda: L.spike_interval_loss(_z(3, 1), _z(3, 1), 1.0, max_intensity=float("nan")),
        "max_intensity",
    ),
    ("interval pairs", lambda: L.spike_interval_loss(_z(3, 1), _z(3, 1), 1.0, "some"), "pairs"),  # type: ignore[arg-type]
    (
        "window integer means",
        lambda: L.window_mean_loss(torch.zeros(2, 1, 3, dtype=torch.long), _z(2, 3)),
        "means",
    ),
    (
        "window no estimates",
        lambda: L.window_mean_loss(_z(2, 0, 3), _z(2, 3)),
        "means",
    ),  # (a NaN loss before)
    ("window target", lambda: L.window_mean_loss(_z(2, 1, 3), _z(2, 1)), "target"),
    ("window band", lambda: L.window_mean_loss(_z(2, 1, 3), _z(2, 3), -torch.ones(2, 1)), "band"),
    ("window weight", lambda: L.window_mean_loss(_z(2, 1, 3), _z(2, 3), weight="log"), "weight"),  # type: ignore[arg-type]
    ("srgb weights", lambda: L.srgb_weights(np.zeros((2, 3))), "render"),  # type: ignore[arg-type]
    ("paper no steps", lambda: L.paper_spike_loss(_z(0, 2, 1), _z(0, 2, 1), 1.0, _z(2, 1)), "intensity"),
    ("paper start", lambda: L.paper_spike_loss(_z(3, 2, 1), _z(3, 2, 1), 1.0, _z(2)), "start_accumulator"),
]


test_bad_inputs_are_refused_naming_the_parameter = refusal_test(REFUSALS)


def test_srgb_weights_of_an_empty_batch_are_empty() -> None:
    """Defined empty value: no render, no weight (not a NaN mean leaking into a loss)."""
    assert L.srgb_weights(torch.zeros(0, 3)).shape == (0, 3)


def test_a_nan_render_shows_as_a_nan_loss() -> None:
    """NaN is passed on, not hidden (the trainer refuses a diverged step), for every loss."""
    nan = torch.full((3, 2, 1), float("nan"))
    assert L.recon_loss(nan[0], torch.zeros(2, 1)).isnan()
    assert L.spike_interval_loss(nan, torch.zeros(3, 2, 1), 1.0).isnan()
    assert L.window_mean_loss(nan.view(3, 2, 1), torch.zeros(3, 1)).isnan()


def test_gradcheck_recon_loss_and_spike_prefix() -> None:
    pred, target = _rand(4, 3, seed=2), torch.rand(4, 3, dtype=D)
    assert torch.autograd.gradcheck(lambda p: L.recon_loss(p, target), (pred,))
    intensity, spikes = _rand(5, 3, 2, seed=3, scale=1.5), _spikes(5, 3, 2)
    assert torch.autograd.gradcheck(lambda x: L.spike_prefix(x, spikes, 0.8), (intensity,))


@pytest.mark.parametrize("max_intensity", [1.0, None])
def test_gradcheck_interval_violation(max_intensity: float | None) -> None:
    """The hinge's kinks are where a pair's integral meets ±φ exactly, which random values miss."""
    intensity, spikes = _rand(5, 3, 2, seed=4, scale=1.5), _spikes(5, 3, 2, seed=5)
    for pairs in ("all", "window"):
        assert torch.autograd.gradcheck(
            lambda x, p=pairs: L.spike_interval_violation(x, spikes, 0.8, p, max_intensity)[0], (intensity,)
        )

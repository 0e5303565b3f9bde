"""``integral.weight``: the spike-integral loss weighted by the squared sRGB slope at the detached render."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

import test_train
from spikenerf.core.color import srgb_encode, srgb_slope
from spikenerf.core.errors import InputError
from spikenerf.render import RenderOutput
from spikenerf.train.config import IntegralConfig
from spikenerf.train.losses import SRGB_WEIGHT_FLOOR, srgb_weights, window_mean_loss
from spikenerf.train.trainer import Trainer

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures


def _old_window_mean_loss(
    means: torch.Tensor, target: torch.Tensor, band: torch.Tensor | None
) -> torch.Tensor:
    """The loss as it was before ``weight`` (a copy, to hold "linear" to it bit for bit)."""
    d = means - target.to(means.dtype)[:, None]
    if band is not None:
        d = torch.sign(d) * torch.relu(d.abs() - band.to(d.dtype)[:, None])
    g = means.shape[1]
    if g == 1:
        return torch.mean(d**2)
    total = d.sum(dim=1)
    return torch.mean((total**2 - (d**2).sum(dim=1)) / (g * (g - 1)))


def test_srgb_slope_is_the_derivative_of_the_encoding_above_the_floor() -> None:
    x = torch.tensor([0.001, 0.0031, 0.004, 0.01, 0.18, 0.5, 0.99], dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(srgb_encode(x).sum(), x)
    torch.testing.assert_close(srgb_slope(x, 1e-4), grad)
    assert not srgb_slope(x, 1e-4).requires_grad
    np.testing.assert_allclose(srgb_slope(x.detach().numpy(), 1e-4), grad.numpy())
    below = torch.tensor([0.0, -1.0, 1 / 255])  # clamped to the floor; above white: white's slope
    assert torch.equal(srgb_slope(below), srgb_slope(torch.full((3,), 1 / 255)))
    assert float(srgb_slope(torch.tensor(3.0))) == pytest.approx(1.055 / 2.4)
    assert float(srgb_slope(torch.tensor(0.0))) == pytest.approx(11.1, abs=0.05)  # at 1/255


@pytest.mark.parametrize("floor", [0, -0.1, 1.5, float("nan"), "0.1", True])
def test_srgb_slope_refuses_a_bad_floor(floor: object) -> None:
    with pytest.raises(InputError, match="floor") as err:
        srgb_slope(torch.ones(2), floor)  # type: ignore[arg-type]
    assert err.value.params == ("floor",)


@pytest.mark.parametrize("groups", [1, 3])
@pytest.mark.parametrize("banded", [False, True])
def test_linear_weight_is_the_loss_as_before_bit_for_bit(groups: int, banded: bool) -> None:
    gen = torch.Generator().manual_seed(3)
    means = torch.rand(64, groups, 3, generator=gen)
    target = torch.rand(64, 3, generator=gen)
    band = torch.full((64, 1), 0.05) if banded else None
    old = _old_window_mean_loss(means, target, band)
    assert torch.equal(window_mean_loss(means, target, band), old)
    assert torch.equal(window_mean_loss(means, target, band, "linear"), old)


@pytest.mark.parametrize("groups", [1, 2])
def test_srgb_weight_is_the_hand_computed_weighted_loss(groups: int) -> None:
    pairs = [[[0.002], [0.004]], [[0.2], [0.3]], [[0.9], [0.7]]]
    means = torch.tensor(pairs, dtype=torch.float64)[:, :groups]
    target = torch.tensor([[0.01], [0.2], [0.8]], dtype=torch.float64)
    m = means.mean(dim=1)[:, 0].tolist()

    def slope(x: float) -> float:  # the derivative of the sRGB curve, by hand, at max(x, 1/255)
        x = max(x, 1 / 255)
        return 12.92 if x <= 0.0031308 else 1.055 / 2.4 * x ** (1 / 2.4 - 1)

    w = [slope(x) ** 2 for x in m]
    w = [v / (sum(w) / len(w)) for v in w]
    d = (means - target[:, None])[:, :, 0].tolist()
    # G = 2: ((Σ d)² − Σ d²) / (G(G − 1)) is the product of the two errors
    per = [e[0] ** 2 for e in d] if groups == 1 else [e[0] * e[1] for e in d]
    expected = sum(a * b for a, b in zip(w, per, strict=True)) / len(per)
    assert float(window_mean_loss(means, target, None, "srgb")) == pytest.approx(expected, rel=1e-12)
    assert w[0] > 50 * w[2]  # the dark window counts far more than the bright one


def test_srgb_weights_carry_no_gradient_and_have_mean_one() -> None:
    render = torch.rand(50, 3, dtype=torch.float64).requires_grad_()
    w = srgb_weights(render)
    assert not w.requires_grad and w.shape == render.shape and w.dtype == render.dtype
    assert float(w.mean()) == pytest.approx(1.0)
    assert torch.equal(w, srgb_weights(render.detach() * 1))  # the same at any depth of the graph
    assert pytest.approx(1 / 255) == SRGB_WEIGHT_FLOOR
    # the loss's gradient is the weights times the linear loss's per-term gradient: none through w
    means = render.detach()[:, None].clone().requires_grad_()
    target = torch.rand(50, 3, dtype=torch.float64)
    (grad,) = torch.autograd.grad(window_mean_loss(means, target, None, "srgb"), means)
    expected = w[:, None] * 2 * (means.detach() - target[:, None]) / means.numel()
    torch.testing.assert_close(grad, expected)


@pytest.mark.parametrize("groups", [1, 3])
def test_srgb_gradient_is_the_weighted_sum_of_the_linear_terms_gradients(groups: int) -> None:
    """With the band and G ≥ 2 too: each (window, channel) term's linear gradient times its weight (a
    gradcheck would differentiate the weight as well, which the loss holds constant on purpose)."""
    gen = torch.Generator().manual_seed(4)
    target = torch.rand(5, 2, generator=gen, dtype=torch.float64)
    band = torch.full((5, 1), 0.01, dtype=torch.float64)
    means = torch.rand(5, groups, 2, generator=gen, dtype=torch.float64).requires_grad_()
    w = srgb_weights(means.mean(dim=1))
    terms = [
        w[b, c]
        * window_mean_loss(means[b : b + 1, :, c : c + 1], target[b : b + 1, c : c + 1], band[b : b + 1])
        for b in range(5)
        for c in range(2)
    ]
    expected = torch.stack(terms).mean()
    loss = window_mean_loss(means, target, band, "srgb")
    torch.testing.assert_close(loss, expected)
    torch.testing.assert_close(torch.autograd.grad(loss, means)[0], torch.autograd.grad(expected, means)[0])


def test_a_bad_weight_is_refused() -> None:
    t = torch.zeros(2, 1)
    with pytest.raises(InputError, match="weight must be one of linear, srgb") as err:
        window_mean_loss(t[:, None], t, None, "log")  # type: ignore[arg-type]
    assert err.value.params == ("weight",)
    with pytest.raises(InputError, match="render"):
        srgb_weights(np.zeros((2, 1)))  # type: ignore[arg-type]
    with pytest.raises(InputError, match=r"integral\.weight"):
        IntegralConfig(weight="gamma").check()  # type: ignore[arg-type]


def _fake_render(colors: torch.Tensor):  # type: ignore[no-untyped-def]
    """A renderer that returns ``colors`` cycled over the rays (varied, so that the weights differ)."""

    def render(poses, pixels, perturb=True):  # type: ignore[no-untyped-def]
        n = len(pixels)
        color = colors[torch.arange(n) % len(colors)][:, None].clone().requires_grad_()
        return RenderOutput(color, torch.zeros(n), torch.zeros(n))

    return render


@pytest.mark.parametrize("track", [False, True])
def test_the_method_weighs_its_window_and_track_terms(
    dataset_dir: Path, dataset, tmp_path: Path, track: bool
) -> None:  # type: ignore[no-untyped-def]
    """``integral.weight=srgb`` reaches both of spike-integral's terms: the loss of a batch is
    ``window_mean_loss(..., "srgb")`` of its renders and targets, not the linear one."""
    cfg = test_train._config(dataset_dir, method="spike-integral")
    cfg.integral.samples, cfg.integral.groups, cfg.integral.track = 1, 1, 3 if track else 0
    cfg.integral.weight = "srgb"
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    assert "sRGB slope" in " ".join(trainer.method.settings())
    colors = torch.tensor([0.002, 0.05, 0.3, 0.9])
    trainer.render_rays = _fake_render(colors)  # type: ignore[method-assign]
    method, counts = trainer.method, trainer.method.counts
    start, end, pixels, steps = drawn = method.draw(trainer)
    renders = colors[torch.arange(len(pixels)) % 4][:, None, None]
    if track:  # depth 0 (nothing hit): each ray's own pixel over the track's steps
        term = method.track_term(trainer, pixels, steps[:, 0])
        step = steps[:, 0]
        target = counts.window_mean((step - 3).clamp_min(0), (step + 4).clamp_max(counts.steps), pixels)
    else:
        term = method.integral_term(trainer, drawn)
        target = counts.window_mean(start, end, pixels)
    torch.testing.assert_close(term.loss, window_mean_loss(renders, target, None, "srgb"))
    assert not torch.allclose(term.loss, window_mean_loss(renders, target, None, "linear"))

"""Colour and the metrics a loss or a log reads (``core/color.py``, ``core/psnr.py``, ``eval/metrics.py``),
kornia style: a smoke test, the refusals (InputError naming the parameter) and a float64 ``gradcheck`` of
each differentiable function, at points away from its kinks (the sRGB knee, the clip to [0, 1])."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
import torch

from helpers import refusal_test
from spikenerf.core import color as C
from spikenerf.core.psnr import mse_to_psnr
from spikenerf.eval import metrics as M

D = torch.float64


def _inside(*shape: int, seed: int = 0, low: float = 0.05, high: float = 0.95) -> torch.Tensor:
    """Values in [low, high]: above the sRGB knees (0.0031308 linear, 0.04045 encoded), below the clip."""
    gen = torch.Generator().manual_seed(seed)
    return (low + (high - low) * torch.rand(*shape, generator=gen, dtype=D)).requires_grad_()


def test_smoke() -> None:
    rgb = torch.tensor([1.0, 0.5, 0.0]).view(3, 1, 1)
    assert torch.isclose(C.rgb_to_gray(rgb), torch.tensor(0.299 + 0.2935)).all()
    assert C.rgb_to_gray(np.ones((2, 3)), channel_axis=-1).tolist() == pytest.approx([1.0, 1.0])
    x = torch.tensor([0.0, 0.002, 0.18, 1.0])
    assert torch.allclose(C.srgb_decode(C.srgb_encode(x)), x, atol=1e-6)
    assert C.srgb_slope(torch.tensor([0.0, 1.0])).tolist() == pytest.approx(
        [11.14, 1.055 / 2.4], rel=1e-3
    )  # floor 1/255
    assert C.srgb_mse(torch.zeros(2, 3), torch.ones(2, 3)).item() == pytest.approx(1.0)
    assert mse_to_psnr(0.01) == pytest.approx(20.0) and mse_to_psnr(0.0) == math.inf
    assert mse_to_psnr(np.array([0.01, 0.0001])).tolist() == pytest.approx([20.0, 40.0])  # (AttributeError)
    assert mse_to_psnr(torch.tensor([0.01, 0.0])).tolist() == [pytest.approx(20.0), math.inf]
    a = torch.rand(3, 12, 12, generator=torch.Generator().manual_seed(1))
    assert M.psnr(a, a) == math.inf and M.ssim(a, a) == pytest.approx(1.0)


def test_empty_and_nan_inputs() -> None:
    assert C.srgb_encode(torch.zeros(0)).shape == (0,) and C.rgb_to_gray(torch.zeros(3, 0)).shape == (0,)
    assert C.srgb_encode(torch.tensor([float("nan")])).isnan().all()  # passed on, not clipped to a value
    assert math.isnan(mse_to_psnr(-1.0)) and mse_to_psnr(torch.tensor([-1.0, float("nan")])).isnan().all()


def test_a_batch_of_no_images_scores_empty_not_nan() -> None:
    """N = 0 images is no image to score: empty results (only images without pixels are refused)."""
    a = torch.zeros(0, 3, 4, 4)
    assert M.psnr(a, a).shape == (0,) and M.mse(a, a).shape == (0,)


REFUSALS: list[tuple[str, Callable[[], object], str]] = [
    ("gray channels", lambda: C.rgb_to_gray(torch.zeros(4, 2)), "rgb"),
    ("gray list", lambda: C.rgb_to_gray([0.1, 0.2, 0.3]), "rgb"),  # type: ignore[type-var]
    ("gray 0-d", lambda: C.rgb_to_gray(torch.tensor(1.0)), "channel_axis"),
    ("gray axis", lambda: C.rgb_to_gray(np.zeros((3, 2)), channel_axis=2), "channel_axis"),
    ("slope floor", lambda: C.srgb_slope(torch.zeros(2), floor=0.0), "floor"),
    # (3,) against (2, 3) broadcast to a wrong MSE before
    ("srgb mse shape", lambda: C.srgb_mse(torch.zeros(3), torch.zeros(2, 3)), "target"),
    # an empty batch: the mean of nothing (NaN before, a train PSNR of NaN)
    ("srgb mse no rays", lambda: C.srgb_mse(torch.zeros(0, 3), torch.zeros(0, 3)), "pred"),
    ("srgb mse no values", lambda: C.srgb_mse(torch.zeros(0), torch.zeros(0)), "pred"),
    ("psnr range 0", lambda: mse_to_psnr(0.1, 0.0), "data_range"),  # (a "math domain error" before)
    ("psnr range -1", lambda: mse_to_psnr(torch.tensor(0.1), -1.0), "data_range"),  # (10 dB before)
    (
        "psnr range nan",
        lambda: M.psnr(torch.zeros(3, 2, 2), torch.zeros(3, 2, 2), float("nan")),
        "data_range",
    ),
    ("psnr shapes", lambda: M.psnr(torch.zeros(3, 2, 2), torch.zeros(3, 2, 3)), "a"),
    ("psnr integers", lambda: M.psnr(torch.zeros(3, 2, 2, dtype=torch.uint8), torch.zeros(3, 2, 2)), "a"),
    ("psnr mask", lambda: M.psnr(torch.zeros(3, 2, 2), torch.zeros(3, 2, 2), mask=torch.ones(2, 2)), "mask"),
    ("ssim size", lambda: M.ssim(torch.zeros(3, 8, 8), torch.zeros(3, 8, 8)), "a"),
    ("psnr no pixels", lambda: M.psnr(torch.zeros(3, 0, 4), torch.zeros(3, 0, 4)), "a"),  # (NaN before)
    ("mse no channels", lambda: M.mse(torch.zeros(2, 0, 4, 4), torch.zeros(2, 0, 4, 4)), "a"),
]


test_bad_inputs_are_refused_naming_the_parameter = refusal_test(REFUSALS)


def test_gradcheck_colour() -> None:
    assert torch.autograd.gradcheck(lambda x: C.rgb_to_gray(x, channel_axis=1), (_inside(2, 3, 2, seed=2),))
    assert torch.autograd.gradcheck(C.srgb_encode, (_inside(8, seed=3),))
    low = _inside(4, seed=4, low=1e-4, high=3e-3)  # the linear segment below the knee
    assert torch.autograd.gradcheck(C.srgb_encode, (low,))
    assert torch.autograd.gradcheck(C.srgb_decode, (_inside(8, seed=5),))
    target = _inside(4, 3, seed=6).detach()
    assert torch.autograd.gradcheck(lambda p: C.srgb_mse(p, target), (_inside(4, 3, seed=7),))


def test_srgb_encode_gradient_is_finite_at_black_and_zero_outside_the_range() -> None:
    """The clamp at 1e-12 keeps the unused branch's slope finite: no NaN gradient at black."""
    x = torch.tensor([0.0, 1e-13, -0.5, 1.5], dtype=D, requires_grad=True)
    C.srgb_encode(x).sum().backward()
    assert x.grad.tolist() == pytest.approx([12.92, 12.92, 0.0, 0.0])


def test_gradcheck_psnr_and_ssim() -> None:
    mse = _inside(5, seed=8, low=1e-4, high=0.5)
    assert torch.autograd.gradcheck(lambda m: mse_to_psnr(m, 2.0), (mse,))
    a, b = _inside(1, 2, 6, 6, seed=9), _inside(1, 2, 6, 6, seed=10).detach()
    assert torch.autograd.gradcheck(lambda x: M.psnr(x, b), (a,))
    mask = torch.rand(1, 2, 6, 6, generator=torch.Generator().manual_seed(11)) < 0.5
    assert torch.autograd.gradcheck(lambda x: M.psnr(x, b, mask=mask), (a,))
    a, b = _inside(1, 1, 12, 12, seed=12), _inside(1, 1, 12, 12, seed=13).detach()
    assert torch.autograd.gradcheck(lambda x: M.ssim(x, b), (a,), fast_mode=True)  # (144 inputs)


def test_psnr_gradient_at_a_perfect_match_is_minus_inf_not_nan() -> None:
    mse = torch.tensor([0.0, 0.01], dtype=D, requires_grad=True)
    psnr = mse_to_psnr(mse)
    assert psnr[0] == math.inf and psnr[1].item() == pytest.approx(20.0)
    psnr.sum().backward()
    assert mse.grad[0] == -math.inf and mse.grad[1].item() == pytest.approx(-10 / (0.01 * math.log(10)))

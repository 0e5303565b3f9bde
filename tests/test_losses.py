"""Losses: reconstruction MSE, the differentiable interval spike loss and the paper's spike loss."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from spikenerf.camera.firing import fire
from spikenerf.train.losses import (
    mse_to_psnr,
    paper_spike_loss,
    recon_loss,
    spike_interval_loss,
    spike_prefix,
    spike_weight,
)


def _simulate(intensity: torch.Tensor, start: torch.Tensor, threshold: float) -> torch.Tensor:
    """Fire the camera model over (L, ...) intensities from ``start``; returns (L, ...) bool spikes."""
    acc, out = start.clone(), []
    for step in intensity:
        spk, acc = fire(acc, step, threshold)
        out.append(spk)
    return torch.stack(out)


def test_recon_loss_and_psnr() -> None:
    pred = torch.tensor([[0.5], [0.25]])
    target = torch.tensor([[0.5], [0.75]])
    assert recon_loss(pred, target).item() == pytest.approx(0.125)
    assert mse_to_psnr(0.01) == pytest.approx(20.0)
    assert mse_to_psnr(0.0) == float("inf")


def test_prefix_is_accumulator_change() -> None:
    gen = torch.Generator().manual_seed(0)
    inten = torch.rand(20, 7, 1, generator=gen, dtype=torch.float64)
    a0 = torch.rand(7, 1, generator=gen, dtype=torch.float64)
    acc, states = a0.clone(), [a0.clone()]
    spikes = []
    for step in inten:
        spk, acc = fire(acc, step, 1.0)
        spikes.append(spk)
        states.append(acc.clone())
    d = spike_prefix(inten, torch.stack(spikes), 1.0)
    assert torch.allclose(d, torch.stack(states) - a0, atol=1e-12)


@pytest.mark.parametrize("threshold", [1.0, 2.0])
@pytest.mark.parametrize("pairs", ["all", "window"])
def test_true_intensity_gives_zero_loss(threshold: float, pairs: str) -> None:
    gen = torch.Generator().manual_seed(1)
    inten = torch.rand(32, 200, 3, generator=gen, dtype=torch.float64)  # ≤ 1 ≤ φ
    a0 = threshold * torch.rand(200, 3, generator=gen, dtype=torch.float64)
    spikes = _simulate(inten, a0, threshold)
    assert spikes.any() and not spikes.all()
    loss = spike_interval_loss(inten, spikes, threshold, pairs=pairs)  # type: ignore[arg-type]
    assert loss.item() <= 1e-20
    assert spike_interval_loss(inten * 1.5 + 0.1, spikes, threshold, pairs=pairs).item() > 1e-4  # type: ignore[arg-type]


def test_window_bounds_are_exact() -> None:
    """No spike in L steps: the feasible set is ΣI < φ, and the penalty is ((ΣI − φ)/(φL))² beyond it."""
    length, phi = 10, 1.0
    silent = torch.zeros(length, 1, 1)
    just_in = torch.full((length, 1, 1), (phi - 1e-6) / length, dtype=torch.float64)
    assert spike_interval_loss(just_in, silent, phi, pairs="window").item() == 0.0
    out = torch.full((length, 1, 1), (phi + 1e-3) / length, dtype=torch.float64)
    expected = (1e-3 / (phi * length)) ** 2
    assert spike_interval_loss(out, silent, phi, pairs="window").item() == pytest.approx(expected, rel=1e-6)
    # N spikes in L steps: ΣI must exceed φ(N − 1)
    n = 4
    spikes = torch.zeros(length, 1, 1)
    spikes[::3] = 1  # steps 0, 3, 6, 9
    low = torch.full((length, 1, 1), phi * (n - 1) / length - 1e-4, dtype=torch.float64)
    got = spike_interval_loss(low, spikes, phi, pairs="window").item()
    assert got == pytest.approx((1e-4 * length / (phi * length)) ** 2, rel=1e-6)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    length=st.integers(2, 24),
    scale=st.floats(0.5, 1.5),
)
def test_zero_loss_iff_some_start_reproduces_the_spikes(seed: int, length: int, scale: float) -> None:
    """The loss vanishes exactly when some A0 in [0, φ) makes the camera fire the recorded spikes."""
    rng = np.random.default_rng(seed)
    true = torch.tensor(rng.uniform(0, 1, (length, 1, 1)))
    spikes = _simulate(true, torch.tensor(rng.uniform(0, 1, (1, 1))), 1.0)
    guess = (true * scale + torch.tensor(rng.normal(0, 0.05, (length, 1, 1)))).clamp(0, 1)
    loss = spike_interval_loss(guess, spikes, 1.0).item()
    d = spike_prefix(guess, spikes, 1.0)[:, 0, 0]
    lo, hi = max(0.0, float((-d).max())), min(1.0, float((1.0 - d).min()))  # A0 + D_m ∈ [0, 1) ∀m
    start = torch.full((1, 1), 0.5 * (lo + hi), dtype=guess.dtype)  # the middle of the feasible A0 interval
    reproduces = lo < hi and torch.equal(_simulate(guess, start, 1.0), spikes)
    assert (loss == 0.0) == reproduces or abs(hi - lo) < 1e-9


@pytest.mark.parametrize(("theta0", "sign"), [(0.2, +1.0), (0.6, -1.0)])
def test_gradient_moves_a_constant_intensity_towards_the_true_rate(theta0: float, sign: float) -> None:
    true_rate, length = 0.37, 32
    spikes = _simulate(
        torch.full((length, 16, 1), true_rate),
        torch.rand(16, 1, generator=torch.Generator().manual_seed(3)),
        1.0,
    )
    theta = torch.nn.Parameter(torch.tensor(theta0))
    loss = spike_interval_loss(theta.expand(length, 16, 1), spikes, 1.0)
    loss.backward()
    assert loss.item() > 0
    assert theta.grad is not None and theta.grad.item() != 0.0
    assert np.sign(-theta.grad.item()) == sign  # a descent step moves θ towards the true rate
    # gradient descent converges into the feasible set around the true rate
    opt = torch.optim.Adam([theta], lr=0.01)
    for _ in range(200):
        opt.zero_grad()
        spike_interval_loss(theta.expand(length, 16, 1), spikes, 1.0).backward()
        opt.step()
    assert abs(theta.item() - true_rate) < 1.0 / length


def test_unbounded_intensity_keeps_only_exact_bounds() -> None:
    """With φ below the brightest intensity the camera saturates; the true intensity still costs nothing."""
    gen = torch.Generator().manual_seed(4)
    inten = torch.rand(24, 50, 1, generator=gen, dtype=torch.float64)
    spikes = _simulate(inten, torch.zeros(50, 1, dtype=torch.float64), 0.4)
    assert spike_interval_loss(inten, spikes, 0.4, max_intensity=1.0).item() <= 1e-20
    assert spike_interval_loss(inten * 0.3, spikes, 0.4, max_intensity=1.0).item() > 0


def test_a_window_after_saturation_does_not_assume_an_empty_start() -> None:
    """After the pixel saturates its accumulator may hold φ or more when a window starts, so the first
    bound of a window is unknown even where the step before it fired; the true intensity costs nothing."""
    gen = torch.Generator().manual_seed(4)
    inten = torch.rand(48, 50, 1, generator=gen, dtype=torch.float64)
    inten[:10] = 1.0  # 2.5 φ a step: the accumulator climbs far above φ
    spikes = _simulate(inten, torch.zeros(50, 1, dtype=torch.float64), 0.4)
    assert spike_interval_loss(inten[12:], spikes[12:], 0.4, max_intensity=1.0).item() <= 1e-20


def test_paper_spike_loss_discards_its_warmup_steps() -> None:
    recorded = torch.zeros(8, 5, 1)
    recorded[:2] = 1.0  # the prediction (no light: no spike) misses only the first two steps
    silent, start = torch.zeros(8, 5, 1), torch.zeros(5, 1)
    assert paper_spike_loss(silent, recorded, 1.0, start, warmup=2).item() == 0.0
    assert paper_spike_loss(silent, recorded, 1.0, start, warmup=0).item() == pytest.approx(2 / 8)
    assert paper_spike_loss(silent, recorded, 1.0, start, warmup=1).item() == pytest.approx(1 / 7)


def test_paper_spike_loss_has_no_gradient() -> None:
    gen = torch.Generator().manual_seed(5)
    true = torch.rand(16, 30, 1, generator=gen)
    a0 = torch.rand(30, 1, generator=gen)
    spikes = _simulate(true, a0, 1.0)
    param = torch.nn.Parameter(true.clone())
    loss = paper_spike_loss(param, spikes, 1.0, a0, warmup=0)
    assert loss.item() == 0.0 and not loss.requires_grad
    wrong = paper_spike_loss(param * 0.2, spikes, 1.0, a0, warmup=2)
    assert wrong.item() > 0 and not wrong.requires_grad


def test_spike_weight_schedule() -> None:
    assert spike_weight(0, 0.5, warmup_iters=10, ramp_iters=10) == 0.0
    assert spike_weight(9, 0.5, 10, 10) == 0.0
    assert spike_weight(10, 0.5, 10, 10) == pytest.approx(0.05)
    assert spike_weight(19, 0.5, 10, 10) == pytest.approx(0.5)
    assert spike_weight(1000, 0.5, 10, 10) == pytest.approx(0.5)
    assert spike_weight(5, 0.5, 0, 0) == 0.5
    assert spike_weight(5, 0.0, 0, 0) == 0.0


def test_losses_refuse_mismatched_shapes_and_a_bad_threshold_naming_the_parameter() -> None:
    """A (N, 1) prediction against an (N,) target broadcast to (N, N) (4.0 for equal values) and spikes
    without the channel axis broadcast against the intensity; φ ≤ 0 gave NaN or a meaningless number."""
    from spikenerf.core.errors import InputError
    from spikenerf.train.losses import window_mean_loss

    with pytest.raises(
        InputError, match=r"target must have the shape of pred, \(5, 1\), found \(5,\)"
    ) as err:
        recon_loss(torch.arange(5.0)[:, None], torch.arange(5.0))
    assert err.value.params == ("target",)
    intensity = torch.full((8, 8, 1), 0.5)
    spikes = torch.zeros(8, 8, dtype=torch.bool)
    spikes[1::2] = True
    with pytest.raises(InputError, match="spikes must have the shape of intensity") as err:
        spike_interval_loss(intensity, spikes, 1.0)
    assert err.value.params == ("spikes",)
    for threshold in (0.0, -1.0, float("nan"), "1"):
        with pytest.raises(InputError, match="threshold φ must be a finite number > 0") as err:
            spike_interval_loss(intensity, spikes[..., None], threshold)  # type: ignore[arg-type]
        assert err.value.params == ("threshold",)
    with pytest.raises(InputError, match="pairs must be 'all' or 'window'"):
        spike_interval_loss(intensity, spikes[..., None], 1.0, pairs="some")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="band must be"):
        window_mean_loss(torch.zeros(4, 2, 3), torch.zeros(4, 3), torch.zeros(4))
    with pytest.raises(InputError, match="spikes must have the shape"):
        paper_spike_loss(intensity, spikes, 1.0, torch.zeros(8, 1))


def test_the_spike_losses_take_a_numpy_stream_as_read_dat_gives() -> None:
    intensity = torch.full((8, 8, 1), 0.5)
    spikes = np.zeros((8, 8, 1), np.uint8)
    spikes[1::2] = 1
    torch_spikes = torch.from_numpy(spikes)
    assert spike_interval_loss(intensity, spikes, 1.0) == spike_interval_loss(intensity, torch_spikes, 1.0)
    assert paper_spike_loss(intensity, spikes, 1.0, torch.zeros(8, 1)) == paper_spike_loss(
        intensity, torch_spikes, 1.0, torch.zeros(8, 1)
    )

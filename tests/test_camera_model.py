"""The spike camera model: conservation, rates, colour modes, warm-up, backends, noise, input validation."""

from __future__ import annotations

import dataclasses
import math
import tracemalloc

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from spikenerf.camera.bayer import bayer_channel_index, bayer_mosaic
from spikenerf.camera.firing import fire, fire_
from spikenerf.camera.model import CameraConfig, SpikeCamera
from spikenerf.camera.noise import RealisticNoise
from spikenerf.camera.simulation import simulate, simulate_iter
from spikenerf.core.color import rgb_to_gray
from spikenerf.core.errors import InputError

EPS32 = float(np.finfo(np.float32).eps)
#: Torch devices to check against numpy: CPU always, CUDA where present (the CUDA kernel is torch-only).
DEVICES = ["cpu", *(["cuda"] if torch.cuda.is_available() else [])]
#: Realistic parameters with every noise source off; tests switch one on at a time.
QUIET = RealisticNoise(
    dark_mean=0.0,
    dark_std=0.0,
    threshold_std=0.0,
    capacitance_std=0.0,
    prnu_std=0.0,
    jitter_std=0.0,
    photons_per_white=math.inf,
    readout_delay=0.0,
)


def _np(x) -> np.ndarray:
    return x.cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def _mode_intensity(frame: np.ndarray, color: str) -> np.ndarray:
    """What the camera integrates for one (3, H, W) float32 frame, in float64."""
    if color == "gray":
        return rgb_to_gray(frame).astype(np.float64)
    if color == "bayer":
        return bayer_mosaic(frame).astype(np.float64)
    return frame.astype(np.float64)


# --- the ideal model ----------------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(
    h=st.integers(1, 7),
    w=st.integers(1, 7),
    steps=st.integers(1, 60),
    scale=st.floats(0.0, 3.0),
    threshold=st.sampled_from([0.3, 1.0, 1.7]),
    color=st.sampled_from(["gray", "rgb", "bayer"]),
    seed=st.integers(0, 2**32 - 1),
    torch_backend=st.booleans(),
)
def test_ideal_conserves_charge(h, w, steps, scale, threshold, color, seed, torch_backend) -> None:
    """φ·(spike count) + final accumulator − initial accumulator = Σ intensity, per pixel."""
    rng = np.random.default_rng(seed)
    frames = (rng.random((steps, 3, h, w)) * scale).astype(np.float32)
    cam = SpikeCamera(
        h, w, CameraConfig(threshold=threshold, color=color, seed=seed), "cpu" if torch_backend else None
    )
    a0 = _np(cam.initial_accumulator).astype(np.float64)
    assert np.all((a0 >= 0) & (a0 < threshold))
    counts = sum(_np(cam.step(f)).astype(np.int64) for f in frames)
    total = sum(_mode_intensity(f, color) for f in frames)
    lhs = threshold * counts + _np(cam.accumulator).astype(np.float64) - a0
    atol = 8 * steps * EPS32 * (threshold + total.max(initial=0.0)) + 1e-6
    np.testing.assert_allclose(lhs, total, rtol=0, atol=atol)
    assert cam.steps == steps


@pytest.mark.parametrize("c", [0.0, 0.013, 0.25, 0.5, 0.77, 0.999])
@pytest.mark.parametrize("threshold", [1.0, 2.5])
def test_constant_intensity_fires_at_rate_c_over_phi(c: float, threshold: float) -> None:
    steps = 2000
    spikes = simulate(
        [np.full((5, 6), c * threshold, np.float32)] * steps, 5, 6, CameraConfig(threshold=threshold)
    )
    rate = spikes.mean(axis=0)
    assert np.all(np.abs(rate - c) <= 1.0 / steps + 1e-9)


def test_at_most_one_spike_per_step_and_saturation() -> None:
    cam = SpikeCamera(3, 3)
    for _ in range(10):
        assert cam.step(np.full((3, 3), 2.5)).all()  # bool output: at most one spike per step
    assert np.all(cam.accumulator > 10)  # the excess stays in the accumulator


@settings(max_examples=30, deadline=None)
@given(
    shape=st.sampled_from([(4,), (2, 3), (3, 2, 5)]),
    threshold=st.sampled_from([0.1, 0.3, 1.0, 7.0, "array"]),
    seed=st.integers(0, 10_000),
    torch_backend=st.booleans(),
)
def test_in_place_fire_matches_fire_bit_for_bit(shape, threshold, seed, torch_backend) -> None:
    rng = np.random.default_rng(seed)
    acc = (rng.random(shape) * 2).astype(np.float32)
    inten = (rng.random(shape) * 1.5).astype(np.float32)
    thr = (0.2 + rng.random(shape)).astype(np.float32) if threshold == "array" else threshold
    conv = torch.from_numpy if torch_backend else np.asarray
    ref_spikes, ref_acc = fire(conv(acc.copy()), conv(inten), conv(thr) if threshold == "array" else thr)
    a, spikes = conv(acc.copy()), conv(np.empty(shape, bool))
    fire_(
        a, conv(inten), conv(thr) if threshold == "array" else thr, spikes, conv(np.empty(shape, np.float32))
    )
    np.testing.assert_array_equal(_np(spikes), _np(ref_spikes))
    np.testing.assert_array_equal(_np(a).view(np.uint32), _np(ref_acc).view(np.uint32))


@pytest.mark.parametrize("device", [None, *DEVICES])
def test_spike_fires_when_the_accumulator_reaches_the_threshold_exactly(device: str | None) -> None:
    def conv(x: np.ndarray):
        return x if device is None else torch.from_numpy(x).to(device)

    acc = conv(np.array([0.5, 0.25, 0.75], np.float32))
    spikes = conv(np.empty(3, bool))
    fire_(acc, conv(np.array([0.5, 0.5, 0.5], np.float32)), 1.0, spikes, conv(np.empty(3, np.float32)))
    np.testing.assert_array_equal(_np(spikes), [True, False, True])
    np.testing.assert_array_equal(_np(acc), [0.0, 0.75, 0.25])
    ref, _ = fire(conv(np.array([0.5], np.float32)), conv(np.array([0.5], np.float32)), 1.0)
    assert bool(ref[0])


@pytest.mark.parametrize("noise", ["ideal", "realistic"])
def test_deterministic_under_seed_and_different_across_seeds(noise: str) -> None:
    frames = np.random.default_rng(1).random((100, 3, 9, 11)).astype(np.float32) * 0.6

    def run(seed: int) -> np.ndarray:
        return simulate(frames, 9, 11, CameraConfig(noise=noise, seed=seed))

    np.testing.assert_array_equal(run(3), run(3))
    assert not np.array_equal(run(3), run(4))


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("color", ["gray", "rgb", "bayer"])
@pytest.mark.parametrize("threshold", [1.0, 0.3])
def test_numpy_and_torch_give_identical_ideal_spikes(color: str, threshold: float, device: str) -> None:
    rng = np.random.default_rng(7)
    frames = rng.random((120, 3, 10, 14)) * 0.8  # float64 input, converted to float32 on both
    config = CameraConfig(threshold=threshold, color=color, seed=11, warmup=5)
    a = simulate(frames, 10, 14, config)
    b = simulate(frames, 10, 14, config, device=device)
    c = simulate((torch.from_numpy(f) for f in frames), 10, 14, config, device=torch.device(device))
    assert a.dtype == b.dtype == c.dtype == np.bool_
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
    subframes = rng.random((40, 4, 3, 10, 14)).astype(np.float32)  # sub-frame averaging, both backends
    np.testing.assert_array_equal(
        simulate(subframes, 10, 14, config), simulate(subframes, 10, 14, config, "cpu")
    )


def test_rgb_mode_gives_three_independent_streams() -> None:
    rng = np.random.default_rng(2)
    frames = rng.random((80, 3, 6, 7)).astype(np.float32)
    cam = SpikeCamera(6, 7, CameraConfig(color="rgb", seed=5))
    a0 = cam.initial_accumulator
    spikes = np.stack([cam.step(f) for f in frames])
    assert spikes.shape == (80, 3, 6, 7)
    for k in range(3):  # each channel is the ideal model run on that channel alone
        acc = a0[k].copy()
        for t, f in enumerate(frames):
            ref, acc = fire(acc, f[k], 1.0)
            np.testing.assert_array_equal(spikes[t, k], ref)
    changed = frames.copy()
    changed[:, 0] = rng.random((80, 6, 7))
    other = simulate(changed, 6, 7, CameraConfig(color="rgb", seed=5))
    np.testing.assert_array_equal(other[:, 1:], spikes[:, 1:])  # changing R leaves G and B untouched
    assert not np.array_equal(other[:, 0], spikes[:, 0])


@pytest.mark.parametrize("channel", [0, 1, 2])
def test_bayer_pure_colour_fires_only_on_its_sites(channel: int) -> None:
    h, w = 6, 8
    scene = np.zeros((3, h, w), np.float32)
    scene[channel] = 0.6
    spikes = simulate([scene] * 30, h, w, CameraConfig(color="bayer"))
    fired = spikes.any(axis=0)
    sites = bayer_channel_index(h, w) == channel
    assert fired[sites].all() and not fired[~sites].any()


def test_bayer_layout_and_mosaic() -> None:
    np.testing.assert_array_equal(bayer_channel_index(2, 2), [[0, 1], [1, 2]])
    idx = bayer_channel_index(5, 7)
    assert idx.shape == (5, 7) and idx[4, 6] == 0 and idx[3, 5] == 2 and idx[3, 6] == 1
    rgb = np.random.default_rng(0).random((3, 5, 7)).astype(np.float32)
    expected = np.take_along_axis(rgb, idx[None], axis=0)[0]
    np.testing.assert_array_equal(bayer_mosaic(rgb), expected)
    np.testing.assert_array_equal(bayer_mosaic(torch.from_numpy(rgb)).numpy(), expected)
    with pytest.raises(InputError):
        bayer_mosaic(rgb[:2])


def test_warmup_steps_are_simulated_then_discarded() -> None:
    frames = list(np.random.default_rng(4).random((30, 5, 5)).astype(np.float32) * 0.4)
    warm = simulate(frames, 5, 5, CameraConfig(warmup=7))
    manual = simulate([frames[0]] * 7 + frames, 5, 5, CameraConfig())
    assert warm.shape == (30, 5, 5)
    np.testing.assert_array_equal(warm, manual[7:])
    assert not np.array_equal(warm, simulate(frames, 5, 5, CameraConfig()))
    cam = SpikeCamera(5, 5, CameraConfig(warmup=7))
    for f in frames[:3]:
        cam.step(f)
    assert cam.steps == 3


def test_input_forms() -> None:
    rng = np.random.default_rng(9)
    rgb = rng.random((3, 4, 5)).astype(np.float32)
    gray = rgb_to_gray(rgb)
    outs = {}
    for name, frame in {
        "rgb": rgb,
        "gray": gray,
        "sub": np.stack([gray] * 1),
        "sub1": gray[None, None],
    }.items():
        outs[name] = simulate([frame] * 20, 4, 5)
    for name in ("gray", "sub", "sub1"):
        np.testing.assert_array_equal(outs[name], outs["rgb"])
    sub = rng.random((6, 2, 4, 5)).astype(np.float32)  # (S, H, W) sub-frames: conservation of their mean
    cam = SpikeCamera(4, 5)
    counts = sum(cam.step(s).astype(np.int64) for s in sub)
    lhs = counts + cam.accumulator.astype(np.float64) - cam.initial_accumulator
    np.testing.assert_allclose(lhs, sub.astype(np.float64).mean(axis=1).sum(axis=0), atol=1e-5)
    assert simulate([], 4, 5).shape == (0, 4, 5)
    assert simulate([], 4, 5, CameraConfig(color="rgb"), device="cpu").shape == (0, 3, 4, 5)
    gen = simulate((f for f in [gray] * 300), 4, 5, progress=True)  # no len(): chunked path
    np.testing.assert_array_equal(gen, simulate([gray] * 300, 4, 5))


def test_streaming_memory_does_not_grow_with_length() -> None:
    def peak(steps: int) -> int:
        frames = (np.full((32, 32), 0.3, np.float32) for _ in range(steps))
        tracemalloc.start()
        for _ in simulate_iter(frames, 32, 32, CameraConfig(noise="realistic")):
            pass
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        return top

    short, long = peak(20), peak(2000)
    assert long < short + 16_384, (short, long)


# --- realistic noise ----------------------------------------------------------------------------------------


def _rates(scene: float, steps: int, params: RealisticNoise | None, noise: str = "realistic", seed: int = 0):
    frames = [np.full((24, 24), scene, np.float32)] * steps
    return simulate(frames, 24, 24, CameraConfig(noise=noise, seed=seed), noise_params=params).mean(axis=0)


def test_published_constants_are_converted_into_camera_units() -> None:
    p = RealisticNoise()
    assert p.dark_mean == pytest.approx(0.4442 / (20 * 4.348 * 1.0924))
    assert p.dark_mean == pytest.approx(0.004676, abs=1e-6)
    assert p.dark_std == pytest.approx(0.001822, abs=1e-6)
    assert p.threshold_std == pytest.approx(0.0497 / 1.0924)
    assert p.prnu_std == pytest.approx(0.058, abs=5e-4)
    assert p.jitter_std == pytest.approx(0.00582, abs=1e-5)
    assert p.readout_delay == pytest.approx(0.004)


def test_dark_current_makes_a_black_scene_fire() -> None:
    assert _rates(0.0, 2000, None, noise="ideal").max() == 0.0
    rate = _rates(0.0, 2000, None)
    assert rate.mean() == pytest.approx(RealisticNoise().dark_mean, rel=0.1)
    assert (rate > 0).mean() > 0.9


def test_prnu_and_threshold_patterns_spread_rates() -> None:
    ideal = _rates(0.5, 1000, None, noise="ideal")
    assert ideal.std() < 1e-3
    prnu = _rates(0.5, 1000, dataclasses.replace(QUIET, prnu_std=0.058))
    assert prnu.std() / prnu.mean() == pytest.approx(0.058, rel=0.2)
    full = _rates(0.5, 1000, None)
    assert full.std() > 20 * ideal.std()


def test_fixed_patterns_are_drawn_once_from_the_seed() -> None:
    p = RealisticNoise()
    a, b, c = (p.draw_patterns((50, 60), 1.0, s) for s in (1, 1, 2))
    for f in ("gain", "dark", "threshold", "jitter"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
        assert not np.array_equal(getattr(a, f), getattr(c, f))
    assert a.threshold.mean() == pytest.approx(1.0, abs=0.01) and a.gain.mean() == pytest.approx(
        1.0, abs=0.01
    )
    np_cam = SpikeCamera(8, 8, CameraConfig(noise="realistic", seed=3))
    t_cam = SpikeCamera(8, 8, CameraConfig(noise="realistic", seed=3), device="cpu")
    np.testing.assert_array_equal(np_cam._noise._threshold, t_cam._noise._threshold.numpy())


def _intervals(spikes: np.ndarray) -> np.ndarray:
    return np.concatenate([np.diff(np.flatnonzero(p)) for p in spikes.reshape(len(spikes), -1).T])


@pytest.mark.parametrize(
    "change", [{"photons_per_white": 200.0}, {"jitter_std": 0.05}], ids=["shot-noise", "jitter"]
)
def test_temporal_noise_makes_intervals_irregular(change: dict) -> None:
    frames = [np.full((8, 8), 0.25, np.float32)] * 400
    ideal = simulate(frames, 8, 8)
    noisy = simulate(
        frames, 8, 8, CameraConfig(noise="realistic"), noise_params=dataclasses.replace(QUIET, **change)
    )
    assert np.all(_intervals(ideal) == 4)
    assert _intervals(noisy).std() > 0.3
    assert noisy.mean() == pytest.approx(0.25, abs=0.02)  # zero-mean noise keeps the rate


def test_readout_delay_adds_refractory_steps() -> None:
    white = _rates(1.0, 1000, None, noise="ideal")
    assert white.min() == 1.0
    for delay, scene, rate in [(1.0, 1.0, 1 / 2), (1.0, 2.5, 1 / 2), (2.0, 1.0, 1 / 3), (2.0, 4.0, 1 / 3)]:
        delayed = _rates(scene, 1000, dataclasses.replace(QUIET, readout_delay=delay))
        np.testing.assert_allclose(
            delayed, rate, atol=1.0 / 1000
        )  # whole dead steps neither integrate nor fire
    small = _rates(0.9, 1000, dataclasses.replace(QUIET, readout_delay=0.5))
    assert small.mean() < 0.9 - 0.1


@pytest.mark.parametrize("device", DEVICES)
def test_realistic_torch_backend_is_deterministic_and_matches_numpy_statistics(device: str) -> None:
    frames = [np.full((3, 24, 24), 0.01, np.float32)] * 1500  # nearly black: mostly dark current
    config = CameraConfig(noise="realistic", color="rgb")
    a = simulate(frames, 24, 24, config, device=device)
    np.testing.assert_array_equal(a, simulate(frames, 24, 24, config, device=device))
    assert a.shape == (1500, 3, 24, 24)
    reference = simulate(frames, 24, 24, config)
    if device == "cpu":  # same generator and the same float32 operations
        np.testing.assert_array_equal(a, reference)
    assert a.mean() == pytest.approx(reference.mean(), rel=0.1)


# --- bad input ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs",
    [
        {"threshold": 0},
        {"threshold": -1.0},
        {"threshold": float("nan")},
        {"threshold": float("inf")},
        {"threshold": "1"},
        {"threshold": 1e-60},
        {"color": "grey"},
        {"noise": "noisy"},
        {"seed": -1},
        {"seed": 1.5},
        {"warmup": -2},
        {"warmup": True},
    ],
)
def test_bad_config_raises_input_error(kwargs: dict) -> None:
    field = next(iter(kwargs))
    with pytest.raises(InputError, match=field):
        CameraConfig(**kwargs)


def test_bad_camera_input_raises_input_error() -> None:
    with pytest.raises(InputError, match="height"):
        SpikeCamera(0, 4)
    with pytest.raises(InputError, match="device"):
        SpikeCamera(4, 4, device="tpu")
    with pytest.raises(InputError, match="prnu_std"):
        RealisticNoise(prnu_std=-0.1)
    with pytest.raises(InputError, match="photons_per_white"):
        RealisticNoise(photons_per_white=0.0)
    cam = SpikeCamera(4, 5, CameraConfig(color="rgb"))
    with pytest.raises(InputError, match=r"4×5.*\(4, 6\)"):
        cam.step(np.zeros((4, 6)))
    with pytest.raises(InputError, match="needs RGB"):
        cam.step(np.zeros((4, 5)))
    with pytest.raises(InputError, match="sub-frames"):
        cam.step(np.zeros((2, 2, 4, 5)))

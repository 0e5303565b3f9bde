"""TFP, TFI and spike masks: recovery of constant scenes, edge rules, naive references, range reading."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from spikenerf.camera.firing import fire
from spikenerf.camera.masks import spike_masks
from spikenerf.camera.reconstruct import check_window, reconstruct_frames, tfi, tfp, window_sum
from spikenerf.core.errors import InputError

small_streams = arrays(
    np.uint8,
    st.tuples(st.integers(1, 30), st.integers(1, 3), st.integers(1, 3)),
    elements=st.integers(0, 1),
)


def _simulate(intensity: np.ndarray, frames: int, start: np.ndarray | None = None) -> np.ndarray:
    """Spikes (T, H, W) of a static scene from the ideal integrate-and-fire pixel, float64 accumulator."""
    acc = np.zeros_like(intensity) if start is None else start.copy()
    out = []
    for _ in range(frames):
        spikes, acc = fire(acc, intensity, 1.0)
        out.append(spikes)
    return np.stack(out)


def _naive_tfi(s: np.ndarray) -> np.ndarray:
    """The documented TFI rule, one pixel and one frame at a time (threshold 1)."""
    total = s.shape[0]
    out = np.zeros(s.shape, np.float64)
    for idx in np.ndindex(*s.shape[1:]):
        times = [t for t in range(total) if s[(t, *idx)]]
        if not times:
            continue
        gaps = np.diff(times)
        for k in range(total):
            before = [t for t in times if t < k]
            after = [t for t in times if t >= k]
            if not before:
                delta = max(times[0] + 1, gaps[0] if len(gaps) else 0)
            elif not after:
                delta = max(total - times[-1], gaps[-1] if len(gaps) else 0)
            else:
                delta = after[0] - before[-1]
            out[(k, *idx)] = 1.0 / delta
    return out


def test_tfp_recovers_a_constant_scene() -> None:
    rng = np.random.default_rng(0)
    intensity = rng.uniform(0.0, 1.0, (6, 7))
    spikes = _simulate(intensity, 200, start=rng.uniform(0.0, 1.0, (6, 7)))
    window = 41
    est = tfp(spikes, window=window)
    assert est.dtype == np.float32 and est.shape == spikes.shape
    err = np.abs(est - intensity)
    # an ideal pixel fires floor or ceil(m·I) times in any m consecutive steps → |error| < 1/m
    assert err[20:-20].max() <= 1.0 / window + 1e-6
    used = np.minimum(np.arange(200) + 21, 200) - np.maximum(np.arange(200) - 20, 0)
    assert np.all(err.max(axis=(1, 2)) <= 1.0 / used + 1e-6)
    assert err[20:-20].max() > 0.25 / window  # the bound is tight, not vacuous


def test_tfp_threshold_scales_units() -> None:
    spikes = _simulate(np.full((2, 8), 0.5), 50)
    np.testing.assert_allclose(tfp(spikes, 5, threshold=256.0), 256.0 * tfp(spikes, 5), rtol=1e-6)


@settings(max_examples=60, deadline=None)
@given(spikes=small_streams, half=st.integers(0, 6))
def test_tfp_matches_naive_window_mean(spikes: np.ndarray, half: int) -> None:
    total = spikes.shape[0]
    expect = np.stack(
        [spikes[max(0, k - half) : min(total, k + half + 1)].mean(axis=0) for k in range(total)]
    )
    np.testing.assert_allclose(tfp(spikes, 2 * half + 1), expect, rtol=1e-6, atol=1e-7)
    _, used = window_sum(spikes, half)
    np.testing.assert_array_equal(used, [min(total, k + half + 1) - max(0, k - half) for k in range(total)])


@pytest.mark.parametrize("window", [255, 257, 601])  # uint8 and uint16 running counters, longer than T
def test_tfp_long_windows_match_naive(window: int) -> None:
    spikes = np.random.default_rng(4).random((500, 2, 2)) < 0.9
    spikes[:, 0, 0] = True  # a pixel that always fires: counts reach the full window
    half = (window - 1) // 2
    expect = np.stack([spikes[max(0, k - half) : k + half + 1].mean(axis=0) for k in range(500)])
    np.testing.assert_allclose(tfp(spikes, window), expect, rtol=1e-6)
    counts, _ = window_sum(spikes, half)
    assert counts.dtype == np.int32 and counts.max() == min(window, 500)


def test_tfp_rgb_torch_and_frame_selection() -> None:
    rng = np.random.default_rng(1)
    rgb = (rng.random((40, 3, 4, 5)) < 0.3).astype(np.uint8)
    full = tfp(rgb, 9)
    assert full.shape == (40, 3, 4, 5)
    for c in range(3):
        np.testing.assert_array_equal(full[:, c], tfp(rgb[:, c], 9))
    np.testing.assert_array_equal(tfp(rgb, 9, frames=slice(5, 30, 4)), full[5:30:4])
    as_torch = tfp(torch.from_numpy(rgb).bool(), 9)
    assert isinstance(as_torch, torch.Tensor) and as_torch.dtype == torch.float32
    np.testing.assert_array_equal(as_torch.numpy(), full)


@pytest.mark.parametrize("window", [0, 2, 40, -3, 4.0])
def test_bad_window_is_an_input_error(window) -> None:
    with pytest.raises(InputError, match="odd"):
        tfp(np.zeros((5, 2, 2), np.uint8), window=window)


def test_check_window_is_the_one_window_rule() -> None:
    """Every window of the toolkit (TFP, train's targets, the learned network's, an import's) is checked by
    ``check_window``: an odd integer ≥ its least, named by its parameter (and file)."""
    assert check_window(np.int64(5)) == 5 and check_window(3, least=3) == 3
    with pytest.raises(
        InputError, match=r"^cfg.yaml: imported.window must be an odd number of steps ≥ 3"
    ) as e:
        check_window(1, "imported.window", least=3, path=Path("cfg.yaml"))
    assert e.value.params == ("imported.window",)
    for bad in (2, 5.0, True, "5"):
        with pytest.raises(InputError, match=r"window must be an odd number of steps ≥ 1"):
            check_window(bad)


@pytest.mark.parametrize("phi", [0.0, -1.0, float("nan")])
def test_bad_threshold_is_an_input_error(phi: float) -> None:
    with pytest.raises(InputError, match="threshold"):
        tfp(np.zeros((5, 2, 2), np.uint8), threshold=phi)
    with pytest.raises(InputError, match="threshold"):
        tfi(np.zeros((5, 2, 2), np.uint8), threshold=phi)


@pytest.mark.parametrize("period", [1, 2, 3, 5, 7, 16])
def test_tfi_periodic_stream_is_exact_everywhere(period: int) -> None:
    total = 60
    spikes = np.zeros((total, 1, period), np.uint8)
    for offset in range(period):  # every phase, so the stream edges fall everywhere in an interval
        spikes[offset::period, 0, offset] = 1
    np.testing.assert_array_equal(tfi(spikes), np.full(spikes.shape, 1.0 / period, np.float32))


def test_tfi_recovers_constant_intensities_from_the_camera() -> None:
    exact = np.array([[1.0, 0.5, 0.25, 0.125]])  # binary fractions: no rounding in the accumulator
    np.testing.assert_array_equal(tfi(_simulate(exact, 64)), np.broadcast_to(exact, (64, 1, 4)))
    n = np.array([3.0, 5.0, 7.0, 10.0])
    est = tfi(_simulate(1.0 / n[None], 200))[:, 0]
    np.testing.assert_allclose(np.median(est, axis=0), 1.0 / n, rtol=1e-6)
    assert np.all(est >= 1.0 / (n + 1) - 1e-7) and np.all(est <= 1.0 / (n - 1) + 1e-7)


def test_tfi_edge_rules() -> None:
    def one(times: list[int], total: int = 10) -> np.ndarray:
        s = np.zeros((total, 1, 1), np.uint8)
        s[times, 0, 0] = 1
        return tfi(s)[:, 0, 0]

    np.testing.assert_allclose(one([3, 7]), np.full(10, 1 / 4))  # edges use the neighbouring interval
    np.testing.assert_allclose(one([2]), [1 / 3] * 3 + [1 / 8] * 7)  # one spike: edge-bounded intervals
    np.testing.assert_allclose(
        one([1, 2, 9]), [1 / 2, 1 / 2, 1, *[1 / 7] * 7]
    )  # edge bound 2 beats the first gap 1
    np.testing.assert_array_equal(one([]), np.zeros(10))  # never fires → 0
    np.testing.assert_allclose(one(list(range(10))), np.ones(10))


@settings(max_examples=60, deadline=None)
@given(spikes=small_streams)
def test_tfi_matches_naive_rule(spikes: np.ndarray) -> None:
    np.testing.assert_allclose(tfi(spikes), _naive_tfi(spikes), rtol=1e-6)
    np.testing.assert_allclose(tfi(torch.from_numpy(spikes)).numpy(), _naive_tfi(spikes), rtol=1e-6)


@settings(max_examples=60, deadline=None)
@given(spikes=small_streams, n=st.integers(0, 5))
def test_masks_match_naive_or(spikes: np.ndarray, n: int) -> None:
    total = spikes.shape[0]
    expect = np.stack([spikes[max(0, k - n) : min(total, k + n + 1)].any(axis=0) for k in range(total)])
    got = spike_masks(spikes, n)
    assert got.dtype == np.bool_
    np.testing.assert_array_equal(got, expect)


def test_masks_window_is_exactly_2n_plus_1() -> None:
    spikes = np.zeros((20, 1, 1), np.uint8)
    spikes[10] = 1
    np.testing.assert_array_equal(np.flatnonzero(spike_masks(spikes, 3)[:, 0, 0]), np.arange(7, 14))
    np.testing.assert_array_equal(spike_masks(spikes, 0), spikes.astype(bool))
    as_torch = spike_masks(torch.from_numpy(spikes), 3)
    assert isinstance(as_torch, torch.Tensor) and as_torch.dtype == torch.bool
    with pytest.raises(InputError, match="n must be an integer"):
        spike_masks(spikes, -1)


@settings(max_examples=40, deadline=None)
@given(data=st.data(), method=st.sampled_from(["tfp", "tfi"]))
def test_reconstruct_frames_equals_the_full_stream(data, method: str) -> None:
    total = data.draw(st.integers(1, 400))
    rate = data.draw(st.sampled_from([0.0, 0.005, 0.05, 0.5]))
    spikes = np.random.default_rng(data.draw(st.integers(0, 99))).random((total, 2, 3)) < rate
    start = data.draw(st.integers(0, total - 1))
    stop = data.draw(st.integers(start + 1, total))
    reads: list[tuple[int, int]] = []

    def read(a: int, b: int) -> np.ndarray:
        reads.append((a, b))
        return spikes[a:b]

    got = reconstruct_frames(read, total, start, stop, method, window=21)
    full = tfp(spikes, 21) if method == "tfp" else tfi(spikes)
    np.testing.assert_array_equal(got, full[start:stop])
    if method == "tfp":
        assert reads == [(max(0, start - 10), min(total, stop + 10))]


def test_reconstruct_frames_tfi_reads_a_margin_when_spikes_are_dense() -> None:
    spikes = np.ones((10_000, 2, 2), np.uint8)
    reads: list[tuple[int, int]] = []
    reconstruct_frames(lambda a, b: reads.append((a, b)) or spikes[a:b], 10_000, 5000, 5001, "tfi")
    assert reads == [(5000 - 64, 5000 + 64)]
    with pytest.raises(InputError, match="method"):
        reconstruct_frames(lambda a, b: spikes[a:b], 10_000, 0, 1, "tfx")

"""The fast learned-reconstruction path (running counts, channels-last network) equals the reference."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from spikenerf.recon.features import RunningFeatures, feature_count, spike_features
from spikenerf.recon.infer import learned_frames, mirrored, predict_frame
from spikenerf.recon.net import NetConfig, ReconNet, load_weights


def _stream(shape: tuple[int, ...], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rate = rng.random(shape[1:], dtype=np.float32)  # per-pixel rates: features vary across the image
    return (rng.random(shape, dtype=np.float32) < rate).astype(np.uint8)


def test_running_features_equal_the_whole_window_features() -> None:
    k, half = 9, 4
    frames = _stream((30, 7, 11))
    run = RunningFeatures(torch.from_numpy(frames), k)
    for f in [
        *range(0, 30),
        3,
        17,
        16,
        29,
    ]:  # consecutive (mirrored at both ends), then jumps and a step back
        steps = mirrored(f, half, 30)
        feats, scale = run(steps)
        window = torch.from_numpy(frames[steps]).float()[None]
        ref_scale = torch.tensor([max(float(window.mean()), 1e-2)])
        assert torch.equal(scale, ref_scale)
        assert torch.equal(feats, spike_features(window, ref_scale)), f


def test_running_features_read_no_value_back_from_the_device() -> None:
    """On a meta device every value read (``float``, ``item``, ``bool``) raises: a stream's frames make
    their features without a host synchronisation each (on CUDA they queue up)."""
    frames = torch.zeros(30, 6, 8, dtype=torch.uint8, device="meta")
    run = RunningFeatures(frames, 9)
    for f in (0, 1, 2, 20):  # mirrored, running, then recounted
        feats, scale = run(mirrored(f, 4, 30))
        assert feats.device.type == scale.device.type == "meta"
        assert feats.shape == (1, feature_count(9), 6, 8) and scale.shape == (1,)


def test_decode_equals_upsampling_before_the_1x1_convolutions() -> None:
    torch.manual_seed(1)
    net = ReconNet(NetConfig(window=7, width=8)).eval()
    feats, scale = torch.rand(2, feature_count(7), 12, 20), torch.tensor([0.3, 0.7])
    up = nn.functional.interpolate
    e1 = net.enc1(feats)
    e2 = net.enc2(e1)
    d2 = net.dec2(torch.cat([net.up2(up(net.mid(e2), scale_factor=2.0)), e2], 1))
    d1 = net.dec1(torch.cat([net.up1(up(d2, scale_factor=2.0)), e1], 1))
    ref = ((net.head(d1)[:, 0] + feats[:, net.base]) * scale.view(-1, 1, 1)).clamp_min(0.0)
    with torch.no_grad():
        torch.testing.assert_close(net.decode(feats, scale), ref, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    ("mode", "shape"), [("gray", (48, 18, 26)), ("rgb", (44, 3, 12, 16)), ("bayer", (45, 14, 18))]
)
def test_learned_frames_equal_predict_frame_of_each_mirrored_window(
    mode: str, shape: tuple[int, ...]
) -> None:
    net, _ = load_weights(None)  # the shipped weights, K = 41
    reference, _ = load_weights(None)
    k, total = net.config.window, shape[0]
    spikes = _stream(shape, seed=len(shape))
    for start, stop in ((0, 3), (total - 3, total), (20, 23)):  # both mirrored ends and the middle
        fast = learned_frames(net, lambda a, b: spikes[a:b], total, start, stop, mode, threshold=2.0)
        ref = np.stack(
            [predict_frame(reference, spikes[mirrored(f, k // 2, total)], mode) for f in range(start, stop)]
        )
        np.testing.assert_allclose(fast, 2.0 * ref, rtol=1e-5, atol=1e-6)
        assert float(np.abs(ref).max()) > 0.05  # not a trivially black comparison


def test_mirrored_reflects_the_window_at_both_ends_of_the_stream() -> None:
    assert mirrored(0, 3, 10).tolist() == [3, 2, 1, 0, 1, 2, 3]
    assert mirrored(9, 3, 10).tolist() == [6, 7, 8, 9, 8, 7, 6]
    assert mirrored(5, 2, 10).tolist() == [3, 4, 5, 6, 7]

"""The spiking volume renderer: the camera's firing rule over rendered intensity, and its gradients."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from spikenerf.camera.firing import fire
from spikenerf.camera.layout import to_camera_layout
from spikenerf.camera.model import CameraConfig, SpikeCamera
from spikenerf.fields import GridFieldConfig, MLPFieldConfig
from spikenerf.render import (
    build_model,
    fire_sequence,
    iter_spike_states,
    render_image,
    render_spike_stream,
    render_spike_window,
)
from spikenerf.scenes.trajectory import Intrinsics, orbit

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
GRID = GridFieldConfig(n_voxels_init=16**3, n_voxels_final=16**3, upsample_steps=(), density_components=4,
                       app_components=4, app_dim=8, hidden=16)  # fmt: skip
INTR = Intrinsics.from_fov(10, 8, 0.9)


@pytest.fixture(autouse=True, scope="module")
def _one_thread() -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _poses(n: int) -> np.ndarray:
    """n consecutive steps of a fast orbit (a full turn in 40 steps)."""
    return orbit(3.0, 25.0, duration=40 / 40000)[:n].poses


def _constant_model(value: float):
    """A gray MLP model that renders an opaque, constant intensity ``value`` everywhere in the box."""
    model = build_model("mlp", 1, BOX, MLPFieldConfig.tiny())
    with torch.no_grad():
        for net in (model.field.coarse, model.field.fine):
            net.sigma.weight.zero_()
            net.sigma.bias.fill_(1000.0)
            net.out.weight.zero_()
            net.out.bias.fill_(math.log(value / (1 - value)))
    return model


def test_fire_sequence_is_fire_in_a_loop_bit_for_bit() -> None:
    gen = torch.Generator().manual_seed(3)
    intensity = torch.rand(50, 64, 3, generator=gen) * 1.3
    start = torch.rand(64, 3, generator=gen)
    spikes, accs = fire_sequence(intensity, start, 1.0)
    acc = start
    for k in range(50):
        s, acc = fire(acc, intensity[k], 1.0)
        assert torch.equal(spikes[k], s) and torch.equal(accs[k], acc)
    assert spikes.dtype == torch.bool and spikes.any() and not spikes.all()


@pytest.mark.parametrize("color", ["gray", "rgb"])
def test_fire_sequence_reproduces_the_camera_simulator(color: str) -> None:
    h, w, steps = 6, 7, 60
    camera = SpikeCamera(h, w, CameraConfig(threshold=1.0, color=color, seed=11), device="cpu")
    shape = (steps, h, w) if color == "gray" else (steps, 3, h, w)
    frames = torch.rand(shape, generator=torch.Generator().manual_seed(5)) * 0.9
    expected = torch.stack([camera.step(f).clone() for f in frames])
    start = SpikeCamera(
        h, w, CameraConfig(threshold=1.0, color=color, seed=11), device="cpu"
    ).initial_accumulator
    spikes, accs = fire_sequence(frames, start, 1.0)
    assert torch.equal(spikes, expected)
    assert torch.equal(accs[-1], camera.accumulator)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(0.0, 2.0, allow_nan=False, width=32), min_size=1, max_size=60),
    st.floats(0.0, 0.99),
    st.sampled_from([0.5, 1.0, 2.0]),
)
def test_fire_sequence_conserves_charge(intensities: list[float], start: float, threshold: float) -> None:
    start = start * threshold
    x = torch.tensor(intensities, dtype=torch.float32)[:, None]
    spikes, accs = fire_sequence(x, torch.tensor([start]), threshold)
    total = start + float(x.double().sum()) - threshold * int(spikes.sum())
    assert accs[-1].item() == pytest.approx(total, abs=1e-4)
    assert (accs >= -1e-6).all()


@pytest.mark.parametrize("kind", ["grid", "mlp"])
def test_window_matches_image_renders_and_gradient_reaches_the_field(kind: str) -> None:
    torch.manual_seed(0)
    model = build_model(kind, 3, BOX, GRID if kind == "grid" else MLPFieldConfig.tiny())
    if kind == "grid":
        with torch.no_grad():
            model.field.density_lines.mul_(60.0)  # visible content, so colour is decoded (weights > 1e-4)
    poses = _poses(4)
    pixels = torch.tensor([[0, 0], [4, 3], [9, 7], [5, 5]])
    start = torch.rand(4, 3)
    window = render_spike_window(model, poses, INTR, pixels, start, threshold=0.5)
    assert window.intensity.shape == window.spikes.shape == window.accumulator.shape == (4, 4, 3)
    assert window.spikes.dtype == torch.bool
    for k in range(4):  # step k uses the pose of step k
        img = render_image(model, poses[k], INTR).color
        assert torch.allclose(window.intensity[k], img[pixels[:, 1], pixels[:, 0]], atol=1e-5)
    ref_spikes, ref_accs = fire_sequence(window.intensity.detach(), start, 0.5)
    assert torch.equal(window.spikes, ref_spikes) and torch.allclose(window.accumulator, ref_accs)

    perturbed = render_spike_window(model, poses, INTR, pixels, start, threshold=0.5, perturb=True)
    (perturbed.intensity.square().sum() + perturbed.accumulator.sum()).backward()
    params = dict(model.named_parameters())
    names = (
        ["field.density_planes", "field.decoder.0.weight"]
        if kind == "grid"
        else ["field.fine.trunk.0.weight"]
    )
    for name in names:
        assert params[name].grad is not None and params[name].grad.abs().sum() > 0, name


def test_spike_stream_fires_like_the_camera_for_a_constant_scene() -> None:
    model = _constant_model(0.35)
    poses = _poses(12)
    narrow = Intrinsics.from_fov(10, 8, 0.5)  # every pixel sees the box (no white background)
    stream = render_spike_stream(model, poses, narrow, threshold=1.0, start_accumulator=torch.zeros(8, 10))
    assert stream.shape == (12, 8, 10) and stream.dtype == torch.bool  # the camera layout
    # 0.35 per step from 0: spikes after steps 3, 6, 9, 12 (indices 2, 5, 8, 11), everywhere
    fired = stream.reshape(12, -1).all(dim=1)
    assert fired.tolist() == [k in (2, 5, 8, 11) for k in range(12)]
    assert not stream.reshape(12, -1)[[k for k in range(12) if k not in (2, 5, 8, 11)]].any()


@pytest.mark.parametrize("channels", [1, 3])
def test_spike_stream_equals_fire_sequence_over_rendered_images_and_seeds_repeat(channels: int) -> None:
    torch.manual_seed(1)
    model = build_model("grid", channels, BOX, GRID)
    with torch.no_grad():
        model.field.density_lines.mul_(60.0)  # make something visible
    poses = _poses(6)
    stream = render_spike_stream(model, poses, INTR, threshold=2.5, start_accumulator=4, chunk=17)
    frames = torch.stack([render_image(model, p, INTR).color for p in poses])
    start = torch.rand((8, 10, channels), generator=torch.Generator().manual_seed(4)) * 2.5
    expected, _ = fire_sequence(frames, start, 2.5)  # channels last, like the rendered images
    assert stream.shape == ((6, 8, 10) if channels == 1 else (6, 3, 8, 10))  # the camera layout
    assert torch.equal(stream, to_camera_layout(expected))
    assert 0 < stream.float().mean() < 0.6
    assert torch.equal(render_spike_stream(model, poses, INTR, 2.5, start_accumulator=4), stream)
    assert not torch.equal(render_spike_stream(model, poses, INTR, 2.5, start_accumulator=5), stream)


@pytest.mark.parametrize("channels", [1, 3])
def test_a_stream_continued_from_a_yielded_accumulator_fires_the_same_spikes(channels: int) -> None:
    """What ``render`` relies on to resume a stream: the state after step k, passed back as the start of
    the remaining poses, gives the uninterrupted stream's spikes bit for bit."""
    torch.manual_seed(1)
    model = build_model("grid", channels, BOX, GRID)
    with torch.no_grad():
        model.field.density_lines.mul_(60.0)
    poses = _poses(7)
    whole = render_spike_stream(model, poses, INTR, threshold=2.5, start_accumulator=3)
    states = list(iter_spike_states(model, poses[:4], INTR, 2.5, start_accumulator=3))
    spikes, acc = states[-1]
    assert acc.shape == spikes.shape and acc.dtype == torch.float32  # both in the camera layout
    rest = render_spike_stream(model, poses[4:], INTR, 2.5, start_accumulator=acc.cpu().clone())
    assert torch.equal(torch.cat([torch.stack([s for s, _ in states]), rest]), whole)
    assert 0 < whole.float().mean() < 0.9

"""The fused CPU kernel's two loops for the grid's packed training render, each against the computation it
replaced: the march (``render/march_cpu.py``) keeps exactly the torch march's steps in their order, and the
density looked up only up to each ray's early stop (``GridField.density_until``) renders and differentiates
as the lookup of every sample, then masked, did; both left aside where the kernel is not used."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

import test_static_render as static
from spikenerf.fields import grid as grid_module
from spikenerf.fields import vm_kernel
from spikenerf.render import march_cpu
from spikenerf.render.volume import early_stop_mask, ray_offsets


@pytest.fixture(autouse=True)
def _kernel() -> None:
    if not vm_kernel.available():
        pytest.skip("no C++ compiler for the fused VM kernel")


def _with(model, **changes):  # type: ignore[no-untyped-def]
    model.field.config = dataclasses.replace(model.field.config, **changes)
    return model


def _marching(model, size: tuple[int, int]):  # type: ignore[no-untyped-def]
    """The march's inputs for ``size`` rays of ``static._rays`` (normalised origins and directions, near and
    far shortened as ``render_rays`` does, the step), every 7th ray empty and every 5th ending exactly where
    a step starts."""
    origins, dirs, near, far = static._rays(model, size)
    field, step = model.field, model.field.step_size
    if model.use_occupancy:
        near, far = model._shorten(origins, dirs, near, far, step)
    d_n = dirs * (2.0 / (field.scene_box[1] - field.scene_box[0]))
    i = torch.arange(len(far))
    on_lattice = near + step * torch.floor((far - near) / step)
    far = torch.where(i % 5 == 1, on_lattice, torch.where(i % 7 == 3, near, far))
    return field.normalize(origins), d_n, near, far, step


def _torch_march(model, inputs, monkeypatch: pytest.MonkeyPatch):  # type: ignore[no-untyped-def]
    """``GridModel._march`` as it was: the torch ops over every candidate step."""
    with monkeypatch.context() as m:
        m.setattr(march_cpu, "applies", lambda *a: False)
        return model._march(*inputs)


@pytest.mark.parametrize("threads", [1, 3])
@pytest.mark.parametrize("occupancy", [False, True])
def test_the_cpu_march_keeps_the_torch_marchs_steps_in_order(
    occupancy: bool, threads: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = static._model(occupancy)
    inputs = _marching(model, (40, 30))  # 1200 rays: the kernel's 64 chunks of rays, moved up into place
    assert march_cpu.applies(*inputs[:4])
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        ray, k = model._march(*inputs)
    finally:
        torch.set_num_threads(before)
    want_ray, want_k = _torch_march(model, inputs, monkeypatch)
    assert len(want_ray) > 5000
    assert torch.equal(ray, want_ray) and torch.equal(k, want_k)
    counts = model._counts(*inputs[2:])
    kept = torch.bincount(ray, minlength=len(counts))
    assert (kept == 0).any()  # empty rays
    assert (int((counts - kept).sum()) > len(ray) // 4) == occupancy  # and many steps culled by the grid


def test_the_cpu_march_survives_a_ray_of_nan_direction(monkeypatch: pytest.MonkeyPatch) -> None:
    """A NaN direction (the torch march cannot index a cell for it): the kernel reads a cell of the grid,
    keeps at most that ray's steps, and the other rays' steps as the torch march does."""
    model = static._model(occupancy=True)
    o_n, d_n, near, far, step = _marching(model, (12, 10))
    want_ray, want_k = _torch_march(model, (o_n, d_n, near, far, step), monkeypatch)
    d_n = d_n.clone()
    d_n[0] = float("nan")
    ray, k = model._march(o_n, d_n, near, far, step)
    counts = model._counts(near, far, step)
    assert int((ray == 0).sum()) <= int(counts[0])
    assert torch.equal(ray[ray > 0], want_ray[want_ray > 0]) and torch.equal(k[ray > 0], want_k[want_ray > 0])


def _packed_samples(model, rays):  # type: ignore[no-untyped-def]
    """The packed training render's samples of ``rays``: normalised points, interval lengths, ray of each,
    the rays' offsets and their number."""
    origins, dirs, near, far = rays
    field, step = model.field, model.field.step_size
    near, far = model._shorten(origins, dirs, near, far, step)
    o_n, d_n = field.normalize(origins), dirs * (2.0 / (field.scene_box[1] - field.scene_box[0]))
    ray, k = model._march(o_n, d_n, near, far, step)
    _, deltas, xn = model._points(o_n, d_n, near, far, step, ray, k, False)
    return xn, deltas, ray, ray_offsets(ray, len(origins)), len(origins)


@pytest.mark.parametrize("eps", [1e-2, 1e-4])
def test_the_density_is_looked_up_until_each_rays_early_stop_and_there_as_before(eps: float) -> None:
    model = _with(static._model(occupancy=True), early_stop=eps, distance_scale=40.0)
    xn, deltas, ray, offsets, n = _packed_samples(model, static._rays(model, (24, 20)))
    field, cfg = model.field, model.field.config
    with torch.no_grad():
        raw = vm_kernel.vm_sum_until(field.density_planes, field.density_lines, xn, offsets, deltas,
                                     cfg.density_shift, cfg.distance_scale, -math.log(eps))  # fmt: skip
        every = vm_kernel.vm_lookup(field.density_planes, field.density_lines, xn, summed=True)
        kept = early_stop_mask(field.density_norm(xn), deltas, ray, n, eps, offsets)
    looked = raw.isfinite()
    assert bool((raw[~looked] == -math.inf).all())
    assert int(kept.sum()) <= int(looked.sum()) < 0.7 * len(raw)  # a third of the samples skipped or more
    assert bool(looked[kept].all())  # every sample the early stop keeps is looked up, with its value
    torch.testing.assert_close(raw[looked], every[looked], rtol=1e-6, atol=1e-7)
    assert torch.equal(field.density_until(xn, offsets, deltas, -math.log(eps)) == 0, ~looked)


@pytest.mark.parametrize("occupancy", [False, True])
def test_a_training_render_and_its_gradients_are_those_of_every_samples_density(
    occupancy: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Closeness against the previous computation: every sample's density looked up, then the early stop's
    mask applied (``density_norm`` in place of ``density_until``)."""
    model = _with(static._model(occupancy), early_stop=1e-3, distance_scale=40.0)
    rays = static._rays(model, (24, 20))
    calls = []
    until = grid_module.GridField.density_until
    monkeypatch.setattr(grid_module.GridField, "density_until", lambda *a: calls.append(1) or until(*a))
    got, got_grads = static._render(model, rays)
    assert calls and got.opacity.max() > 1 - 1e-3  # the stopping lookup ran, on rays that become opaque
    monkeypatch.setattr(grid_module.GridField, "density_until", lambda self, xyz, *a: self.density_norm(xyz))
    want, want_grads = static._render(model, rays)
    for name in ("color", "depth", "opacity"):
        torch.testing.assert_close(getattr(got, name), getattr(want, name), rtol=1e-6, atol=1e-6)
    for g, w in zip(got_grads, want_grads, strict=True):
        torch.testing.assert_close(g, w, rtol=1e-5, atol=1e-6)


def test_the_stopping_lookup_is_a_custom_op_with_the_lookups_gradient() -> None:
    gen = torch.Generator().manual_seed(3)
    p = torch.randn(3, 7, 7, 4, generator=gen, requires_grad=True)  # channels-last (3, R, R, C)
    ln = torch.randn(3, 7, 4, generator=gen, requires_grad=True)  # (3, R, C)
    xyz = torch.rand(40, 3, generator=gen) * 2 - 1
    offsets, deltas = torch.tensor([0, 15, 15, 40]), torch.full((40,), 0.3)
    args = (p, ln, xyz, offsets, deltas, 0.0, 10.0, 2.0)
    torch.library.opcheck(torch.ops.spikenerf.vm_cpu_until.default, args)
    raw = torch.ops.spikenerf.vm_cpu_until(*args)
    looked = raw.isfinite()
    assert 0 < int(looked.sum()) < 40
    every = torch.ops.spikenerf.vm_cpu_forward(p, ln, xyz, True)
    weights = torch.randn(40, generator=gen) * looked
    got = torch.autograd.grad((torch.where(looked, raw, 0.0) * weights).sum(), (p, ln))
    want = torch.autograd.grad((every * weights).sum(), (p, ln))
    for g, w in zip(got, want, strict=True):
        torch.testing.assert_close(g, w)


def test_where_the_kernel_is_not_used_every_sample_is_looked_up(monkeypatch: pytest.MonkeyPatch) -> None:
    model = _with(static._model(occupancy=True), early_stop=1e-2, distance_scale=40.0)
    xn, deltas, _, offsets, _ = _packed_samples(model, static._rays(model))
    field = model.field
    with torch.no_grad():
        with monkeypatch.context() as m:
            m.setattr(grid_module, "usable", lambda *a: False)  # e.g. SPIKENERF_VM_KERNEL=0: grid_sample
            assert torch.equal(field.density_until(xn, offsets, deltas, 1.0), field.density_norm(xn))
        every = field.density_norm(xn)
        assert not torch.equal(field.density_until(xn, offsets, deltas, 1.0), every)
        field.density_norm = field.density_norm  # what train --compile does: its compiled function is used
        assert torch.equal(field.density_until(xn, offsets, deltas, 1.0), every)
    with pytest.raises(RuntimeError, match="offsets"):
        vm_kernel.vm_sum_until(field.density_planes, field.density_lines, xn, offsets[:-1], deltas, 0, 1, 1)
    with pytest.raises(ValueError, match="offsets"):
        vm_kernel.vm_sum_until(field.density_planes, field.density_lines, xn, offsets[None], deltas, 0, 1, 1)


def test_the_cpu_march_leaves_a_float64_input_to_the_torch_march(monkeypatch: pytest.MonkeyPatch) -> None:
    """The torch march tests a float64 ``far`` (or direction) in float64; the kernel, all float32, would keep
    other steps, so it applies only where all four inputs are float32."""
    model = static._model(occupancy=True)
    o_n, d_n, near, far, step = _marching(model, (40, 30))
    far = far.double() + 1e-9  # between two float32 values
    ray, k = model._march(o_n, d_n, near, far, step)
    want_ray, want_k = _torch_march(model, (o_n, d_n, near, far, step), monkeypatch)
    assert torch.equal(ray, want_ray) and torch.equal(k, want_k)
    assert not march_cpu.applies(o_n, d_n, near, far) and not march_cpu.applies(o_n, d_n.double(), near, far)


def test_the_kernels_refuse_inputs_they_would_read_or_write_outside_of() -> None:
    """Offsets that do not start at 0 or that decrease (samples never written, or written out of bounds) and
    march inputs of different lengths: an error, from the Python functions and the raw ops alike."""
    gen = torch.Generator().manual_seed(5)
    planes, lines = torch.randn(3, 4, 8, 8, generator=gen), torch.randn(3, 4, 8, 1, generator=gen)
    xyz, deltas = torch.rand(10, 3, generator=gen) * 2 - 1, torch.full((10,), 0.01)
    for offsets in ([3, 6, 10], [0, 8, 4, 10]):
        with pytest.raises(RuntimeError, match="offsets"):
            vm_kernel.vm_sum_until(planes, lines, xyz, torch.tensor(offsets), deltas, 0.0, 1.0, 5.0)
    p, ln = torch.randn(3, 8, 8, 4, generator=gen), torch.randn(3, 8, 4, generator=gen)  # channels last
    for offsets in ([0, 8, 4, 10], [0, 50_000_000, 10], [2, 10]):
        with pytest.raises(RuntimeError, match="offsets"):
            torch.ops.spikenerf.vm_cpu_until(p, ln, xyz, torch.tensor(offsets), deltas, 0.0, 1.0, 5.0)
    o_n, d_n = torch.zeros(4, 3), torch.ones(4, 3)
    near, far, counts = torch.zeros(5), torch.ones(5), torch.full((5,), 3)
    with pytest.raises(RuntimeError, match="march"):
        march_cpu.march(o_n, d_n, near, far, counts, None, 0.5)

"""The grid's colour on a CPU, each shortcut against the computation it replaced: the fused kernel writing the
bf16 decoder's padded input rows itself and reading their bfloat16 gradient (``vm_kernel.vm_rows``) against
the float32 lookup padded by ``row_buckets.pad_rows``; the view encoding made once a ray and gathered
(``GridField.color_norm``'s ``rays``) against the encoding of every point's direction. Outputs and
gradients."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from spikenerf.fields import grid as grid_module
from spikenerf.fields import vm_kernel
from spikenerf.fields.row_buckets import bucket_rows, pad_rows
from test_fields import CFG, smooth_field


@pytest.fixture(autouse=True)
def _kernel() -> None:
    if not vm_kernel.available():
        pytest.skip("no C++ compiler for the fused VM kernel")


def _padded_lookup(planes: torch.Tensor, lines: torch.Tensor, xyz: torch.Tensor, rows: int) -> torch.Tensor:
    """The previous computation: the float32 (M, 3, C) lookup, padded to bf16 rows."""
    return pad_rows(vm_kernel.vm_lookup(planes, lines, xyz).reshape(len(xyz), -1), rows, torch.bfloat16)


@pytest.mark.parametrize("threads", [1, 3])
def test_the_kernels_bf16_rows_are_the_padded_lookup_with_the_same_gradients(threads: int) -> None:
    """The same bits forward and backward; with 3 threads the backward splits the plane rows into bands (a
    point on a band's edge scatters into two threads' rows)."""
    gen = torch.Generator().manual_seed(7)
    planes = torch.randn(3, 6, 16, 16, generator=gen).contiguous(memory_format=torch.channels_last)
    lines = torch.randn(3, 6, 16, 1, generator=gen).contiguous(memory_format=torch.channels_last)
    planes.requires_grad_()
    lines.requires_grad_()
    xyz = torch.rand(9000, 3, generator=gen) * 2.2 - 1.1  # some outside the box: zeros padding
    rows = bucket_rows(len(xyz))
    assert rows > len(xyz)
    upstream = torch.randn(rows, 18, generator=gen).bfloat16()
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        got = vm_kernel.vm_rows(planes, lines, xyz, rows)
        got_grads = torch.autograd.grad(got, (planes, lines), upstream)
        want = _padded_lookup(planes, lines, xyz, rows)
        want_grads = torch.autograd.grad(want, (planes, lines), upstream)
    finally:
        torch.set_num_threads(before)
    assert got.dtype == torch.bfloat16 and got.shape == (rows, 18) and not got[len(xyz) :].any()
    assert torch.equal(got, want)
    for g, w in zip(got_grads, want_grads, strict=True):
        assert g.shape == w.shape
        assert torch.equal(g, w)
    with torch.no_grad():  # no gradient: the same rows
        assert torch.equal(vm_kernel.vm_rows(planes, lines, xyz, rows), want)


def _colour_and_grads(field, xyz, dirs, rays=None):  # type: ignore[no-untyped-def]
    rgb = field.color_norm(xyz, dirs, rays)
    weights = torch.linspace(-1, 1, rgb.numel()).view_as(rgb)
    names = ("app_planes", "app_lines", "basis.weight", "decoder.0.weight")
    params = [field.get_parameter(n) for n in names]
    return rgb, torch.autograd.grad((rgb * weights).sum(), params)


@pytest.mark.parametrize("bf16", [False, True])
def test_the_colour_takes_the_kernels_rows_and_renders_as_the_padded_lookup(
    bf16: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(grid_module, "cpu_has", lambda *flags: True)  # bf16 emulated where not native
    torch.manual_seed(0)
    field = smooth_field(replace(CFG, hidden=32, decoder_bf16=bf16))
    xyz, dirs = torch.rand(700, 3) * 2 - 1, torch.nn.functional.normalize(torch.randn(700, 3), dim=-1)
    calls: list[int] = []
    rows = vm_kernel.vm_rows
    monkeypatch.setattr(grid_module, "vm_rows", lambda *a: calls.append(1) or rows(*a))
    got, got_grads = _colour_and_grads(field, xyz, dirs)
    assert len(calls) == int(bf16)  # only the bf16 decoder takes rows
    monkeypatch.setattr(grid_module, "vm_rows", _padded_lookup)
    want, want_grads = _colour_and_grads(field, xyz, dirs)
    assert torch.equal(got, want)
    for g, w in zip(got_grads, want_grads, strict=True):
        assert torch.equal(g, w)


@pytest.mark.parametrize("bf16", [False, True])
def test_a_view_encoded_once_a_ray_colours_as_one_encoded_at_every_point(
    bf16: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(grid_module, "cpu_has", lambda *flags: True)
    torch.manual_seed(1)
    field = smooth_field(replace(CFG, hidden=32, decoder_bf16=bf16))
    dirs = torch.nn.functional.normalize(torch.randn(37, 3), dim=-1)  # 37 rays
    rays = torch.sort(torch.randint(0, 37, (900,))).values  # 900 points, ray after ray
    xyz = torch.rand(900, 3) * 2 - 1
    got, got_grads = _colour_and_grads(field, xyz, dirs, rays)
    want, want_grads = _colour_and_grads(field, xyz, dirs.index_select(0, rays))
    torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-6)
    for g, w in zip(got_grads, want_grads, strict=True):
        torch.testing.assert_close(g, w, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("bf16", [False, True])
@pytest.mark.parametrize("kernel", [False, True])
def test_no_point_to_colour_is_an_empty_colour(
    bf16: bool, kernel: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """0 points (a render whose every sample is culled) gave ``reshape(0, -1)``'s error: (0, C) instead, on
    each lookup path, with and without the rays, and its backward runs."""
    monkeypatch.setattr(grid_module, "cpu_has", lambda *flags: True)
    field = smooth_field(replace(CFG, hidden=32, decoder_bf16=bf16))
    xyz, dirs = torch.zeros(0, 3), torch.nn.functional.normalize(torch.randn(4, 3), dim=-1)
    for rays in (None, torch.zeros(0, dtype=torch.int64)):
        if kernel:
            rgb = field.color_norm(xyz, dirs[:0] if rays is None else dirs, rays)
        else:
            with vm_kernel.suspended():
                rgb = field.color_norm(xyz, dirs[:0] if rays is None else dirs, rays)
        assert rgb.shape == (0, field.channels) and rgb.dtype == torch.float32
        rgb.sum().backward()

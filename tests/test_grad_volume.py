"""Volume rendering (``render/volume.py``, kornia style): for each function a smoke test, the refusals
(InputError naming the parameter, instead of a torch broadcast error or a silently wrong sum) and a float64
``gradcheck``; the Triton custom ops (``render/volume_triton.py``, float32 only) against the float64 eager
path with a tolerance instead. Small sizes: each test runs in well under a second."""

from __future__ import annotations

from collections.abc import Callable

import pytest
import torch

from helpers import refusal_test
from spikenerf.render import volume as V
from spikenerf.render import volume_triton

D = torch.float64
RAY = torch.tensor([0, 0, 0, 2, 2, 3])  # rays of 3, 0, 2 and 1 samples
N_RAYS = 4


def _rand(*shape: int, seed: int = 0, scale: float = 1.0, low: float = 0.0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(*shape, generator=gen, dtype=D) * scale + low).requires_grad_()


def test_smoke_shapes_and_values() -> None:
    sigma, deltas = torch.full((2, 3), 1.0), torch.full((2, 3), 0.5)
    w = V.weights_from_density(sigma, deltas)
    assert w.shape == (2, 3) and torch.all(w >= 0) and torch.all(w.sum(-1) < 1)
    color, depth, opacity = V.composite(w, torch.zeros(2, 3, 3), torch.arange(3.0).expand(2, 3))
    assert color.shape == (2, 3) and depth.shape == opacity.shape == (2,)
    assert torch.allclose(color, (1 - opacity)[:, None].expand(2, 3))  # black samples on white
    packed = V.packed_weights(sigma.reshape(-1), deltas.reshape(-1), torch.tensor([0, 0, 0, 1, 1, 1]), 2)
    assert torch.allclose(packed, w.reshape(-1), atol=1e-7)
    offsets = V.ray_offsets(RAY, N_RAYS)
    assert offsets.tolist() == [0, 3, 3, 5, 6]
    assert V.segment_sum(torch.ones(6), RAY, offsets).tolist() == [3.0, 0.0, 2.0, 1.0]
    assert V.packed_depth_before(torch.ones(6), RAY, N_RAYS).tolist() == [0, 1, 2, 0, 1, 0]
    c, d, o = V.packed_composite(torch.full((6,), 0.25), RAY, N_RAYS, torch.ones(6), torch.zeros(6, 3), None)
    assert c.shape == (4, 3) and o.tolist() == [0.75, 0.0, 0.5, 0.25] and d[1] == 0
    t, edges = V.stratified_samples(torch.zeros(2), torch.ones(2), 4, perturb=False)
    assert (
        t.shape == (2, 4) and edges.shape == (2, 5) and torch.allclose(t[0], torch.tensor([1, 3, 5, 7]) / 8)
    )
    assert V.deltas_from_samples(t, torch.ones(2)).shape == (2, 4)
    fine = V.sample_pdf(edges, torch.ones(2, 4), 5, perturb=False)
    assert fine.shape == (2, 5) and torch.all((fine >= 0) & (fine <= 1))
    keep = V.early_stop_mask(torch.full((6,), 10.0), torch.ones(6), RAY, N_RAYS, 0.01)
    assert keep.tolist() == [True, False, False, True, False, True]  # depth 10 > −ln 0.01 after one sample


def test_empty_inputs_give_empty_results_not_crashes() -> None:
    empty = torch.zeros(0, dtype=torch.long)
    assert V.weights_from_density(torch.zeros(0, 5), torch.zeros(0, 5)).shape == (0, 5)
    assert (
        V.composite(torch.zeros(2, 0), torch.zeros(2, 0, 3), torch.zeros(2, 0))[0].tolist() == [[1.0] * 3] * 2
    )
    assert V.packed_weights(torch.zeros(0), torch.zeros(0), empty, 3).shape == (0,)
    color, depth, opacity = V.packed_composite(
        torch.zeros(0), empty, 2, torch.zeros(0), torch.zeros(0, 3), None
    )
    assert color.tolist() == [[1.0] * 3] * 2 and depth.tolist() == opacity.tolist() == [0.0, 0.0]
    assert V.sample_pdf(torch.zeros(0, 5), torch.zeros(0, 4), 3, perturb=False).shape == (0, 3)


_z = torch.zeros
_idx = torch.tensor([2])

REFUSALS: list[tuple[str, Callable[[], object], str]] = [
    ("weights deltas", lambda: V.weights_from_density(_z(3, 5), _z(3, 4)), "deltas"),
    ("composite colors", lambda: V.composite(_z(2, 5), _z(2, 4, 3), _z(2, 5)), "colors"),
    ("composite 2-d colors", lambda: V.composite(_z(2, 5), _z(2, 5), _z(2, 5)), "colors"),
    ("composite t", lambda: V.composite(_z(2, 5), _z(2, 5, 3), _z(2, 4)), "t"),
    (
        "composite background",
        lambda: V.composite(_z(2, 5), _z(2, 5, 3), _z(2, 5), float("nan")),
        "background",
    ),
    ("packed deltas", lambda: V.packed_weights(_z(6), _z(5), RAY, N_RAYS), "deltas"),
    ("packed ray", lambda: V.packed_weights(_z(5), _z(5), RAY, N_RAYS), "ray"),
    ("packed 2-d sigma", lambda: V.packed_weights(_z(6, 1), _z(6, 1), RAY, N_RAYS), "sigma"),
    ("depth ray", lambda: V.packed_depth_before(_z(5), RAY, N_RAYS), "ray"),
    # colours of K samples but a colour index of another length: summed into the wrong rays before
    ("packed colour index", lambda: V.packed_composite(_z(6), RAY, N_RAYS, _z(6), _z(2, 3), _idx), "colors"),
    ("packed colours", lambda: V.packed_composite(_z(6), RAY, N_RAYS, _z(6), _z(5, 3), None), "colors"),
    ("packed t", lambda: V.packed_composite(_z(6), RAY, N_RAYS, _z(5), _z(6, 3), None), "t"),
    (
        "packed background",
        lambda: V.packed_composite(_z(6), RAY, 4, _z(6), _z(6, 3), None, 1e400),
        "background",
    ),
    # values of 7 rows summed by 6 rays' offsets: the 7th row was silently dropped before
    ("segment rows", lambda: V.segment_sum(_z(7), RAY, V.ray_offsets(RAY, N_RAYS)), "values"),
    ("stratified n=0", lambda: V.stratified_samples(_z(2), _z(2) + 1, 0, False), "n"),
    ("stratified n=-1", lambda: V.stratified_samples(_z(2), _z(2) + 1, -1, False), "n"),
    ("stratified n=2.5", lambda: V.stratified_samples(_z(2), _z(2) + 1, 2.5, False), "n"),  # type: ignore[arg-type]
    ("stratified far", lambda: V.stratified_samples(_z(2), _z(3), 4, False), "far"),
    ("deltas far", lambda: V.deltas_from_samples(_z(2, 4), _z(3)), "far"),
    ("pdf edges", lambda: V.sample_pdf(_z(2, 5), _z(2, 5), 3, False), "edges"),
    ("pdf n", lambda: V.sample_pdf(_z(2, 5), _z(2, 4), 0, False), "n"),
    (
        "early stop threshold",
        lambda: V.early_stop_mask(_z(6), _z(6), RAY, 4, float("nan")),
        "min_transmittance",
    ),
]


test_bad_inputs_are_refused_naming_the_parameter = refusal_test(REFUSALS)


def test_nan_and_inf_densities_stay_inside_their_own_ray() -> None:
    """The packed scan clamps τ: a NaN or inf sample makes its ray's later weights 0, no other ray's NaN."""
    sigma = torch.ones(6)
    for bad in (float("nan"), float("inf")):
        sigma[0] = bad
        w = V.packed_weights(sigma, torch.ones(6), RAY, N_RAYS)
        assert torch.isfinite(w[1:]).all() and w[1:3].eq(0).all()
        assert torch.equal(w[3:], V.packed_weights(torch.ones(3), torch.ones(3), RAY[3:] - 2, 2))


def test_gradcheck_dense_compositing() -> None:
    w, colors, t = _rand(3, 4, seed=1, scale=0.25), _rand(3, 4, 2, seed=2), _rand(3, 4, seed=3, scale=4)
    assert torch.autograd.gradcheck(lambda a, b, c: V.composite(a, b, c, 0.3), (w, colors, t))
    near, far = _rand(3, seed=4), _rand(3, seed=5, low=2.0)
    assert torch.autograd.gradcheck(lambda a, b: V.stratified_samples(a, b, 4, False), (near, far))
    ts = torch.sort(_rand(3, 4, seed=6).detach(), dim=-1).values.requires_grad_()
    assert torch.autograd.gradcheck(V.deltas_from_samples, (ts, far))


def test_gradcheck_hierarchical_samples_in_the_bin_edges() -> None:
    """``sample_pdf`` is piecewise linear in the edges (the caller detaches the weights)."""
    edges = torch.cumsum(_rand(2, 5, seed=7, low=0.2).detach(), dim=-1).requires_grad_()
    weights = torch.rand(2, 4, generator=torch.Generator().manual_seed(8), dtype=D)
    assert torch.autograd.gradcheck(lambda e: V.sample_pdf(e, weights, 6, False), (edges,))


def test_gradcheck_packed_compositing_and_sums() -> None:
    tau = _rand(6, seed=9, scale=2)
    assert torch.autograd.gradcheck(lambda x: V.packed_depth_before(x, RAY, N_RAYS), (tau,))
    offsets = V.ray_offsets(RAY, N_RAYS)
    values = _rand(6, 2, seed=10)
    assert torch.autograd.gradcheck(lambda v: V.segment_sum(v, RAY, offsets), (values,))
    w, t, colors = _rand(6, seed=11, scale=0.3), _rand(6, seed=12, scale=3), _rand(6, 3, seed=13)
    assert torch.autograd.gradcheck(
        lambda a, b, c: V.packed_composite(a, RAY, N_RAYS, b, c, None), (w, t, colors)
    )
    index, some = torch.tensor([0, 2, 5]), _rand(3, 3, seed=14)
    assert torch.autograd.gradcheck(
        lambda a, b, c: V.packed_composite(a, RAY, N_RAYS, b, c, index), (w, t, some)
    )


def _triton_or_skip() -> None:
    if not volume_triton.applies(torch.zeros(1)):
        pytest.skip("Triton does not run here (no triton, or no TRITON_INTERPRET=1 without CUDA)")


def test_triton_depth_before_matches_the_float64_path_forward_and_backward() -> None:
    """The custom op is float32 only, so no gradcheck: its values and its backward (a suffix sum) against
    the eager float64 scan's, to float32 rounding (rtol 1e-5, atol 1e-5 on values of order 1)."""
    _triton_or_skip()
    gen = torch.Generator().manual_seed(15)
    tau64 = (torch.rand(6, generator=gen, dtype=D) * 2).requires_grad_()
    tau32 = tau64.detach().float().requires_grad_()
    offsets = V.ray_offsets(RAY, N_RAYS)
    ref = V.packed_depth_before(tau64, RAY, N_RAYS)
    out = volume_triton.depth_before(tau32, offsets, V.MAX_TAU)
    assert out.dtype == torch.float32 and torch.allclose(out.double(), ref, rtol=1e-5, atol=1e-5)
    grad = torch.randn(6, generator=gen, dtype=D)
    (g64,) = torch.autograd.grad(ref, tau64, grad)
    (g32,) = torch.autograd.grad(out, tau32, grad.float())
    assert torch.allclose(g32.double(), g64, rtol=1e-5, atol=1e-5)


def test_triton_segment_sum_matches_the_float64_path_forward_and_backward() -> None:
    _triton_or_skip()
    gen = torch.Generator().manual_seed(16)
    v64 = torch.randn(6, 3, generator=gen, dtype=D).requires_grad_()
    v32 = v64.detach().float().requires_grad_()
    offsets = V.ray_offsets(RAY, N_RAYS)
    ref, out = V.segment_sum(v64, RAY, offsets), V.segment_sum(v32, RAY, offsets, fused=True)
    assert torch.allclose(out.double(), ref, rtol=1e-5, atol=1e-6)
    grad = torch.randn(4, 3, generator=gen, dtype=D)
    (g64,) = torch.autograd.grad(ref, v64, grad)
    (g32,) = torch.autograd.grad(out, v32, grad.float())
    assert torch.allclose(g32.double(), g64, rtol=1e-6, atol=1e-6)

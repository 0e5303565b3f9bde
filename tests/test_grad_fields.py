"""The fields' differentiable pieces, kornia style: the positional encoding, the reference VM lookup
(``sample_vm``) and the custom autograd functions over it: the fused CPU kernel's ``torch.library`` ops
(``vm_lookup``, ``vm_sum_until``), its ``autograd.Function`` (``vm_rows``) and the Triton ops
(``triton_vm``). Their gradients include the points' (pose refinement moves them). The kernels are float32
only (bfloat16 rows for ``vm_rows``), so they are compared with the float64 eager reference, forward and
backward, to a tolerance (float32: 1e-5; bfloat16: 1e-2 relative); ``sample_vm`` and the encoding pass
``gradcheck`` in float64. (``gather_vm``, ``vm_lattice_sum`` and ``total_variation`` have theirs in
``test_vm_gather.py``, ``test_vm_lattice.py`` and ``test_fields.py``.)"""

from __future__ import annotations

from collections.abc import Callable

import pytest
import torch

from spikenerf.core.errors import InputError
from spikenerf.fields import vm_kernel, vm_triton
from spikenerf.fields.encoding import encoded_size, positional_encoding
from spikenerf.fields.vm_sample import sample_vm

D = torch.float64


def _factors(
    seed: int = 0, channels: int = 3, res: int = 5
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """float64 planes (3, C, R, R), lines (3, C, R, 1) and 12 points (12, 3), some outside [−1, 1]."""
    gen = torch.Generator().manual_seed(seed)
    planes = torch.randn(3, channels, res, res, generator=gen, dtype=D)
    lines = torch.randn(3, channels, res, 1, generator=gen, dtype=D)
    xyz = torch.rand(12, 3, generator=gen, dtype=D) * 2.2 - 1.1
    return planes, lines, xyz


def test_encoding_smoke_and_gradcheck() -> None:
    x = torch.rand(4, 3, dtype=D, requires_grad=True)
    out = positional_encoding(x, 3)
    assert out.shape == (4, encoded_size(3, 3)) and torch.equal(out[:, :3], x)
    assert positional_encoding(x, 0, include_input=False).shape == (4, 0)
    assert positional_encoding(torch.zeros(0, 3), 2).shape == (0, encoded_size(3, 2))
    assert torch.autograd.gradcheck(lambda v: positional_encoding(v, 3), (x,))


REFUSALS: list[tuple[str, Callable[[], object], str]] = [
    ("encoding octaves", lambda: positional_encoding(torch.zeros(2, 3), -1), "n_freqs"),
    # 2.5 octaves made three, wider than encoded_size said
    ("encoding fraction", lambda: positional_encoding(torch.zeros(2, 3), 2.5), "n_freqs"),  # type: ignore[arg-type]
    ("encoding 0-d", lambda: positional_encoding(torch.tensor(1.0), 2), "x"),
]


@pytest.mark.parametrize(("case", "call", "param"), REFUSALS, ids=[r[0] for r in REFUSALS])
def test_encoding_refusals_name_the_parameter(case: str, call: Callable[[], object], param: str) -> None:
    with pytest.raises(InputError, match=param) as err:
        call()
    assert param in err.value.params


def test_gradcheck_reference_lookup_in_factors_and_points() -> None:
    """``grid_sample`` in float64: the reference every kernel equals (points too: pose refinement)."""
    planes, lines, xyz = (t.requires_grad_() for t in _factors(1, channels=2, res=4))
    xyz = (xyz.detach() * 0.8).requires_grad_()  # inside, off the texel edges' kinks
    assert torch.autograd.gradcheck(sample_vm, (planes, lines, xyz))


def _kernel_or_skip() -> None:
    if not vm_kernel.available():
        pytest.skip("no C++ compiler for the fused VM kernel")


def _against_float64(
    lookup: Callable, summed: bool, seed: int, atol: float = 1e-5, rtol: float = 1e-5, points: bool = True
) -> None:
    """``lookup(planes, lines, xyz)`` in float32 against ``sample_vm`` in float64: values, and the planes',
    lines' and (``points``: pose refinement's case) the points' gradients of a random output gradient."""
    p64, l64, x64 = _factors(seed)
    p64.requires_grad_(), l64.requires_grad_(), x64.requires_grad_(points)
    p32, l32, x32 = (t.detach().float().requires_grad_(t.requires_grad) for t in (p64, l64, x64))
    ref = sample_vm(p64, l64, x64).permute(2, 0, 1)  # (M, 3, C)
    ref = ref.sum(dim=(1, 2)) if summed else ref
    out = lookup(p32, l32, x32)
    assert out.shape == ref.shape and torch.allclose(out.double(), ref, atol=atol, rtol=rtol)
    grad = torch.randn(ref.shape, generator=torch.Generator().manual_seed(seed + 100), dtype=D)
    wanted = (p64, l64, x64) if points else (p64, l64)
    expect = torch.autograd.grad(ref, wanted, grad)
    got = torch.autograd.grad(out, (p32, l32, x32) if points else (p32, l32), grad.to(out.dtype))
    for a, b in zip(got, expect, strict=True):
        assert torch.allclose(a.double(), b, atol=atol * 10, rtol=rtol * 10)


@pytest.mark.parametrize("summed", [False, True])
def test_cpu_custom_op_matches_the_float64_reference(summed: bool) -> None:
    _kernel_or_skip()
    _against_float64(lambda p, ln, x: vm_kernel.vm_lookup(p, ln, x, summed), summed, seed=2)


def test_cpu_stopping_op_without_a_stop_matches_the_float64_reference() -> None:
    _kernel_or_skip()
    offsets, deltas = torch.tensor([0, 5, 5, 12]), torch.full((12,), 0.1)
    _against_float64(
        lambda p, ln, x: vm_kernel.vm_sum_until(p, ln, x, offsets, deltas, 0.0, 1.0, float("inf")),
        True,
        seed=3,
    )


def test_cpu_autograd_function_rows_match_the_float64_reference_to_bfloat16() -> None:
    """``vm_rows`` writes bfloat16 rows and reads a bfloat16 gradient: 8 bits of mantissa, 1e-2 relative."""
    _kernel_or_skip()

    def rows(p: torch.Tensor, ln: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        out = vm_kernel.vm_rows(p, ln, x, 16)
        assert out.dtype == torch.bfloat16 and out[12:].eq(0).all()
        return out[:12].view(12, 3, -1)

    _against_float64(rows, False, seed=4, atol=2e-2, rtol=1e-2)


@pytest.mark.parametrize("summed", [False, True])
def test_triton_custom_op_matches_the_float64_reference(summed: bool) -> None:
    if not vm_triton.applies(torch.zeros(1), torch.zeros(1)):
        pytest.skip("Triton does not run here")
    _against_float64(lambda p, ln, x: vm_triton.triton_vm(p, ln, x, summed), summed, seed=5)


def _bad_factors() -> list[tuple[str, dict[str, torch.Tensor], str]]:
    p, ln, x = (t.float() for t in _factors(6))
    return [
        ("points (M, 2)", {"xyz": x[:, :2].contiguous()}, "xyz"),  # read past the points' end before
        ("line length", {"lines": torch.zeros(3, 3, 7, 1)}, "lines"),
        ("line channels", {"lines": torch.zeros(3, 2, 5, 1)}, "lines"),
        ("two planes", {"planes": p[:2], "lines": ln[:2]}, "planes"),
        ("float64 planes", {"planes": p.double()}, "planes"),
    ]


@pytest.mark.parametrize("case", range(5), ids=[c[0] for c in _bad_factors()])
def test_the_kernels_refuse_factors_they_would_misread(case: int) -> None:
    """The C++ and Triton kernels index by the sizes they assume: a bad shape was read out of bounds."""
    _, change, param = _bad_factors()[case]
    p, ln, x = (t.float() for t in _factors(6))
    args = {"planes": p, "lines": ln, "xyz": x, **change}
    calls = []
    if vm_kernel.available():
        calls += [
            lambda: vm_kernel.vm_lookup(args["planes"], args["lines"], args["xyz"]),
            lambda: vm_kernel.vm_rows(args["planes"], args["lines"], args["xyz"], 16),
            lambda: vm_kernel.vm_sum_until(
                args["planes"],
                args["lines"],
                args["xyz"],
                torch.tensor([0, 12]),
                torch.ones(12),
                0.0,
                1.0,
                1.0,
            ),
        ]
    if vm_triton.applies(torch.zeros(1), torch.zeros(1)):
        calls.append(lambda: vm_triton.triton_vm(args["planes"], args["lines"], args["xyz"]))
    if not calls:
        pytest.skip("neither kernel runs here")
    for call in calls:
        with pytest.raises(InputError, match=param) as err:
            call()
        assert param in err.value.params


@pytest.mark.parametrize("rows", [11, 16.0])
def test_rows_fewer_than_the_points_or_not_an_integer_are_refused_by_name(rows: object) -> None:
    """The kernel's own check (fewer rows than points) was a RuntimeError naming no parameter."""
    _kernel_or_skip()
    p, ln, x = (t.float() for t in _factors(7))
    with pytest.raises(InputError, match="rows must be an integer ≥ the 12 points") as err:
        vm_kernel.vm_rows(p, ln, x, rows)  # type: ignore[arg-type]
    assert "rows" in err.value.params


class _Counting:
    """The built kernel module, counting calls of its ``backward`` (the factors') and ``point_backward``."""

    def __init__(self, module: object) -> None:
        self.module, self.calls = module, {"backward": 0, "point_backward": 0}

    def __getattr__(self, name: str) -> object:
        if name in self.calls:
            self.calls[name] += 1
        return getattr(self.module, name)


@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "aot_eager"])
def test_the_cpu_kernels_backward_passes_run_only_for_the_inputs_that_want_a_gradient(
    compiled: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``ctx.needs_input_grad`` in the ops' backward (``torch.library`` and ``autograd.Function``), eager and
    traced by AOTAutograd: points without a gradient (no pose refinement) cost no point pass, and frozen
    factors (``eval``'s test-time pose fit: only the points want a gradient) no scatter into the factors'
    gradients, which were thrown away; the points get grid_sample's gradient either way."""
    _kernel_or_skip()
    counting = _Counting(vm_kernel.load())
    monkeypatch.setattr(vm_kernel, "load", lambda: counting)
    offsets, deltas = torch.tensor([0, 5, 5, 12]), torch.full((12,), 0.1)
    lookups: dict[str, Callable] = {
        "lookup": lambda p, ln, x: vm_kernel.vm_lookup(p, ln, x).square().sum(),
        "summed": lambda p, ln, x: vm_kernel.vm_lookup(p, ln, x, True).square().sum(),
        "until": lambda p, ln, x: (
            vm_kernel.vm_sum_until(p, ln, x, offsets, deltas, 0.0, 1.0, 1e9).square().sum()
        ),
        "rows": lambda p, ln, x: vm_kernel.vm_rows(p, ln, x, 16).float().square().sum(),
    }
    p64, l64, x64 = _factors(9)
    for name, lookup in lookups.items():
        fn = torch.compile(lookup, backend="aot_eager", fullgraph=name != "rows") if compiled else lookup
        for factors, points in ((True, False), (True, True), (False, True)):
            torch._dynamo.reset()
            p32, l32 = (t.float().requires_grad_(factors) for t in (p64, l64))
            x32 = x64.float().requires_grad_(points)
            before = dict(counting.calls)
            wanted = [t for t in (p32, l32, x32) if t.requires_grad]
            grads = torch.autograd.grad(fn(p32, l32, x32), wanted)
            ran = {k: counting.calls[k] - before[k] for k in before}
            assert ran == {"backward": int(factors), "point_backward": int(points)}, (name, factors, points)
            if points:  # the value's gradient for the points: 2·v·∂v/∂x of grid_sample's
                x_ref = x64.clone().requires_grad_()
                ref = sample_vm(p64, l64, x_ref).permute(2, 0, 1)
                ref = ref.sum(dim=(1, 2)) if name in ("summed", "until") else ref
                expect = torch.autograd.grad(ref.square().sum(), x_ref)[0]
                tol = 3e-2 if name == "rows" else 1e-4
                torch.testing.assert_close(
                    grads[-1].double(), expect, rtol=tol, atol=tol * expect.abs().max()
                )


def _lookups() -> list[Callable]:
    found = [vm_kernel.vm_lookup] if vm_kernel.available() else []
    if vm_triton.applies(torch.zeros(1), torch.zeros(1)):
        found.append(vm_triton.triton_vm)
    if not found:
        pytest.skip("neither kernel runs here")
    return found


@pytest.mark.parametrize("res", [2, 5])
@pytest.mark.parametrize("summed", [False, True])
def test_the_points_gradient_on_texel_knots_the_grids_edges_and_beyond_equals_grid_sample(
    res: int, summed: bool
) -> None:
    """grid_sample's slope is one-sided where a coordinate lies on a texel (the cell above it) and 0 where
    both texels lie outside: every combination of coordinates on knots, at ±1, within a texel outside the
    grid (one texel inside) and beyond, exactly representable, on 2 texels (one cell) and 5, both kernels."""
    half = 0.5 * (res - 1)
    cells = [-2.5, -2, -1, -0.5, 0, 0.25, res - 2, res - 1, res - 0.75, res, res + 1.5]
    coords = sorted({u / half - 1 for u in cells})
    points = torch.cartesian_prod(*[torch.tensor(coords, dtype=D)] * 3)
    planes, lines, _ = _factors(10, channels=3, res=res)
    x64 = points.clone().requires_grad_()
    ref = sample_vm(planes, lines, x64).permute(2, 0, 1)
    ref = ref.sum(dim=(1, 2)) if summed else ref
    grad = torch.randn(ref.shape, generator=torch.Generator().manual_seed(11), dtype=D)
    expect = torch.autograd.grad(ref, x64, grad)[0]
    for lookup in _lookups():
        x32 = points.float().requires_grad_()
        got = torch.autograd.grad(lookup(planes.float(), lines.float(), x32, summed), x32, grad.float())[0]
        torch.testing.assert_close(got.double(), expect, rtol=1e-5, atol=1e-5, msg=lookup.__name__)


@pytest.mark.parametrize("summed", [False, True])
def test_no_points_that_want_a_gradient_get_an_empty_one(summed: bool) -> None:
    planes, lines, _ = (t.float() for t in _factors(12))
    for lookup in _lookups():
        none = torch.zeros(0, 3, requires_grad=True)
        out = lookup(planes, lines, none, summed)
        assert torch.autograd.grad(out.sum(), none)[0].shape == (0, 3)

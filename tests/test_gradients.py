"""Gradient guards: the spike loss reaches the field through the Trainer's own step; float64 gradchecks of
the interval spike loss and of the compositing weights; a training loop without per-step host reads; bf16."""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

import pytest
import torch

import test_train
from spikenerf.render.volume import packed_weights, weights_from_density
from spikenerf.train.losses import spike_interval_loss
from spikenerf.train.trainer import Trainer

_config = test_train._config
dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures


def _field_grads(dataset_dir: Path, dataset, out: Path, lam: float) -> dict[str, torch.Tensor]:  # type: ignore[no-untyped-def]
    """The field's gradients left by ONE ``Trainer.train`` step with the spike loss at full weight λ."""
    cfg = _config(dataset_dir, method="spike-nerf", spike={"lam": lam, "warmup_iters": 0, "ramp_iters": 0})
    trainer = Trainer(cfg, out, dataset, progress=False)
    trainer.train(stop_after=1)  # the loop zeroes gradients before backward, so they survive the step
    return {n: p.grad.clone() for n, p in trainer.model.named_parameters() if p.grad is not None}


def test_spike_loss_reaches_the_field_through_the_trainer_step(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """Same seeds, λ = 1 vs λ = 0: the gradients differ by λ·∇L_spike, which must be non-zero on the grid.

    A ``.detach()`` anywhere between the rendered intensity and the spike loss makes the two runs leave the
    same gradients (the reconstruction part is identical), so this test fails.
    """
    base = _field_grads(dataset_dir, dataset, tmp_path / "a", 0.0)
    again = _field_grads(dataset_dir, dataset, tmp_path / "b", 0.0)
    spike = _field_grads(dataset_dir, dataset, tmp_path / "c", 1.0)
    assert base.keys() == again.keys() == spike.keys()
    assert all(torch.equal(base[k], again[k]) for k in base)  # λ = 0 twice: exactly the same step
    grid = [k for k in base if "planes" in k or "lines" in k]
    diff = sum(float((spike[k] - base[k]).abs().sum()) for k in grid)
    scale = sum(float(base[k].abs().sum()) for k in grid)
    assert grid and diff > 1e-3 * scale


def test_gradcheck_interval_spike_loss() -> None:
    gen = torch.Generator().manual_seed(0)
    intensity = (torch.rand(6, 3, 2, generator=gen, dtype=torch.float64) * 1.6).requires_grad_()
    spikes = torch.rand(6, 3, 2, generator=gen) < 0.4
    for pairs in ("all", "window"):
        assert torch.autograd.gradcheck(
            lambda x, p=pairs: spike_interval_loss(x, spikes, 0.8, p), (intensity,)
        )
    assert torch.autograd.gradcheck(
        lambda x: spike_interval_loss(x, spikes, 0.8, max_intensity=None), (intensity,)
    )


def test_gradcheck_compositing_weights_dense_and_packed() -> None:
    gen = torch.Generator().manual_seed(1)
    sigma = (torch.rand(3, 5, generator=gen, dtype=torch.float64) * 4).requires_grad_()
    deltas = (torch.rand(3, 5, generator=gen, dtype=torch.float64) * 0.5).requires_grad_()
    assert torch.autograd.gradcheck(weights_from_density, (sigma, deltas))
    # packed: rays of 5, 0, 2 and 1 samples
    ray = torch.tensor([0, 0, 0, 0, 0, 2, 2, 3])
    s, d = sigma.detach().reshape(-1)[:8].clone(), deltas.detach().reshape(-1)[:8].clone()
    assert torch.autograd.gradcheck(
        lambda a, b: packed_weights(a, b, ray, 4), (s.requires_grad_(), d.requires_grad_())
    )


def test_packed_weights_equal_the_padded_ones() -> None:
    gen = torch.Generator().manual_seed(2)
    sigma, deltas = torch.rand(4, 7, generator=gen) * 30, torch.rand(4, 7, generator=gen) * 0.1
    counts = torch.tensor([7, 0, 3, 5])
    keep = torch.arange(7)[None] < counts[:, None]
    dense = weights_from_density(sigma * keep, deltas)
    ray = torch.repeat_interleave(torch.arange(4), counts)
    packed = packed_weights(sigma[keep], deltas[keep], ray, 4)
    assert torch.allclose(packed, dense[keep], atol=1e-6)


def test_an_infinite_density_leaves_the_other_rays_weights_finite() -> None:
    """One ``inf`` (or NaN) sample in ray 0: before the clamped scan, ``inf − inf`` made every ray NaN."""
    gen = torch.Generator().manual_seed(4)
    sigma, deltas = torch.rand(3, 4, generator=gen) * 5, torch.rand(3, 4, generator=gen) * 0.2 + 0.01
    ray = torch.arange(3).repeat_interleave(4)
    for bad in (float("inf"), float("nan")):
        sigma[0, 1] = bad
        packed = packed_weights(sigma.reshape(-1), deltas.reshape(-1), ray, 3).view(3, 4)
        assert torch.isfinite(packed[1:]).all()
        assert torch.allclose(packed[1:], weights_from_density(sigma[1:], deltas[1:]), atol=1e-6)
        assert packed[0, 0] == weights_from_density(sigma[:1], deltas[:1])[0, 0]  # before the bad sample
        assert packed[0, 2:].eq(0).all()  # after it: transmittance 0


@pytest.mark.parametrize("method", ["spike-nerf", "spike-integral"])
def test_training_loop_reads_no_tensor_value_per_step(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch, method: str
) -> None:  # type: ignore[no-untyped-def]
    """``.item()`` is a host–device sync on a GPU: the loop reads values back only every log_every steps."""
    cfg = _config(dataset_dir, method=method)
    cfg.iters, cfg.eval_every, cfg.ckpt_every = 20, 0, 100
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    trainer.evaluate = lambda: float("nan")  # type: ignore[method-assign]
    calls = []
    item = torch.Tensor.item
    monkeypatch.setattr(torch.Tensor, "item", lambda self: calls.append(1) or item(self))
    trainer.train(stop_after=19)
    assert len(calls) <= 2  # the final train PSNR; before: 2 per iteration


def test_amp_bf16_trains_on_a_cpu(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    cfg = _config(dataset_dir, method="spike-nerf", amp="bf16")
    summary = Trainer(cfg, tmp_path / "run", dataset, progress=False).train()
    assert summary.iteration == 6 and torch.isfinite(torch.tensor(summary.test_psnr))
    with pytest.raises(Exception, match="amp must be one of"):
        _config(dataset_dir, amp="fp8").validate()


def test_fused_vm_kernel_matches_grid_sample_forward_and_backward() -> None:
    from spikenerf.fields import vm_kernel
    from spikenerf.fields.vm_sample import sample_vm

    if not vm_kernel.available():
        pytest.skip("no C++ compiler for the fused VM kernel")
    gen = torch.Generator().manual_seed(3)
    planes = torch.randn(3, 5, 9, 9, generator=gen, requires_grad=True)
    lines = torch.randn(3, 5, 9, 1, generator=gen, requires_grad=True)
    xyz = torch.rand(300, 3, generator=gen) * 2 - 1
    xyz[:4] = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0, -1.0, 0.0], [0.0, 1.0, -1.0]])  # edges
    # outside the box (zeros padding as grid_sample: half a texel out, one texel out, far out)
    xyz[4:8] = torch.tensor([[1.1, 0.0, 0.3], [-1.1, -1.2, 0.5], [1.26, 0.2, -1.3], [5.0, -7.0, 0.0]])
    ref = sample_vm(planes, lines, xyz).permute(2, 0, 1)
    out = vm_kernel.vm_lookup(planes, lines, xyz)
    assert torch.allclose(out, ref, atol=1e-5)
    grad = torch.randn(ref.shape, generator=gen)
    for a, b in zip(
        torch.autograd.grad(ref, (planes, lines), grad),
        torch.autograd.grad(out, (planes, lines), grad),
        strict=True,
    ):
        assert torch.allclose(a, b, atol=1e-4)
    # points that want a gradient (pose refinement) take the kernel too, and get grid_sample's gradient
    assert vm_kernel.usable(planes, xyz.clone().requires_grad_())
    inner = xyz[8:].clone().requires_grad_()  # off the box's edges, where grid_sample's slope is one-sided
    grad = torch.randn(inner.shape[0], 3, planes.shape[1], generator=gen)
    expect = torch.autograd.grad(sample_vm(planes, lines, inner).permute(2, 0, 1), inner, grad)[0]
    got = torch.autograd.grad(vm_kernel.vm_lookup(planes, lines, inner), inner, grad)[0]
    assert torch.allclose(got, expect, atol=1e-3, rtol=1e-4)


def test_the_summed_fused_lookup_is_the_sum_of_the_products_forward_and_backward() -> None:
    """``summed=True`` (the density): the kernel sums over axis pairs and channels itself; values and
    gradients are those of the (M, 3, C) products summed, on 1 and 2 threads (> 4096 points) and outside
    the grid."""
    from spikenerf.fields.vm_sample import sample_vm

    vm_kernel = _kernel_or_skip()
    gen = torch.Generator().manual_seed(11)
    planes = torch.randn(3, 6, 10, 10, generator=gen, requires_grad=True)
    lines = torch.randn(3, 6, 10, 1, generator=gen, requires_grad=True)
    xyz = torch.rand(9000, 3, generator=gen) * 2.4 - 1.2  # some points outside [-1, 1]
    ref = sample_vm(planes, lines, xyz).permute(2, 0, 1).sum(dim=(1, 2))
    grad = torch.randn(ref.shape, generator=gen)
    grad[::3] = 0.0  # points the backward skips (behind a ray's early stop)
    want = torch.autograd.grad(ref, (planes, lines), grad)
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            out = vm_kernel.vm_lookup(planes, lines, xyz, summed=True)
            assert out.shape == (9000,) and torch.allclose(out, ref, atol=1e-4)
            got = torch.autograd.grad(out, (planes, lines), grad)
            assert all(torch.allclose(a, b, rtol=1e-4, atol=1e-3) for a, b in zip(got, want, strict=True))
    finally:
        torch.set_num_threads(threads)
    # gradcheck in float32 is too coarse: compare with the unsummed kernel's gradients of the same sum
    small = xyz[:50]
    summed = torch.autograd.grad(
        vm_kernel.vm_lookup(planes, lines, small, summed=True).sum(), (planes, lines)
    )
    full = torch.autograd.grad(vm_kernel.vm_lookup(planes, lines, small).sum(), (planes, lines))
    assert all(torch.allclose(a, b, atol=1e-5) for a, b in zip(summed, full, strict=True))


def test_the_grid_density_takes_the_summed_kernel_and_equals_grid_sample(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.fields import grid as grid_module

    vm_kernel = _kernel_or_skip()
    field = grid_module.GridField(1, torch.tensor([[-1.0, -1, -1], [1, 1, 1]]))
    x = torch.rand(700, 3) * 2 - 1
    calls: list[bool] = []
    lookup = vm_kernel.vm_lookup
    monkeypatch.setattr(
        grid_module, "vm_lookup", lambda *a, **k: calls.append(k.get("summed", False)) or lookup(*a, **k)
    )
    fused = field.density_norm(x)
    assert calls == [True]
    with vm_kernel.suspended():
        plain = field.density_norm(x)  # grid_sample, summed by torch
    assert torch.allclose(fused, plain, rtol=1e-5, atol=1e-6)


def _kernel_or_skip():  # type: ignore[no-untyped-def]
    from spikenerf.fields import vm_kernel

    if not vm_kernel.available():
        pytest.skip("no C++ compiler for the fused VM kernel")
    return vm_kernel


def test_the_fused_kernels_custom_ops_pass_opcheck_and_compile_as_one_graph() -> None:
    """The kernel is a torch.library op pair: schema, fake tensors and autograd pass ``opcheck``, and the
    grid's density and colour trace as one graph with it (no break) and give the eager values and
    gradients."""
    from spikenerf.fields.grid import GridField

    vm_kernel = _kernel_or_skip()
    gen = torch.Generator().manual_seed(5)
    p = torch.randn(3, 7, 7, 4, generator=gen, requires_grad=True)  # channels-last (3, R, R, C)
    ln = torch.randn(3, 7, 4, generator=gen, requires_grad=True)  # (3, R, C)
    xyz = torch.rand(50, 3, generator=gen) * 2.2 - 1.1
    for summed in (False, True):
        torch.library.opcheck(torch.ops.spikenerf.vm_cpu_forward.default, (p, ln, xyz, summed))
        points = xyz.clone().requires_grad_()  # pose refinement's case: the point backward op too
        torch.library.opcheck(torch.ops.spikenerf.vm_cpu_forward.default, (p, ln, points, summed))
        frozen = p.detach(), ln.detach(), points  # eval's pose fit: only the points want a gradient
        torch.library.opcheck(torch.ops.spikenerf.vm_cpu_forward.default, (*frozen, summed))

    field = GridField(1, torch.tensor([[-1.0, -1, -1], [1, 1, 1]]))
    dirs = torch.nn.functional.normalize(torch.randn(300, 3, generator=gen), dim=-1)
    x = torch.rand(300, 3, generator=gen) * 2 - 1
    assert vm_kernel.usable(field.density_planes, x)

    def both(x: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        return field.density_norm(x).sum() + field.color_norm(x, dirs).sum()

    torch._dynamo.reset()
    explained = torch._dynamo.explain(both)(x, dirs)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons
    params = [field.density_planes, field.density_lines, field.app_planes, field.app_lines]
    got = torch.compile(both, backend="aot_eager", fullgraph=True)(x, dirs)
    expected = both(x, dirs)
    torch.testing.assert_close(got, expected)
    for g, e in zip(torch.autograd.grad(got, params), torch.autograd.grad(expected, params), strict=True):
        torch.testing.assert_close(g, e)
    torch._dynamo.reset()


def test_fused_vm_kernel_nan_point_gives_nan_not_a_crash() -> None:
    """A NaN coordinate used to become a wild index (segfault); now NaN exactly where grid_sample has NaN."""
    from spikenerf.fields.vm_sample import sample_vm

    vm_kernel = _kernel_or_skip()
    planes, lines = torch.randn(3, 4, 6, 6, requires_grad=True), torch.randn(3, 4, 6, 1, requires_grad=True)
    nan, inf = float("nan"), float("inf")
    xyz = torch.tensor([[nan, 0.1, 0.2], [0.3, nan, -0.5], [1e30, -1e30, 0], [inf, 0, -inf], [0.2, 0.1, 0]])
    ref = sample_vm(planes, lines, xyz).permute(2, 0, 1)
    out = vm_kernel.vm_lookup(planes, lines, xyz)
    assert torch.equal(out.isnan(), ref.isnan())
    assert torch.allclose(out, ref, atol=1e-5, equal_nan=True)
    out.sum().backward()  # no crash in the scatter either
    points = xyz.clone().requires_grad_()
    got = torch.autograd.grad(vm_kernel.vm_lookup(planes, lines, points).sum(), points)[0]
    expect = torch.autograd.grad(sample_vm(planes, lines, points).sum(), points)[0]
    bad = expect.isnan().any(dim=1)  # NaN in the points' gradient at the same points (grid_sample gives a
    assert torch.equal(got.isnan().any(dim=1), bad)  # NaN coordinate's own component 0, the kernel NaN)
    assert torch.allclose(got[~bad], expect[~bad], atol=1e-4)


def test_the_grid_fields_point_gradients_take_the_kernel_and_equal_grid_sample(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Pose refinement moves the sample points: density and colour (the bf16 rows where the CPU has them)
    give the points grid_sample's gradient through the kernel, eager and compiled. Before, a point that
    wanted a gradient sent every lookup to grid_sample (about 3× slower steps on an imported recording)."""
    from spikenerf.fields import grid as grid_module

    vm_kernel = _kernel_or_skip()
    gen = torch.Generator().manual_seed(8)
    field = grid_module.GridField(1, torch.tensor([[-1.0, -1, -1], [1, 1, 1]]))
    with torch.no_grad():
        for factor in (field.density_planes, field.density_lines, field.app_planes, field.app_lines):
            factor.normal_(generator=gen)
    dirs = torch.nn.functional.normalize(torch.randn(400, 3, generator=gen), dim=-1)
    x = torch.rand(400, 3, generator=gen) * 1.9 - 0.95
    calls: list[bool] = []
    rows = grid_module.vm_rows
    monkeypatch.setattr(grid_module, "vm_rows", lambda *a: calls.append(True) or rows(*a))
    monkeypatch.setattr(grid_module, "sample_vm", None)  # the kernel must serve every lookup

    def point_grad(fn):  # type: ignore[no-untyped-def]
        points = x.clone().requires_grad_()
        value = fn(points, dirs)
        return value, torch.autograd.grad(value, points)[0]

    def both(points: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        return field.density_norm(points).sum() + field.color_norm(points, d).square().sum()

    fused, fused_grad = point_grad(both)
    assert bool(calls) == grid_module.native_bf16(x.device)  # the bf16 rows where this CPU has bf16
    torch._dynamo.reset()
    compiled, compiled_grad = point_grad(torch.compile(both, backend="aot_eager", fullgraph=True))
    torch._dynamo.reset()
    monkeypatch.undo()
    with vm_kernel.suspended():
        plain, plain_grad = point_grad(both)
    bf16 = 2e-2 if grid_module.native_bf16(x.device) else 1e-4  # the colour decoder's bf16 rows
    for value, grad in ((fused, fused_grad), (compiled, compiled_grad)):
        torch.testing.assert_close(value, plain, rtol=bf16, atol=bf16)
        torch.testing.assert_close(grad, plain_grad, rtol=bf16, atol=bf16 * plain_grad.abs().max().item())


def test_a_kernel_pair_without_a_point_backward_refuses_points_that_want_one() -> None:
    """(The Triton pair's case: its gradient for the points would be None, silently 0.)"""
    from spikenerf.core.errors import InputError
    from spikenerf.fields.vm_ops import register_pair

    call = register_pair(
        "test_no_points",
        lambda p, ln, x, summed: x.new_zeros((x.shape[0],) if summed else (x.shape[0], 3, p.shape[-1])),
        lambda p, ln, x, g: (torch.zeros_like(p), torch.zeros_like(ln)),
    )
    p, ln = torch.zeros(3, 4, 4, 2, requires_grad=True), torch.zeros(3, 4, 2, requires_grad=True)
    assert call(p, ln, torch.zeros(5, 3), False).shape == (5, 3, 2)
    with pytest.raises(InputError, match="no gradient for the points") as err:
        call(p, ln, torch.zeros(5, 3, requires_grad=True), True)
    assert err.value.params == ("xyz",)


def test_fused_vm_kernel_multithread_backward_matches_grid_sample() -> None:
    """> 4096 points on 2 threads: each thread's band of plane rows and the sum of the line buffers."""
    from spikenerf.fields.vm_sample import sample_vm

    vm_kernel = _kernel_or_skip()
    gen = torch.Generator().manual_seed(5)
    planes = torch.randn(3, 4, 8, 8, generator=gen, requires_grad=True)
    lines = torch.randn(3, 4, 8, 1, generator=gen, requires_grad=True)
    xyz = torch.rand(9000, 3, generator=gen) * 2 - 1
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        out = vm_kernel.vm_lookup(planes, lines, xyz)
        got = torch.autograd.grad(out, (planes, lines), torch.ones_like(out))
    finally:
        torch.set_num_threads(threads)
    ref = sample_vm(planes, lines, xyz).permute(2, 0, 1)
    want = torch.autograd.grad(ref, (planes, lines), torch.ones_like(ref))
    assert torch.allclose(out, ref, atol=1e-5)
    assert all(torch.allclose(a, b, rtol=1e-4, atol=1e-3) for a, b in zip(got, want, strict=True))


@pytest.mark.parametrize("summed", [False, True])
def test_fused_vm_kernel_backward_has_the_same_plane_gradient_on_any_number_of_threads(summed: bool) -> None:
    """The backward gives each thread a band of plane rows: every plane gradient element is summed in point
    order by one thread, so 1, 2 and 3 threads give the same bits (the line gradients, summed over the
    threads' buffers, agree to rounding; the points' gradient, each point's own, the same bits too), and
    ``grid_sample``'s gradients, with points crowded into a few rows, points on texel rows (band edges) and
    outside the grid, and, for the density, a zero gradient at every third point."""
    from spikenerf.fields.vm_sample import sample_vm

    vm_kernel = _kernel_or_skip()
    gen = torch.Generator().manual_seed(8)
    r = 12
    planes = torch.randn(3, 5, r, r, generator=gen, requires_grad=True)
    lines = torch.randn(3, 5, r, 1, generator=gen, requires_grad=True)
    spread = torch.rand(7000, 3, generator=gen) * 2.2 - 1.1
    few_rows = torch.tensor([2.0, 0.1, 0.1])  # y and z within about one texel
    crowded = torch.rand(4000, 3, generator=gen) * few_rows - torch.tensor([1.0, 0.3, 0.3])
    on_rows = -1 + 2 * torch.randint(0, r, (2000, 3), generator=gen) / (r - 1)
    xyz = torch.cat([spread, crowded, on_rows])[torch.randperm(13000, generator=gen)]
    ref = sample_vm(planes, lines, xyz).permute(2, 0, 1)
    if summed:
        ref = ref.sum(dim=(1, 2))
    grad = torch.randn(ref.shape, generator=gen)
    if summed:
        grad[::3] = 0.0
    want = torch.autograd.grad(ref, (planes, lines), grad)
    points = xyz.clone().requires_grad_()  # the points' gradient (pose refinement): each point its own
    ref_points = sample_vm(planes, lines, points).permute(2, 0, 1)
    ref_points = ref_points.sum(dim=(1, 2)) if summed else ref_points
    want_points = torch.autograd.grad(ref_points, points, grad)[0]
    threads, got = torch.get_num_threads(), {}
    try:
        for n in (1, 2, 3):
            torch.set_num_threads(n)
            out = vm_kernel.vm_lookup(planes, lines, points, summed=summed)
            got[n] = torch.autograd.grad(out, (planes, lines, points), grad)
    finally:
        torch.set_num_threads(threads)
    for n in (2, 3):
        assert torch.equal(got[n][0], got[1][0]), f"plane gradient on {n} threads"
        assert torch.allclose(got[n][1], got[1][1], rtol=1e-5, atol=1e-4)
        assert torch.equal(got[n][2], got[1][2]), f"points' gradient on {n} threads"
    assert all(torch.allclose(a, b, rtol=1e-4, atol=1e-3) for a, b in zip(got[1][:2], want, strict=True))
    torch.testing.assert_close(got[1][2], want_points, rtol=1e-4, atol=1e-3)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="built with OpenMP on Linux only")
def test_fused_vm_kernel_runs_on_every_torch_thread() -> None:
    """The kernel is built with OpenMP: without ``-fopenmp`` its ``at::parallel_for`` ran on one thread."""
    vm_kernel = _kernel_or_skip()
    threads = torch.get_num_threads()
    try:
        for n in (1, 2, 3):
            torch.set_num_threads(n)
            assert vm_kernel.parallel_threads(64) == n
    finally:
        torch.set_num_threads(threads)


def test_fused_vm_kernel_build_without_openmp_then_grid_sample(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A compiler that cannot build with OpenMP: one warning, a single-threaded build; if that fails too,
    grid_sample with the error in the warning."""
    from spikenerf.fields import vm_build

    fail_plain = [False]

    def build(cflags: list[str], ldflags: list[str]) -> object:
        if cflags or fail_plain[0]:
            raise RuntimeError("omp.h: No such file" if cflags else "no compiler")
        return "single-threaded module"

    monkeypatch.setattr(vm_build, "_build", build)
    monkeypatch.setattr(vm_build, "_OPENMP_CFLAGS", ["-fopenmp"])
    monkeypatch.delenv("SPIKENERF_VM_KERNEL", raising=False)
    for fail, want, words in [
        (False, "single-threaded module", "without OpenMP.*omp.h"),
        (True, None, "grid_sample.*no compiler"),
    ]:
        fail_plain[0] = fail
        monkeypatch.setattr(vm_build, "_MODULE", None)
        monkeypatch.setattr(vm_build, "_FAILED", False)
        with warnings.catch_warnings():  # pytest.warns re-emits the other (expected) one
            warnings.simplefilter("ignore")
            with pytest.warns(UserWarning, match=words):
                assert vm_build.load() == want


def test_without_a_compiler_the_kernel_is_not_built_and_says_so_once(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """No C++ compiler and nothing built: one warning naming the compiler, no build attempted (torch's build
    printed about 20 lines, twice, in every command); a module already built loads without one."""
    from spikenerf.fields import vm_build

    monkeypatch.setattr(vm_build, "_build", lambda *a: pytest.fail("a build was attempted"))
    monkeypatch.setattr(vm_build.shutil, "which", lambda name, **kw: None)
    monkeypatch.setenv("CXX", "g++-none")
    monkeypatch.delenv("SPIKENERF_VM_KERNEL", raising=False)
    monkeypatch.setattr(vm_build, "_built_any", lambda: False)
    monkeypatch.setattr(vm_build, "_MODULE", None)
    monkeypatch.setattr(vm_build, "_FAILED", False)
    with pytest.warns(
        UserWarning, match=r"no C\+\+ compiler \(g\+\+-none\) to build it: using grid_sample"
    ) as got:
        assert vm_build.load() is None
        assert vm_build.load() is None  # remembered: no second warning
    assert len(got) == 1
    monkeypatch.setattr(vm_build, "_FAILED", False)
    monkeypatch.setenv("CXX", "ccache g++ -O2")  # a wrapper: either of its first two words will do
    monkeypatch.setattr(
        vm_build.shutil, "which", lambda name, **kw: "/usr/bin/g++" if name == "g++" else None
    )
    monkeypatch.setattr(vm_build, "_build", lambda *a: "built")
    assert vm_build.load() == "built"
    monkeypatch.undo()
    import torch.utils.cpp_extension as ext

    def unwritable(name: str, verbose: bool) -> str:
        raise NotADirectoryError(20, "Not a directory", "/tmp/file/ext")

    monkeypatch.setattr(ext, "_get_build_directory", unwritable)
    assert vm_build._built_any() is False  # an unwritable cache: nothing built, not an error


_LOAD_KERNEL = """
import sys, time, warnings
warnings.simplefilter("error")
t = time.monotonic()
from spikenerf.fields import vm_kernel
assert vm_kernel.available(), "the fused kernel was not loaded"
print(round(time.monotonic() - t, 3))
"""


def _kernel_build_dir() -> Path:
    from torch.utils.cpp_extension import _get_build_directory

    from spikenerf.fields import vm_build

    for cflags, ldflags in ((vm_build._OPENMP_CFLAGS, vm_build._OPENMP_LDFLAGS), ([], [])):
        name = vm_build._name(vm_build._CFLAGS + cflags, ldflags)
        folder = Path(_get_build_directory(name, verbose=False))
        if (folder / f"{name}.so").exists():
            return folder
    pytest.skip("the fused kernel is not built")


def test_fused_vm_kernel_loads_at_once_back_to_back_and_past_lock_files() -> None:
    """Two processes one after the other, each with torch's ``lock`` file left in the build folder (torch
    ≥ 2.14 keeps it after every build) and a build-lock file no live process holds: each loads the compiled
    kernel within seconds, with no warning (the old rule waited 600 s on such a file, then fell back)."""
    import subprocess
    import sys

    _kernel_or_skip()
    folder = _kernel_build_dir()
    for _ in range(2):
        (folder / "lock").touch()
        (folder / "spikenerf-build.lock").touch()
        run = subprocess.run(
            [sys.executable, "-c", _LOAD_KERNEL], capture_output=True, text=True, timeout=120
        )
        assert run.returncode == 0, run.stderr
        assert float(run.stdout.split()[-1]) < 10.0
        assert "building" not in run.stderr  # the cached module was imported, not rebuilt


def test_fused_vm_kernel_waits_for_a_live_builder_only(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A live process holding the build lock is waited for (then grid_sample with one warning); once that
    process is killed, its lock is free at once."""
    import subprocess
    import sys
    import time

    import torch.utils.cpp_extension as ext

    from spikenerf.fields import vm_build, vm_kernel

    holder = subprocess.Popen(
        [sys.executable, "-c", "import fcntl, sys, time; f = open(sys.argv[1], 'w');"
         " fcntl.flock(f, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)",
         str(tmp_path / "spikenerf-build.lock")],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        monkeypatch.setattr(ext, "_get_build_directory", lambda name, verbose: str(tmp_path))
        monkeypatch.setattr(vm_build, "BUILD_WAIT_S", 0.5)
        monkeypatch.setattr(vm_build, "_MODULE", None)
        monkeypatch.setattr(vm_build, "_FAILED", False)
        monkeypatch.delenv("SPIKENERF_VM_KERNEL", raising=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with pytest.warns(UserWarning, match="held .*spikenerf-build.lock"):
                assert not vm_kernel.available()
        with pytest.raises(RuntimeError, match="unavailable"):  # vm_lookup without the kernel: a clear error
            vm_kernel.vm_lookup(torch.zeros(3, 1, 2, 2), torch.zeros(3, 1, 2, 1), torch.zeros(1, 3))
    finally:
        holder.kill()
        holder.wait()
    start = time.monotonic()
    with vm_build._build_lock(tmp_path, wait_s=5.0) as locked:  # the dead holder's flock is gone
        assert locked
    assert time.monotonic() - start < 1.0


def test_fused_vm_kernel_build_finds_the_ninja_of_the_pip_package(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """torch runs ``ninja`` by name: with none on PATH (a venv that is not activated) the build puts the
    pip package's on it; a ninja already on PATH is left first."""
    import shutil

    ninja = pytest.importorskip("ninja")
    from spikenerf.fields import vm_build

    if shutil.which("ninja", path=ninja.BIN_DIR) is None:
        pytest.skip(f"the ninja package of another environment: no executable in {ninja.BIN_DIR}")

    monkeypatch.setenv("PATH", "/nonexistent")
    assert shutil.which("ninja") is None
    vm_build._find_ninja()
    found = shutil.which("ninja")
    assert found is not None and Path(found).parent == Path(ninja.BIN_DIR)
    monkeypatch.setenv("PATH", os.pathsep.join(["/usr/bin", ninja.BIN_DIR]))
    vm_build._find_ninja()
    assert os.environ["PATH"].startswith("/usr/bin")

"""``render/volume_triton.py``: the Triton compositing kernels (``composite="triton"``) give the torch path's
depths before each sample, per-ray sums and their gradients (empty rays, rays longer than a block, NaN and
huge optical depths), the grid renderer's colour, depth, opacity and gradients on its packed and static
paths, stay one graph under ``torch.compile`` and are left aside where they cannot run (``train`` refusing
them there in one line: ``tests/test_vm_triton.py``).

Without a GPU the kernels run in Triton's CPU interpreter (``TRITON_INTERPRET=1``, set by ``conftest.py``):
it checks the indexing, masks, scans and custom ops, not GPU speed. On a CUDA host the same tests run the
compiled kernels."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import test_static_render
import test_train
from helpers import counts_graphs, triton_device
from spikenerf.core.errors import InputError
from spikenerf.fields import field_config
from spikenerf.render import volume_triton
from spikenerf.render.volume import (
    MAX_TAU,
    packed_composite,
    packed_depth_before,
    packed_weights,
    ray_offsets,
    segment_sum,
)

DEVICE = triton_device()
dataset_dir = test_train.dataset_dir  # the module's fixture


def _packed(counts: list[int], seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Optical depths (M,) of rays with ``counts`` samples, their ray (M,) and offsets (N + 1,)."""
    gen = torch.Generator().manual_seed(seed)
    ray = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    tau = torch.rand(len(ray), generator=gen) * torch.rand(len(ray), generator=gen)
    ray, tau = ray.to(DEVICE), tau.to(DEVICE)
    return tau, ray, ray_offsets(ray, len(counts))


#: empty rays, one-sample rays, a ray over two blocks (LAUNCH["BLOCK"] is 64) and one over three
COUNTS = [0, 3, 130, 1, 0, 70, 5, 200, 0]


def test_the_depth_before_each_sample_and_its_gradient_equal_the_torch_path() -> None:
    tau, ray, offsets = _packed(COUNTS)
    tau[10], tau[140], tau[200] = float("nan"), 5e3, float("inf")  # the clamp: no gradient past it
    tau.requires_grad_(True)
    expected = packed_depth_before(tau, ray, len(COUNTS), offsets)
    got = packed_depth_before(tau, ray, len(COUNTS), offsets, fused=True)
    assert expected.dtype == torch.float64 and got.dtype == torch.float32
    torch.testing.assert_close(got, expected.float(), atol=1e-5, rtol=1e-6)
    weights = torch.randn(len(tau), device=DEVICE)
    (g,) = torch.autograd.grad((got * weights).sum(), tau)
    (e,) = torch.autograd.grad((expected.float() * weights).sum(), tau)
    assert g[10] == g[140] == g[200] == 0
    torch.testing.assert_close(g, e, atol=1e-5, rtol=1e-5)


def test_the_weights_and_their_gradients_equal_the_torch_path() -> None:
    tau, ray, offsets = _packed(COUNTS, seed=1)
    sigma = (tau * 40).requires_grad_(True)
    deltas = torch.full_like(tau, 0.05).requires_grad_(True)
    expected = packed_weights(sigma, deltas, ray, len(COUNTS), offsets)
    got = packed_weights(sigma, deltas, ray, len(COUNTS), offsets, fused=True)
    torch.testing.assert_close(got, expected, atol=1e-6, rtol=1e-5)
    weights = torch.randn_like(got)
    grads = torch.autograd.grad((got * weights).sum(), (sigma, deltas))
    for g, e in zip(grads, torch.autograd.grad((expected * weights).sum(), (sigma, deltas)), strict=True):
        torch.testing.assert_close(g, e, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("columns", [None, 1, 3, 5])
def test_per_ray_sums_and_their_gradient_equal_index_add(columns: int | None) -> None:
    _, ray, offsets = _packed(COUNTS, seed=2)
    shape = (len(ray),) if columns is None else (len(ray), columns)
    values = torch.randn(shape, device=DEVICE, requires_grad=True)
    expected = values.new_zeros((len(COUNTS), *shape[1:])).index_add(0, ray, values)
    got = segment_sum(values, ray, offsets, fused=True)
    assert got.shape == expected.shape and (got[torch.tensor(COUNTS) == 0] == 0).all()
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    weights = torch.randn_like(got)
    (g,) = torch.autograd.grad((got * weights).sum(), values)
    (e,) = torch.autograd.grad((expected * weights).sum(), values)
    torch.testing.assert_close(g, e)


def test_no_samples_give_zeros_and_a_different_block_the_same_sums(monkeypatch: pytest.MonkeyPatch) -> None:
    none = torch.zeros(0, device=DEVICE, dtype=torch.long)
    offsets = ray_offsets(none, 3)
    assert packed_depth_before(torch.zeros(0, device=DEVICE), none, 3, offsets, fused=True).shape == (0,)
    assert segment_sum(torch.zeros(0, 2, device=DEVICE), none, offsets, fused=True).abs().sum() == 0
    tau, ray, offsets = _packed(COUNTS, seed=3)
    expected = packed_depth_before(tau, ray, len(COUNTS), offsets, fused=True)
    sums = segment_sum(tau[:, None].expand(-1, 2), ray, offsets, fused=True)
    monkeypatch.setattr(volume_triton, "LAUNCH", {"BLOCK": 16, "num_warps": 1})  # 130 samples: 9 blocks
    torch.testing.assert_close(packed_depth_before(tau, ray, len(COUNTS), offsets, fused=True), expected)
    torch.testing.assert_close(segment_sum(tau[:, None].expand(-1, 2), ray, offsets, fused=True), sums)


def test_packed_composite_with_a_colour_index_equals_the_torch_path() -> None:
    tau, ray, offsets = _packed(COUNTS, seed=4)
    weights = packed_weights(tau * 30, torch.full_like(tau, 0.05), ray, len(COUNTS), offsets)
    t = torch.linspace(1, 2, len(tau), device=DEVICE)
    index = (weights > 0.01).nonzero().squeeze(1)
    colors = torch.rand(len(index), 3, device=DEVICE)
    expected = packed_composite(weights, ray, len(COUNTS), t, colors, index, offsets=offsets)
    got = packed_composite(weights, ray, len(COUNTS), t, colors, index, offsets=offsets, fused=True)
    for g, e in zip(got, expected, strict=True):
        torch.testing.assert_close(g, e, atol=1e-5, rtol=1e-5)


def _composite(model, how: str) -> None:  # type: ignore[no-untyped-def]
    model.field.config = dataclasses.replace(model.field.config, composite=how)


@pytest.mark.parametrize(
    ("samples", "occupancy"), [(0, True), (test_static_render.ALL_FIT, True), (16, False)]
)
def test_the_grid_renders_as_with_torch_sums_on_its_packed_and_static_paths(
    samples: int, occupancy: bool
) -> None:
    model = test_static_render._model(occupancy).to(DEVICE)
    model.field.config = dataclasses.replace(model.field.config, static_samples=samples)
    rays = tuple(r.to(DEVICE) for r in test_static_render._rays(model))
    expected, expected_grads = test_static_render._render(model, rays)
    _composite(model, "triton")
    assert model.fused(rays[0])
    test_static_render.assert_renders_as(model, rays, expected, expected_grads)


@counts_graphs
def test_the_custom_ops_pass_opcheck_and_a_static_render_compiles_as_one_graph(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    tau, ray, offsets = _packed([2, 0, 5], seed=5)
    torch.library.opcheck(
        torch.ops.spikenerf.depth_before.default, (tau.requires_grad_(True), offsets, MAX_TAU)
    )
    values = torch.randn(len(ray), 3, device=DEVICE, requires_grad=True)
    torch.library.opcheck(torch.ops.spikenerf.segment_sum.default, (values, ray, offsets))
    monkeypatch.setattr(
        test_static_render.grid_module, "usable", lambda *_: False
    )  # the CPU kernel: no trace
    model = test_static_render._model(occupancy=True).to(DEVICE)
    model.field.config = dataclasses.replace(model.field.config, static_samples=test_static_render.ALL_FIT)
    _composite(model, "triton")
    rays = tuple(r.to(DEVICE) for r in test_static_render._rays(model, (6, 5)))
    test_static_render.assert_one_graph(model, rays)


def test_where_the_kernels_cannot_run_they_are_refused_or_left_aside(monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = field_config("grid", {"composite": "triton"})
    model = test_static_render._model(occupancy=False)
    _composite(model, "triton")
    rays = test_static_render._rays(model, (4, 3))
    with torch.no_grad():
        kernels = model.render_rays(*rays).color
    monkeypatch.setenv("TRITON_INTERPRET", "0")  # a CPU without the interpreter: the torch sums
    assert not model.fused(rays[0]) and not volume_triton.applies(torch.zeros(1))
    with torch.no_grad():
        torch.testing.assert_close(model.render_rays(*rays).color, kernels, atol=1e-6, rtol=1e-5)
    with pytest.raises(
        InputError, match=r"field_config\.composite=triton: Triton kernels need a CUDA device"
    ):
        cfg.check_device(torch.device("cpu"))
    with pytest.raises(InputError, match="composite"):
        field_config("grid", {"composite": "cuda"})


def test_a_short_training_run_with_the_triton_composite_matches_the_torch_one(
    dataset_dir: Path, tmp_path: Path
) -> None:
    """The same seed, 6 iterations with the static budget: the kernels' run ends where the torch one does
    (float32 per-ray sums against a float64 running sum: close, not bitwise)."""
    assert test_static_render.short_runs_differ(dataset_dir, tmp_path, "composite", DEVICE.type) < 0.05


def test_the_kernels_compile_for_an_h100_without_spilling(tmp_path: Path) -> None:
    """Triton's real compiler and its bundled ptxas build each compositing kernel, and each march kernel of
    ``render/march_triton.py``, for sm_90 without a GPU (``benchmarks/tools/triton_compile_report.py
    --kernels volume,march``); no registers spill."""
    pytest.importorskip("triton", minversion="3.3")  # the report builds ASTSource as Triton 3.3 does
    root = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    env |= {"PYTHONPATH": os.pathsep.join([str(root / "src"), str(root)]), "TRITON_DEFAULT_FP_FUSION": "1"}
    env["TRITON_CACHE_DIR"] = str(tmp_path / "cache")
    report = [sys.executable, "-m", "benchmarks.tools.triton_compile_report", "--kernels", "volume,march"]
    proc = subprocess.run(report, cwd=root, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = re.findall(r"^\| (depth_before|depth_before_backward|segment_sum) \| (\d*) \| (\d+) \| (\d+) \| "
                      r"(\d+) \| (\d+) \|$", proc.stdout, flags=re.M)  # fmt: skip
    march = re.findall(r"^\| (count|write) \| (yes|no) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \|$", proc.stdout,
                       flags=re.M)  # fmt: skip
    assert len(rows) == 4 and len(march) == 4, proc.stdout
    rows += march
    for kernel, columns, registers, stack, local, _ in rows:
        assert int(stack) == int(local) == 0, f"{kernel} {columns}: registers spill\n{proc.stdout}"
        assert 0 < int(registers) <= 255

"""``fields/vm_triton.py``: the Triton VM lookup equals ``grid_sample``'s values and gradients (per channel
and summed, zeros outside the grid, NaN for a NaN point), serves the grid field with ``lookup="triton"``,
stays one graph under ``torch.compile`` and is refused, in one line, where it cannot run.

Without a GPU the kernels run in Triton's CPU interpreter (``TRITON_INTERPRET=1``, set by ``conftest.py``
before anything imports triton), which executes the same kernel source with numpy: it checks the indexing,
masks, atomics and the custom ops, not GPU speed. On a CUDA host the same tests run the compiled kernels."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import test_train
import test_vm_gather
from helpers import counts_graphs, triton_device
from spikenerf.core.errors import InputError
from spikenerf.fields import field_config, vm_triton
from spikenerf.fields.grid import GridField, _factor
from spikenerf.fields.grid_config import GridFieldConfig
from spikenerf.fields.vm_sample import sample_vm
from spikenerf.fields.vm_triton import applies, triton_vm

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
ROOT = Path(__file__).resolve().parents[1]


#: where the kernels run: the GPU, else the interpreter on the CPU
DEVICE = triton_device()
dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures


def _factors(c: int = 5, r: int = 7) -> tuple[torch.Tensor, torch.Tensor]:
    """``test_vm_gather``'s factors, on :data:`DEVICE`."""
    planes, lines = test_vm_gather._factors(c, r)
    return _factor(planes.detach().to(DEVICE)), _factor(lines.detach().to(DEVICE))


def _points(m: int = 300, spread: float = 1.8) -> torch.Tensor:
    """``test_vm_gather``'s points (some outside the grid) on :data:`DEVICE`."""
    return test_vm_gather._points(m, spread).to(DEVICE)


def _grads(out: torch.Tensor, weights: torch.Tensor, inputs: list[torch.Tensor]) -> tuple[torch.Tensor, ...]:
    return torch.autograd.grad((out * weights).sum(), inputs)


@pytest.mark.parametrize("channels", [5, 16])
def test_values_and_gradients_equal_grid_sample_inside_and_outside_the_grid(channels: int) -> None:
    planes, lines = _factors(c=channels)
    xyz = _points().requires_grad_()  # the points' gradient too (pose refinement moves them)
    expected = sample_vm(planes, lines, xyz).permute(2, 0, 1)
    got = triton_vm(planes, lines, xyz)
    assert got.shape == (len(xyz), 3, channels)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    outside = (xyz.abs() > 1 + 2 / 6).all(dim=1)  # more than a texel (2 / (R − 1)) outside
    assert outside.any() and got[outside].abs().max() == 0  # zeros padding
    weights = torch.randn_like(got)
    inputs = [planes, lines, xyz]
    for g, e in zip(_grads(got, weights, inputs), _grads(expected, weights, inputs), strict=True):
        assert g.stride() == e.stride() or g.is_contiguous(memory_format=torch.channels_last)
        torch.testing.assert_close(g, e, atol=1e-4, rtol=1e-4)


def test_the_summed_lookup_equals_the_sum_and_skips_zero_gradients() -> None:
    planes, lines = _factors(c=6)
    xyz = _points(200, 1.1).requires_grad_()
    expected = sample_vm(planes, lines, xyz).sum(dim=(0, 1))
    got = triton_vm(planes, lines, xyz, summed=True)
    assert got.shape == (len(xyz),)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    weights = torch.randn(len(xyz), device=DEVICE)
    weights[::3] = 0  # points behind an early stop: their (zero) gradient adds nothing either way
    inputs = [planes, lines, xyz]
    for g, e in zip(_grads(got, weights, inputs), _grads(expected, weights, inputs), strict=True):
        torch.testing.assert_close(g, e, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("launch", [(16, 1), (128, 8)])
def test_other_launch_shapes_give_the_same_values_and_gradients(
    launch: tuple[int, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    planes, lines = _factors(c=6)
    xyz = _points(300).requires_grad_()  # not a multiple of either block: a part-filled last program
    weights = torch.randn(len(xyz), 3, 6, device=DEVICE)
    expected = triton_vm(planes, lines, xyz)
    expected_grads = _grads(expected, weights, [planes, lines, xyz])
    monkeypatch.setattr(vm_triton, "LAUNCH", {"forward": launch, "backward": launch, "point": launch})
    got = triton_vm(planes, lines, xyz)
    torch.testing.assert_close(got, expected, atol=1e-6, rtol=1e-6)
    for g, e in zip(_grads(got, weights, [planes, lines, xyz]), expected_grads, strict=True):
        torch.testing.assert_close(g, e, atol=1e-5, rtol=1e-5)


def test_a_nan_point_gives_nan_and_no_points_give_empty_results() -> None:
    planes, lines = _factors()
    xyz = torch.tensor([[0.1, float("nan"), 0.2], [0.1, 0.2, 0.3]], device=DEVICE, requires_grad=True)
    got = triton_vm(planes, lines, xyz, summed=True)
    assert got[0].isnan() and got[1].isfinite()
    point_grad = torch.autograd.grad(got.sum(), xyz)[0]
    assert point_grad[0].isnan().any() and point_grad[1].isfinite().all()
    none = torch.zeros(0, 3, device=DEVICE)
    assert triton_vm(planes, lines, none).shape == (0, 3, 5)
    empty = triton_vm(planes, lines, none, summed=True)
    assert empty.shape == (0,)


def test_the_grid_field_with_lookup_triton_gives_its_default_lookups_values_and_gradients() -> None:
    config = GridFieldConfig(n_voxels_init=9**3, n_voxels_final=9**3, decoder_bf16=False)
    field = GridField(3, BOX, config).to(DEVICE)
    xyz = _points(100, 1.0).requires_grad_()  # pose refinement's points: their gradient too
    dirs = torch.nn.functional.normalize(torch.randn(104, 3), dim=-1).to(DEVICE)

    def run() -> tuple[torch.Tensor, ...]:
        field.zero_grad()
        xyz.grad = None
        sigma, rgb = field.density_norm(xyz), field.color_norm(xyz, dirs)
        (sigma.sum() + rgb.square().sum()).backward()
        grads = field.density_planes.grad.clone(), field.app_lines.grad.clone(), xyz.grad.clone()
        return sigma.detach(), rgb.detach(), *grads

    default = run()
    field.config = dataclasses.replace(config, lookup="triton")
    for got, expected in zip(run(), default, strict=True):
        torch.testing.assert_close(got, expected, atol=1e-4, rtol=1e-4)


@counts_graphs
def test_the_custom_ops_pass_opcheck_and_compile_as_one_graph() -> None:
    planes, lines = _factors(c=4, r=5)
    xyz = _points(40, 1.0)
    op = torch.ops.spikenerf.vm_triton_forward.default
    p, ln = (
        planes.detach().permute(0, 2, 3, 1).contiguous(),
        lines.detach()[..., 0].permute(0, 2, 1).contiguous(),
    )
    for summed in (False, True):
        torch.library.opcheck(op, (p.requires_grad_(True), ln.requires_grad_(True), xyz, summed))
        torch.library.opcheck(op, (p, ln, xyz.clone().requires_grad_(True), summed))  # the point kernel
        frozen = p.detach(), ln.detach(), xyz.clone().requires_grad_(True)  # only the points' gradient
        torch.library.opcheck(op, (*frozen, summed))

    def density(planes: torch.Tensor, lines: torch.Tensor, xyz: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.softplus(triton_vm(planes, lines, xyz, summed=True) - 1)

    torch._dynamo.reset()
    explained = torch._dynamo.explain(density)(planes, lines, xyz)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons
    compiled = torch.compile(density, backend="aot_eager", fullgraph=True)
    got, expected = compiled(planes, lines, xyz), density(planes, lines, xyz)
    torch.testing.assert_close(got, expected)
    torch.testing.assert_close(torch.autograd.grad(got.sum(), planes)[0],
                               torch.autograd.grad(expected.sum(), planes)[0])  # fmt: skip


def test_where_the_kernels_cannot_run_they_are_refused_naming_why(monkeypatch: pytest.MonkeyPatch) -> None:
    planes, lines = _factors()
    planes, lines = planes.cpu(), lines.cpu()
    assert applies(planes, _points(3).cpu().requires_grad_(True))  # the interpreter; points' gradient too
    monkeypatch.setenv("TRITON_INTERPRET", "0")
    assert not applies(planes, _points(3).cpu())
    with pytest.raises(RuntimeError, match="need a CUDA device, not cpu"):
        triton_vm(planes, lines, _points(3).cpu())
    cfg = field_config("grid", {"lookup": "triton"})
    with pytest.raises(InputError, match=r"field_config\.lookup=triton: Triton kernels need a CUDA device"):
        cfg.check_device(torch.device("cpu"))
    field_config("grid", {}).check_device(torch.device("cpu"))  # the default lookup runs anywhere
    monkeypatch.setattr(vm_triton, "installed", lambda: False)
    with pytest.raises(InputError, match=r"not installed \(pip install triton"):
        cfg.check_device(torch.device("cuda"))


def test_a_field_trained_with_the_triton_lookup_evaluates_where_it_cannot_run(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    config = GridFieldConfig(n_voxels_init=9**3, n_voxels_final=9**3, decoder_bf16=False)
    field = GridField(1, BOX, dataclasses.replace(config, lookup="triton")).to(DEVICE)
    xyz = _points(50, 1.0)
    with torch.no_grad():
        kernels = field.density_norm(xyz).cpu()
        monkeypatch.setenv("TRITON_INTERPRET", "0")  # a CPU without the interpreter: the default lookup
        torch.testing.assert_close(field.cpu().density_norm(xyz.cpu()), kernels, atol=1e-4, rtol=1e-5)


@pytest.mark.parametrize("option", ["lookup", "composite"])  # (composite: render/volume_triton.py)
def test_train_with_a_triton_option_on_a_cpu_is_one_line_and_exit_2(
    option: str, dataset_dir: Path, tmp_path: Path
) -> None:
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "spikenerf", "train", str(dataset_dir), "--out", str(out), "--iters", "2",
         "--field-option", f"{option}=triton", "--device", "cpu"],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and option in proc.stderr and "CUDA" in proc.stderr, proc.stderr
    assert not (out / "checkpoint.pt").exists()


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_triton_equals_grid_sample_on_cuda(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TRITON_INTERPRET", "0")
    planes, lines = (f.cuda() for f in _factors(c=16, r=33))
    planes, lines = _factor(planes.detach()), _factor(lines.detach())
    xyz = _points(20000).cuda()
    for summed in (False, True):
        expected = sample_vm(planes, lines, xyz).permute(2, 0, 1)
        expected = expected.sum(dim=(1, 2)) if summed else expected
        got = triton_vm(planes, lines, xyz, summed=summed)
        torch.testing.assert_close(got, expected, atol=1e-4, rtol=1e-4)
        weights = torch.randn_like(got)
        for g, e in zip(_grads(got, weights, [planes, lines]), _grads(expected, weights, [planes, lines]),
                        strict=True):  # fmt: skip
            torch.testing.assert_close(g, e, atol=1e-3, rtol=1e-4)


def test_the_kernels_compile_for_an_h100_without_spilling(tmp_path: Path) -> None:
    """Triton's real compiler (not the interpreter) and its bundled ptxas build every variant for sm_90
    without a GPU; no registers spill (a runtime channel count of 24 spilled about 24 kB a thread)."""
    pytest.importorskip("triton", minversion="3.3")  # the report builds ASTSource as Triton 3.3 does
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), str(ROOT)])
    env["TRITON_CACHE_DIR"] = str(tmp_path / "cache")
    env["TRITON_DEFAULT_FP_FUSION"] = "1"
    proc = subprocess.run([sys.executable, "-m", "benchmarks.tools.triton_compile_report", "--kernels", "vm"],
                          cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    numbers = r"\| (\d+) \| (\d+) \| (\d+) \| (\d+) \| \d+ × \d+ \|$"
    row = r"^\| (forward|backward|point) \| (\d+)( summed)? " + numbers
    rows = re.findall(row, proc.stdout, flags=re.M)
    assert len(rows) == 6, proc.stdout  # each kernel as vm_triton.LAUNCH launches it
    for kernel, channels, _, registers, stack, local, _ in rows:
        assert int(stack) == int(local) == 0, f"{kernel} C={channels}: registers spill\n{proc.stdout}"
        assert 0 < int(registers) <= 255

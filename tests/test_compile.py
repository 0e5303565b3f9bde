"""``train --compile``: the compiled field renders and trains like the eager one (closeness on the CPU), and a
failing compiler leaves the field eager with one warning."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest
import torch

import test_train
from helpers import counts_graphs
from spikenerf.data.rays import image_rays
from spikenerf.fields import GridFieldConfig, MLPFieldConfig, vm_kernel
from spikenerf.fields import compiled as compiled_mod
from spikenerf.fields.compiled import Fallback, compile_field, compiled_parts
from spikenerf.render import build_model
from spikenerf.render.model import ray_bounds
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.trajectory import Intrinsics
from spikenerf.train.trainer import Trainer

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures
BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
GRID = GridFieldConfig(n_voxels_init=24**3, n_voxels_final=24**3, occupancy=False, init_scale=0.5,
                       density_shift=0.0, distance_scale=5.0, decoder_bf16=False)  # fmt: skip


def _model(kind: str):  # type: ignore[no-untyped-def]
    torch.manual_seed(0)
    return build_model(kind, 3, BOX, GRID if kind == "grid" else MLPFieldConfig.tiny())


def _render(model) -> tuple[torch.Tensor, list[torch.Tensor]]:  # type: ignore[no-untyped-def]
    """Colours (N, 3) of a small view (deterministic samples) and the gradients of their sum."""
    pose = torch.as_tensor(
        look_at(np.array([0.3, 2.5, 1.2]), np.zeros(3)), dtype=torch.float32, device=model.device
    )
    origins, dirs = image_rays(pose, Intrinsics.from_fov(16, 12, 0.8))
    near, far = ray_bounds(model, origins, dirs)
    model.zero_grad(set_to_none=True)
    out = model.render_rays(origins, dirs, near, far)
    out.color.sum().backward()
    return out.color.detach(), [p.grad.clone() for p in model.parameters() if p.grad is not None]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["grid", "mlp"])
def test_compiled_field_renders_and_differentiates_like_eager(kind: str) -> None:
    eager_color, eager_grads = _render(_model(kind))
    model, warnings = _model(kind), []
    assert compile_field(model.field, warnings.append) and not warnings
    assert all(isinstance(getattr(o, a), Fallback) for o, a in compiled_parts(model.field).values())
    color, grads = _render(model)
    assert eager_color.abs().sum() > 0 and torch.allclose(color, eager_color, atol=1e-5, rtol=1e-4)
    assert len(grads) == len(eager_grads)
    for g, e in zip(grads, eager_grads, strict=True):
        assert torch.allclose(g, e, atol=1e-5, rtol=1e-3)
    assert list(model.state_dict()) == list(_model(kind).state_dict())  # checkpoints unchanged


@pytest.mark.parametrize("kernel", [True, False], ids=["kernel", "grid_sample"])
@pytest.mark.parametrize("bf16", [False, True])
def test_grid_field_functions_trace_without_graph_breaks(bf16: bool, kernel: bool) -> None:
    # host queries (thread count, bf16 support) used to break the graph: on the H200 the break in
    # ``color_norm`` recompiled its resume function for every sample count until dynamo's limit
    torch.manual_seed(0)
    field = build_model("grid", 3, BOX, GridFieldConfig(**{**GRID.__dict__, "decoder_bf16": bf16})).field
    xyz = (torch.rand(300, 3) * 1.8 - 0.9).requires_grad_(True)  # points with a gradient (pose refinement)
    dirs = torch.nn.functional.normalize(torch.randn(300, 3), dim=-1)
    with contextlib.nullcontext() if kernel else vm_kernel.suspended():
        for fn, args in ((field.density_norm, (xyz,)), (field.color_norm, (xyz, dirs))):
            torch._dynamo.reset()
            explained = torch._dynamo.explain(fn)(*args)
            assert (explained.graph_count, explained.graph_break_count) == (1, 0), fn.__name__


def _counting(graphs: list[int]):  # type: ignore[no-untyped-def]
    """A ``torch.compile`` backend that runs each graph as traced and appends 1 to ``graphs`` per graph."""

    def backend(gm: torch.fx.GraphModule, _inputs: list) -> object:
        graphs.append(1)
        return gm.forward

    return backend


def test_compiled_grid_function_compiles_once_for_many_sample_counts() -> None:
    torch.manual_seed(0)
    field = build_model("grid", 3, BOX, GRID).field
    graphs: list[int] = []
    backend = _counting(graphs)
    torch._dynamo.reset()
    fn = torch.compile(field.color_norm, backend=backend, dynamic=True)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one point chunk per plane whatever the count (vm_splits)
    try:
        for m in (300, 517, 1024, 2999, 4100):
            xyz = (torch.rand(m, 3) * 1.8 - 0.9).requires_grad_(True)  # (pose refinement's points)
            dirs = torch.nn.functional.normalize(torch.randn(m, 3), dim=-1)
            torch.testing.assert_close(fn(xyz, dirs), field.color_norm(xyz, dirs))
    finally:
        torch.set_num_threads(threads)
    assert len(graphs) == 1


@counts_graphs
def test_compiled_field_functions_do_not_recompile_for_each_grid_resolution(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Upsampling replaces the factors by larger ones; their sizes are traced as symbols after the first
    change, so later resolutions reuse the graphs (a run's four upsamplings, with grad on and off, passed
    Dynamo's recompile limit of 8 and left the field eager with a log warning)."""
    torch.manual_seed(0)
    field = build_model("grid", 1, BOX, GRID).field
    graphs: list[int] = []
    backend = _counting(graphs)
    compile_ = torch.compile
    monkeypatch.setattr(compiled_mod.torch, "compile", lambda fn, **kw: compile_(fn, backend=backend, **kw))
    torch._dynamo.reset()
    assert compile_field(field, pytest.fail)
    counts = []
    for r in (24, 30, 37, 45, 56):
        field.upsample(r)
        for grad in (True, False):
            with torch.set_grad_enabled(grad):
                xyz = torch.rand(200 + r, 3) * 1.8 - 0.9
                dirs = torch.nn.functional.normalize(torch.randn(200 + r, 3), dim=-1)
                field.density_norm(xyz).sum() + field.color_norm(xyz, dirs).sum()
        counts.append(len(graphs))
    torch._dynamo.reset()
    assert counts[2:] == [counts[1]] * 3, counts  # none after the first change of size
    assert all(isinstance(getattr(field, n), Fallback) and getattr(field, n).failed is None
               for n in ("density_norm", "color_norm"))  # fmt: skip


@pytest.mark.parametrize("kind", ["grid", "mlp"])
def test_a_failing_compiler_leaves_the_field_eager_with_one_warning(
    kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(fn, **kw):  # type: ignore[no-untyped-def]
        def run(*args, **kwargs):  # type: ignore[no-untyped-def]
            raise RuntimeError("no compiler\nhere")

        return run

    monkeypatch.setattr(compiled_mod.torch, "compile", broken)
    model, warnings = _model(kind), []
    assert not compile_field(model.field, warnings.append)
    assert len(warnings) == 1 and "training eagerly: RuntimeError: no compiler here" in warnings[0]
    for owner, attr in compiled_parts(model.field).values():
        assert attr not in vars(owner)  # the class's own method again
    eager_color, _ = _render(_model(kind))
    assert torch.equal(_render(model)[0], eager_color)


def test_a_compiled_call_that_fails_later_goes_eager_once() -> None:
    told: list[str] = []
    calls = {"compiled": 0}

    def compiled(x: int) -> int:
        calls["compiled"] += 1
        raise RuntimeError("recompile failed")

    f = Fallback(lambda x: x + 1, compiled, told.append)
    assert f(1) == 2 and f(2) == 3
    assert calls["compiled"] == 1 and told == ["RuntimeError: recompile failed"]


@pytest.mark.slow
def test_training_with_compile_runs_and_resumes(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    cfg = test_train._config(dataset_dir, method="nerf-gt")
    cfg.compile = True
    summary = Trainer(cfg, tmp_path / "run", dataset, progress=False).train(stop_after=3)
    assert summary.iteration == 3
    cfg.compile = False  # a resumable option: the run goes on eagerly
    resumed = Trainer(cfg, tmp_path / "run", dataset, resume=True, progress=False)
    resumed.train()
    assert resumed.iteration == cfg.iters
    assert all(torch.isfinite(p).all() for p in resumed.model.parameters())


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("kind", ["grid", "mlp"])
def test_compiled_field_on_cuda_renders_like_eager(kind: str) -> None:
    eager = _model(kind).cuda()
    model, warnings = _model(kind).cuda(), []
    assert compile_field(model.field, warnings.append), warnings
    (a, ga), (b, gb) = _render(eager), _render(model)
    assert torch.allclose(a, b, atol=1e-4, rtol=1e-3)
    for g, e in zip(gb, ga, strict=True):
        assert torch.allclose(g, e, atol=1e-4, rtol=1e-2)

"""``train --compile`` with the grid's ``static_samples`` (issue 27, ``train/compiled_step.py``): the device
part of a step compiled as one graph (spike-nerf's spike window: a second one) trains and resumes like the
eager static step, recompiles only at the upsamplings, runs the fused CPU kernel inside the graph; a failing
compiler leaves the step eager with one warning and the eager run's parameters; without ``static_samples``
``--compile`` still compiles the field's functions.

Most tests compile with ``backend="aot_eager"`` (the graph traced and run as aten ops, no C++ build); one uses
inductor, the real default, and one CUDA graphs (``mode="reduce-overhead"``, skipped without a GPU)."""

from __future__ import annotations

import dataclasses
import math
import traceback
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from torch._dynamo.utils import counters

import test_train
from helpers import counts_graphs
from spikenerf.fields import grid as grid_module
from spikenerf.fields import vm_build, vm_kernel, vm_triton
from spikenerf.train import compiled_step
from spikenerf.train import trainer as trainer_module
from spikenerf.train.compiled_step import CompiledStep, compile_step
from spikenerf.train.trainer import Trainer

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures
WARNING = "spikenerf: warning: torch.compile of the training step failed, training eagerly: "


pytestmark = pytest.mark.usefixtures("fresh_dynamo")  # tests/conftest.py


@pytest.fixture
def aot_eager(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(compiled_step, "BACKEND", "aot_eager")


def _config(dataset_dir: Path, method: str, compile: bool, static: int = 24, **field):  # type: ignore[no-untyped-def]
    cfg = test_train._config(dataset_dir, method=method)
    cfg.field_config = {**cfg.field_config, "static_samples": static, **field}
    cfg.compile = compile
    return cfg


def _run(cfg, out: Path, dataset, stop_after: int | None = None, resume: bool = False):  # type: ignore[no-untyped-def]
    """(trainer, the total loss of each step it ran) of training ``cfg`` into ``out``."""
    trainer = Trainer(cfg, out, dataset, resume=resume, progress=False)
    recorded: list[torch.Tensor] = []
    losses = trainer.method.losses

    def spy(state, iteration):  # type: ignore[no-untyped-def]
        step = losses(state, iteration)
        recorded.append(step.total().detach())
        return step

    trainer.method.losses = spy  # type: ignore[method-assign]
    trainer.train(stop_after)
    return trainer, [float(x) for x in recorded]


def _graphs() -> int:
    return int(counters["stats"]["unique_graphs"])


@counts_graphs
@pytest.mark.parametrize(
    ("method", "field", "graphs"),
    [("nerf-gt", {}, 1), ("spike-integral", {"tv_density": 0.1}, 2), ("spike-nerf", {}, 2)],
)
def test_the_compiled_step_trains_and_resumes_like_the_eager_static_step(
    dataset_dir: Path,
    dataset,
    tmp_path: Path,
    method: str,
    field: dict,
    graphs: int,
    aot_eager: None,
    capsys,  # type: ignore[no-untyped-def]
) -> None:
    kernel: dict[bool, list[int]] = {False: [0, 0], True: [0, 0]}  # fused-kernel forward, backward calls

    class Counted:  # the compiled module behind the kernel's custom ops, counting the eager and compiled runs
        def __init__(self, module) -> None:  # type: ignore[no-untyped-def]
            self.module = module

        def forward(self, *args):  # type: ignore[no-untyped-def]
            kernel[cfg.compile][0] += 1
            return self.module.forward(*args)

        def forward_rows(self, *args):  # type: ignore[no-untyped-def]
            kernel[cfg.compile][0] += 1  # (the eager colour lookup into bf16 rows: a forward as well)
            return self.module.forward_rows(*args)

        def backward(self, *args):  # type: ignore[no-untyped-def]
            kernel[cfg.compile][1] += 1
            return self.module.backward(*args)

        def __getattr__(self, name: str):  # type: ignore[no-untyped-def]
            return getattr(self.module, name)  # the packed renders' march, not counted

    cfg = _config(dataset_dir, method, False, **field)
    with pytest.MonkeyPatch.context() as mp:
        if vm_kernel.available():
            mp.setattr(vm_build, "_MODULE", Counted(vm_build._MODULE))
        _, eager = _run(cfg, tmp_path / "eager", dataset)
        cfg = _config(dataset_dir, method, True, **field)
        trainer, first = _run(cfg, tmp_path / "compiled", dataset, stop_after=3)
        step = vars(trainer.method)["step_losses"]
        assert isinstance(step, CompiledStep) and step.failed is None
        # one graph for every grid resolution (12, 15: upsampled after step 2; their sizes traced as
        # symbols), whatever the iteration; with the TV prior one more for the steps where
        # iteration % tv_every == 0, and with spike-nerf's spike window (from step 1 on) one more
        assert _graphs() == graphs, counters["stats"]
        resumed, rest = _run(cfg, tmp_path / "compiled", dataset, resume=True)
    assert resumed.iteration == cfg.iters and isinstance(vars(resumed.method)["step_losses"], CompiledStep)
    assert "warning" not in capsys.readouterr().err
    compiled = first + rest
    assert len(compiled) == len(eager) == cfg.iters and all(map(math.isfinite, compiled))
    assert compiled[:2] == pytest.approx(eager[:2], rel=1e-4)
    assert compiled == pytest.approx(eager, rel=1e-3)
    if vm_kernel.available():  # the compiled graph runs the fused kernel (its custom ops) as the eager step
        assert kernel[True] == kernel[False] and kernel[True][1] >= 2 * cfg.iters, kernel
    assert all(torch.isfinite(p).all() for p in resumed.model.parameters())


@counts_graphs
@pytest.mark.parametrize("symbolic", [True, False])
def test_one_graph_serves_every_grid_resolution(
    dataset_dir: Path,
    dataset,
    tmp_path: Path,
    aot_eager: None,
    symbolic: bool,
    monkeypatch: pytest.MonkeyPatch,
) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setattr(compiled_step, "SYMBOLIC_FROM_START", symbolic)
    cfg = _config(dataset_dir, "nerf-gt", True)
    trainer, losses = _run(cfg, tmp_path / "run", dataset)
    assert trainer.model.field.resolution == 20 and len(losses) == cfg.iters  # 12, 15, 20: upsampled twice
    assert vars(trainer.method)["step_losses"].failed is None
    # the factors' and occupancy grid's sizes traced as symbols from the start; else the first
    # resolution's graph, then one with symbolic sizes (bench_compile_cache times both)
    assert _graphs() == (1 if symbolic else 2), counters["stats"]


@counts_graphs
def test_the_gather_lookup_compiles_and_trains_like_grid_sample(
    dataset_dir: Path, dataset, tmp_path: Path, aot_eager: None
) -> None:  # type: ignore[no-untyped-def]
    _, reference = _run(_config(dataset_dir, "spike-integral", False), tmp_path / "eager", dataset)
    cfg = _config(dataset_dir, "spike-integral", True, lookup="gather")
    trainer, gathered = _run(cfg, tmp_path / "gather", dataset)
    assert vars(trainer.method)["step_losses"].failed is None and _graphs() == 1
    assert gathered == pytest.approx(reference, rel=1e-3)


@counts_graphs
@pytest.mark.skipif(
    not (vm_triton.installed() and vm_triton.interpreted()), reason="needs triton and TRITON_INTERPRET=1"
)
def test_the_triton_lookup_compiles_and_trains_like_grid_sample(
    dataset_dir: Path, dataset, tmp_path: Path, aot_eager: None
) -> None:  # type: ignore[no-untyped-def]
    """On the CPU in Triton's interpreter (tests/conftest.py): the kernels' custom ops in a compiled step."""
    eager = _config(dataset_dir, "nerf-gt", False)
    cfg = _config(dataset_dir, "nerf-gt", True, lookup="triton")
    for c in (eager, cfg):
        c.eval_every = 0  # the interpreter is slow: no test-view renders
    _, reference = _run(eager, tmp_path / "eager", dataset, stop_after=3)
    trainer, kernels = _run(cfg, tmp_path / "triton", dataset, stop_after=3)
    assert vars(trainer.method)["step_losses"].failed is None and _graphs() == 1
    assert len(kernels) == 3 and kernels == pytest.approx(reference, rel=1e-3)


def test_draws_go_to_the_gpu_only_where_every_target_lives_there(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.train.compiled_step import draws_to_device

    trainer = Trainer(_config(dataset_dir, "nerf-gt", False), tmp_path / "run", dataset, progress=False)
    assert trainer.method.targets is not None
    assert not draws_to_device(trainer.method, torch.device("cpu"))
    assert not draws_to_device(trainer.method, torch.device("cuda"))  # its targets are host tensors


def test_the_draws_follow_the_images_and_poses_while_the_steps_stay_on_the_host(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.train.compiled_step import draws_to_device

    # "meta" stands in for the GPU: what train/device.py moves there (images and poses), not the steps
    monkeypatch.setattr(compiled_step, "same_device", lambda where, device: where.type == "meta")
    trainer = Trainer(_config(dataset_dir, "nerf-gt", False), tmp_path / "run", dataset, progress=False)
    method, cuda = trainer.method, torch.device("cuda")
    on_host = method.targets
    method.targets = on_host.images_on("meta")
    assert method.targets.steps is on_host.steps and method.targets.poses.device.type == "meta"
    assert draws_to_device(method, cuda)  # the host's steps are not read by the step
    method.targets = dataclasses.replace(method.targets, poses=on_host.poses)
    assert not draws_to_device(method, cuda)  # a step that indexes host poses keeps its draws there


def test_a_tensor_on_cuda_0_is_on_the_training_device_cuda(monkeypatch: pytest.MonkeyPatch) -> None:
    from spikenerf.train.compiled_step import same_device

    monkeypatch.setattr(compiled_step.torch.cuda, "current_device", lambda: 0)
    cuda, cuda0, cuda1 = torch.device("cuda"), torch.device("cuda:0"), torch.device("cuda:1")
    assert cuda0 != cuda  # why the comparison needs more than ==
    assert same_device(cuda0, cuda) and same_device(cuda1, cuda1) and same_device(cuda0, cuda0)
    assert not same_device(cuda1, cuda) and not same_device(cuda0, cuda1)
    cpu = torch.device("cpu")
    assert not same_device(cpu, cuda) and same_device(cpu, cpu)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("method", ["nerf-gt", "spike-integral", "spike-nerf"])
@pytest.mark.parametrize("field", [{}, {"static_visible": 12}])
def test_a_cuda_graph_step_makes_no_host_sync(
    dataset_dir: Path, dataset, tmp_path: Path, method: str, field: dict
) -> None:  # type: ignore[no-untyped-def]
    cfg = _config(dataset_dir, method, True, **field)
    cfg.device, cfg.iters, cfg.eval_every, cfg.ckpt_every = "cuda", 16, 0, 100
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    trainer.train(stop_after=12)  # past the last upsampling (rescaled to 16 iterations): graphs replayed
    method_, optimizer = trainer.method, trainer.optimizer

    def steps() -> None:  # draws, graph, backward, Adam: three steps as the loop runs them
        for it in range(trainer.iteration, trainer.iteration + 3):
            loss = method_.losses(trainer, it).total()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()

    # the same steps once unwatched first: in the first test of a process (on an H200) one synchronisation
    # came from torch/cuda/__init__.py alone in the watched steps, e.g. a graph still being recorded
    steps()
    torch.cuda.synchronize()
    syncs: list[str] = []

    def record(message, category, filename, lineno, file=None, line=None):  # type: ignore[no-untyped-def]
        """Each synchronisation with the Python frames (ours and torch's) that led to it, innermost first:
        on an H200 the first test of a process once saw one in ``torch/cuda/__init__.py`` alone."""
        if "synchroniz" in str(message):
            frames = [f"{f.filename}:{f.lineno}" for f in traceback.extract_stack()[:-1]]
            callers = [f for f in frames if "spikenerf" in f or "torch" in f][-10:]
            syncs.append(f"{filename}:{lineno} from " + " < ".join(reversed(callers)))

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = record  # put back on leaving the block
        torch.cuda.set_sync_debug_mode("warn")
        try:
            steps()
        finally:
            torch.cuda.set_sync_debug_mode("default")
    assert vars(method_)["step_losses"].failed is None
    assert syncs == [], "\n".join(syncs)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_pinned_copies_reach_the_gpu_unchanged() -> None:
    from spikenerf.train.compiled_step import pinned_copies

    drawn = (torch.arange(6), torch.rand(3, 2))
    moved = pinned_copies(drawn, torch.device("cuda"))
    assert all(m.is_cuda for m in moved)
    for m, d in zip(moved, drawn, strict=True):
        torch.testing.assert_close(m.cpu(), d)


@pytest.mark.parametrize("failure", ["raises", "graph break"])
def test_a_failing_compiled_step_trains_eagerly_with_one_warning(
    dataset_dir: Path,
    dataset,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys,
    failure: str,
    aot_eager: None,  # type: ignore[no-untyped-def]
) -> None:
    _, eager_losses = _run(_config(dataset_dir, "nerf-gt", False), tmp_path / "eager", dataset)
    eager = torch.load(tmp_path / "eager" / "checkpoint.pt", weights_only=False)["model"]
    capsys.readouterr()

    def broken(fn, **kw):  # type: ignore[no-untyped-def]
        def run(*args, **kwargs):  # type: ignore[no-untyped-def]
            torch.rand(1000)  # a failure after the call drew random numbers: they are drawn again
            raise RuntimeError("no compiler\nhere")

        return run

    if failure == "raises":
        monkeypatch.setattr(compiled_step.torch, "compile", broken)
    else:  # a graph break inside the step, which fullgraph=True refuses (eagerly, nothing happens)
        density = grid_module.GridField.density_norm

        def breaking(self, xyz):  # type: ignore[no-untyped-def]
            torch._dynamo.graph_break()
            return density(self, xyz)

        monkeypatch.setattr(grid_module.GridField, "density_norm", breaking)
    trainer, losses = _run(_config(dataset_dir, "nerf-gt", True), tmp_path / "broken", dataset)
    lines = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(lines) == 1 and lines[0].startswith(WARNING)
    if failure == "raises":
        assert lines == [WARNING + "RuntimeError: no compiler here"]
    assert trainer.iteration == trainer.config.iters and "step_losses" not in vars(trainer.method)
    assert losses == eager_losses  # the eager step, with the random stream of a run without --compile
    state = trainer.model.state_dict()
    assert all(torch.equal(state[k], v) for k, v in eager.items())


def test_with_pose_refinement_the_compiled_step_trains_eagerly_and_marks_as_eager(
    dataset_dir: Path, dataset, tmp_path: Path, capsys, aot_eager: None
) -> None:  # type: ignore[no-untyped-def]
    """The refiner reads its steps on the host and marks the keyframes a step reads (host state, for the
    hold-out's fill): the compiled static step cannot trace that, so it trains eagerly after one warning,
    with the eager run's marks and corrections (the hold-out on: a keyframe stays unmarked)."""
    runs = []
    for compile in (False, True):
        cfg = _config(dataset_dir, "spike-integral", compile)
        cfg.iters, cfg.eval_every, cfg.ckpt_every = 3, 0, 3
        cfg.poses.refine, cfg.poses.warmup_iters, cfg.poses.lr = True, 0, 1e-2
        cfg.holdout, cfg.holdout_steps, cfg.holdout_radius = True, 1, 30
        runs.append(_run(cfg, tmp_path / f"run{compile}", dataset)[0].pose_refine.refiner)
    lines = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(lines) == 1 and lines[0].startswith(WARNING), lines
    eager, compiled = runs
    assert not eager.reached.all() and np.array_equal(eager.reached, compiled.reached)
    assert torch.equal(eager.xi, compiled.xi) and eager.xi.abs().max() > 0


def test_a_backward_that_fails_to_compile_trains_on_eagerly_with_one_warning(
    dataset_dir: Path, dataset, tmp_path: Path, capsys
) -> None:  # type: ignore[no-untyped-def]
    from torch._dynamo.backends.common import aot_autograd

    def no_backward(gm, example):  # type: ignore[no-untyped-def]
        raise RuntimeError("backward lowering failed")

    name = "spikenerf_test_no_backward"
    if name not in torch._dynamo.list_backends(exclude_tags=()):
        backend = aot_autograd(fw_compiler=lambda gm, ex: gm.forward, bw_compiler=no_backward)
        torch._dynamo.register_backend(backend, name=name)
    compiled_step.BACKEND, before = name, compiled_step.BACKEND
    try:
        trainer, losses = _run(_config(dataset_dir, "nerf-gt", True), tmp_path / "run", dataset)
    finally:
        compiled_step.BACKEND = before
    lines = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(lines) == 1 and lines[0].startswith(WARNING) and "backward lowering failed" in lines[0], lines
    assert trainer.iteration == trainer.config.iters and "step_losses" not in vars(trainer.method)
    assert all(math.isfinite(v) for v in losses)


def test_a_compiler_that_fails_at_once_leaves_the_method_eager(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    trainer = Trainer(_config(dataset_dir, "nerf-gt", False), tmp_path / "run", dataset, progress=False)

    def broken(fn, **kw):  # type: ignore[no-untyped-def]
        raise RuntimeError("no backend")

    monkeypatch.setattr(compiled_step.torch, "compile", broken)
    told: list[str] = []
    assert not compile_step(trainer.method, trainer.model, trainer.device, told.append)
    assert told == [WARNING.removeprefix("spikenerf: warning: ") + "RuntimeError: no backend"]
    assert "step_losses" not in vars(trainer.method)


@pytest.mark.parametrize("static", [0, 24])
def test_compile_without_static_samples_still_compiles_the_field(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, static: int
) -> None:  # type: ignore[no-untyped-def]
    calls: list[str] = []
    monkeypatch.setattr(trainer_module, "compile_field", lambda field, warn: calls.append("field"))
    monkeypatch.setattr(trainer_module, "compile_step", lambda *a: calls.append("step"))
    Trainer(_config(dataset_dir, "nerf-gt", True, static), tmp_path / "run", dataset, progress=False)
    assert calls == (["step"] if static else ["field"])


def test_the_inductor_compiled_step_gives_the_eager_losses(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    # the real default backend, for the two steps before the first upsampling (one graph, C++ built here)
    _, eager = _run(_config(dataset_dir, "nerf-gt", False), tmp_path / "eager", dataset, stop_after=2)
    trainer, compiled = _run(
        _config(dataset_dir, "nerf-gt", True), tmp_path / "compiled", dataset, stop_after=2
    )
    assert vars(trainer.method)["step_losses"].failed is None and _graphs() == 1
    assert compiled == pytest.approx(eager, rel=1e-4)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("method", ["nerf-gt", "spike-integral"])
def test_the_cuda_graph_step_trains_like_eager(
    dataset_dir: Path, dataset, tmp_path: Path, method: str, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setattr(torch._inductor.config, "fallback_random", True)  # eager's random stream
    runs = []
    for compile in (False, True):
        cfg = _config(dataset_dir, method, compile)
        cfg.device = "cuda"
        runs.append(_run(cfg, tmp_path / str(compile), dataset))
    (_, eager), (trainer, compiled) = runs
    step = vars(trainer.method)["step_losses"]
    assert isinstance(step, CompiledStep) and step.cuda_graphs and step.failed is None
    # both keep what the step reads (counts or images, and poses) on the GPU, so the draws go there from
    # page-locked memory; the image targets' steps stay on the host (the pose refiners read them there)
    assert step.move_draws
    assert trainer.method.targets is None or trainer.method.targets.steps.device.type == "cpu"
    assert all(map(math.isfinite, compiled))
    assert compiled[:2] == pytest.approx(eager[:2], rel=1e-3)  # inductor's kernels: other rounding
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())

"""``train --compile-optimizer`` (issue 27, ``train/compiled_optim.py``): the compiled Adam update equals
fused Adam's, a changed learning rate does not recompile, a run trains and resumes (either way round) like
the eager one, and a failing compiler leaves one warning and the eager update.

The optimiser-level test compiles with inductor, the real default; the runs with ``aot_eager`` (no C++
build)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from torch._dynamo.utils import counters

import test_train
from spikenerf.core.errors import InputError
from spikenerf.train import compiled_optim
from spikenerf.train.compiled_optim import CompiledAdamStep, load_state, set_lr, use_tensor_lr
from spikenerf.train.config import TrainConfig
from spikenerf.train.dense_adam import DenseAdam
from spikenerf.train.trainer import Trainer

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures
WARNING = "spikenerf: warning: torch.compile of the optimiser step failed, stepping eagerly: "


pytestmark = pytest.mark.usefixtures("fresh_dynamo")  # tests/conftest.py


def _params(seed: int = 0) -> list[torch.Tensor]:
    """A grid model's kinds of parameters: channels-last plane and line factors, a matrix, a bias."""
    g = torch.Generator().manual_seed(seed)
    plane = torch.randn(1, 12, 9, 7, generator=g).to(memory_format=torch.channels_last)
    line = torch.randn(1, 12, 9, 1, generator=g)
    return [
        t.requires_grad_()
        for t in (plane, line, torch.randn(16, 27, generator=g), torch.randn(3, generator=g))
    ]


def _groups(params: list[torch.Tensor]) -> list[dict]:
    return [
        {"params": params[:2], "lr": 0.02, "base_lr": 0.02},
        {"params": params[2:], "lr": 1e-3, "base_lr": 1e-3},
    ]


def _step_both(
    eager: torch.optim.Optimizer, step, a: list[torch.Tensor], b: list[torch.Tensor], i: int
) -> None:  # type: ignore[no-untyped-def]
    g = torch.Generator().manual_seed(100 + i)
    for p, q in zip(a, b, strict=True):  # gradients in their parameter's layout, as autograd gives them
        grad = torch.empty_like(p).copy_(torch.randn(p.shape, generator=g))
        p.grad, q.grad = grad.clone(), grad.clone()
    for ge, gc in zip(eager.param_groups, step.optimizer.param_groups, strict=True):
        set_lr(ge, ge["base_lr"] * 0.8**i)
        set_lr(gc, gc["base_lr"] * 0.8**i)
    eager.step()
    step()


def test_the_compiled_update_equals_fused_adam_and_a_new_rate_does_not_recompile() -> None:
    a, b = _params(), _params()
    eager = DenseAdam(_groups(a), betas=(0.9, 0.99), fused=True)  # train's CPU optimiser
    plain = torch.optim.Adam(_groups(b), betas=(0.9, 0.99))
    use_tensor_lr(plain)
    step = CompiledAdamStep(plain, pytest.fail, compiles=4)
    for i in range(5):
        _step_both(eager, step, a, b, i)
    assert step.failed is None and int(counters["stats"]["unique_graphs"]) == 1, counters["stats"]
    assert all(isinstance(g["lr"], torch.Tensor) for g in plain.param_groups)
    assert float(plain.param_groups[0]["lr"]) == pytest.approx(0.02 * 0.8**4)
    for p, q in zip(a, b, strict=True):
        assert p.stride() == q.stride()  # the channels-last factors stepped in place
        torch.testing.assert_close(q, p, rtol=1e-5, atol=1e-6)
    assert not torch.equal(b[0], _params()[0])  # it did step


def test_a_failing_compiler_warns_once_and_steps_eagerly(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(gm, inputs):  # type: ignore[no-untyped-def]
        raise RuntimeError("no compiler\nhere")

    monkeypatch.setattr(compiled_optim, "BACKEND", broken)
    told: list[str] = []
    a, b = _params(), _params()
    eager = torch.optim.Adam(_groups(a), betas=(0.9, 0.99))
    plain = torch.optim.Adam(_groups(b), betas=(0.9, 0.99))
    use_tensor_lr(plain)
    step = CompiledAdamStep(plain, told.append, compiles=4)
    for i in range(3):
        _step_both(eager, step, a, b, i)
    step.use(plain)  # a new optimiser after a failure: still eager, no second warning
    _step_both(eager, step, a, b, 3)
    assert len(told) == 1 and told[0].startswith(compiled_optim.FAILED) and "\n" not in told[0]
    assert "no compiler" in told[0]
    for p, q in zip(a, b, strict=True):
        torch.testing.assert_close(q, p, rtol=1e-6, atol=1e-7)


def test_load_state_keeps_the_optimisers_own_flags_and_rate_kind() -> None:
    a = _params()
    fused = DenseAdam(_groups(a), betas=(0.9, 0.99), fused=True)
    for p in a:
        p.grad = torch.ones_like(p)
    fused.step()
    plain = torch.optim.Adam(_groups(_params(1)[:0] + a), betas=(0.9, 0.99))
    use_tensor_lr(plain)
    load_state(plain, fused.state_dict())
    for g in plain.param_groups:
        assert not g["fused"] and isinstance(g["lr"], torch.Tensor)
    assert float(plain.param_groups[1]["lr"]) == pytest.approx(1e-3)
    assert plain.state[a[0]]["step"].device.type == "cpu" and float(plain.state[a[0]]["step"]) == 1.0
    back = DenseAdam(_groups(a), betas=(0.9, 0.99), fused=True)
    load_state(back, plain.state_dict())
    assert all(g["fused"] and isinstance(g["lr"], float) for g in back.param_groups)
    torch.testing.assert_close(back.state[a[2]]["exp_avg"], fused.state[a[2]]["exp_avg"])


def _run(cfg: TrainConfig, out: Path, dataset, stop_after: int | None = None, resume: bool = False):  # type: ignore[no-untyped-def]
    trainer = Trainer(cfg, out, dataset, resume=resume, progress=False)
    recorded: list[float] = []
    losses = trainer.method.losses

    def spy(state, iteration):  # type: ignore[no-untyped-def]
        step = losses(state, iteration)
        recorded.append(float(step.total().detach()))
        return step

    trainer.method.losses = spy  # type: ignore[method-assign]
    trainer.train(stop_after)
    return trainer, recorded


@pytest.mark.parametrize("first", [True, False])
def test_a_run_trains_and_resumes_either_way_like_the_eager_run(
    dataset_dir: Path,
    dataset,
    tmp_path: Path,
    first: bool,
    monkeypatch: pytest.MonkeyPatch,
    capsys,  # type: ignore[no-untyped-def]
) -> None:
    monkeypatch.setattr(compiled_optim, "BACKEND", "aot_eager")
    cfg = test_train._config(dataset_dir, method="nerf-gt")
    _, eager = _run(cfg, tmp_path / "eager", dataset)
    cfg.compile_optimizer = first
    trainer, head = _run(cfg, tmp_path / "run", dataset, stop_after=3)
    assert (trainer.adam_step is not None) == first
    cfg.compile_optimizer = not first
    resumed, tail = _run(cfg, tmp_path / "run", dataset, resume=True)
    assert resumed.iteration == cfg.iters and resumed.model.field.resolution == 20  # upsampled twice
    compiled = resumed.adam_step if not first else trainer.adam_step
    assert compiled is not None and compiled.failed is None
    rates = [g["lr"] for g in resumed.optimizer.param_groups]
    assert all(isinstance(r, torch.Tensor) for r in rates) == (not first)
    assert all(isinstance(r, float) for r in rates) == first
    assert "warning" not in capsys.readouterr().err
    assert len(head + tail) == cfg.iters and all(map(math.isfinite, head + tail))
    assert head + tail == pytest.approx(eager, rel=1e-4)


def test_fp16_amp_with_a_compiled_optimiser_is_refused(dataset_dir: Path) -> None:
    cfg = test_train._config(dataset_dir, method="nerf-gt")
    cfg.compile_optimizer, cfg.amp = True, "fp16"
    with pytest.raises(InputError, match="gradient scaler") as err:
        cfg.validate()
    assert err.value.params == ("compile_optimizer", "amp")


def test_a_compiled_update_that_ran_and_then_raises_is_not_retried_eagerly(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(compiled_optim, "BACKEND", "aot_eager")
    b = _params()
    plain = torch.optim.Adam(_groups(b), betas=(0.9, 0.99))
    use_tensor_lr(plain)
    step = CompiledAdamStep(plain, pytest.fail, compiles=4)
    for p in b:
        p.grad = torch.ones_like(p)
    step()
    assert step.ran

    def broken() -> None:  # e.g. out of memory half-way through the update
        raise RuntimeError("out of memory")

    step.compiled = broken  # type: ignore[method-assign]
    before = [p.detach().clone() for p in b]
    with pytest.raises(RuntimeError, match="out of memory"):
        step()
    assert step.failed is None and all(torch.equal(p, q) for p, q in zip(b, before, strict=True))

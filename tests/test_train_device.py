"""The training GPU on a CPU-only machine: targets kept on the device (the decision with fake free memory, the
gathers on the tensors' device), the batch-memory estimate refused up front (fake free memory), and
``--device cuda`` without CUDA as one line with exit 2."""

from __future__ import annotations

import traceback
from pathlib import Path

import pytest
import torch

import test_train
from spikenerf.cli import main
from spikenerf.core.errors import InputError
from spikenerf.core.limits import NO_LIMITS_ENV
from spikenerf.data.targets import ImageTargets, SpikeTargets
from spikenerf.train.device import batch_bytes, check_batch_fits, keep_targets_on_device, resident_names
from spikenerf.train.methods import make_method
from spikenerf.train.preflight import check_step_memory, gpu_default_batch, model_config

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures
CUDA = torch.device("cuda")  # only its name is used with a fake free-memory value: no CUDA call is made


def test_targets_go_to_the_gpu_while_they_fit_in_half_its_free_memory() -> None:
    sizes = {"targets": 100, "spikes": 50}
    assert resident_names(sizes, None) == []  # not a GPU
    assert resident_names(sizes, 400) == ["targets", "spikes"]
    assert resident_names(sizes, 220) == ["targets"]
    assert resident_names(sizes, 100) == ["spikes"]


def test_what_stays_resident_leaves_room_for_the_step() -> None:
    from types import SimpleNamespace

    def method():  # type: ignore[no-untyped-def]
        images = SimpleNamespace(nbytes=100)
        return SimpleNamespace(targets=SimpleNamespace(images=images, images_on=lambda d: "on " + d.type),
                               spikes=None, counts=None)  # fmt: skip

    roomy, tight = method(), method()
    assert keep_targets_on_device(roomy, CUDA, free=400) == ["targets"] and roomy.targets == "on cuda"
    assert keep_targets_on_device(tight, CUDA, free=400, reserve=250) == []  # 150 left: half is 75 < 100
    assert tight.targets.images.nbytes == 100  # not moved


def test_nothing_moves_off_cuda(dataset_dir: Path, dataset) -> None:  # type: ignore[no-untyped-def]
    method = make_method(test_train._config(dataset_dir, method="spike-nerf"))
    method.build_targets(dataset)
    targets, spikes = method.targets, method.spikes
    assert keep_targets_on_device(method, torch.device("cpu"), free=2**40) == []
    assert method.targets is targets and method.spikes is spikes


def test_gathers_run_on_the_tensors_device_and_equal_the_host_ones() -> None:
    gen = torch.Generator().manual_seed(0)
    images = torch.rand(5, 6, 7, 3, generator=gen).half()
    targets = ImageTargets(torch.eye(4).expand(5, 1, 4, 4), images, torch.arange(5))
    index, pixels = torch.tensor([0, 4, 2]), torch.tensor([[6, 5], [0, 0], [3, 2]])
    moved = targets.images_on("cpu")
    assert torch.equal(moved.gather(index, pixels), targets.gather(index, pixels))
    assert torch.equal(moved.gather(index, pixels)[0], images[0, 5, 6].float())
    assert moved.steps is targets.steps  # the host keeps the steps (the pose refiners read them there)
    spikes = SpikeTargets(
        (torch.rand(9, 6, 7, 1, generator=gen) < 0.5).to(torch.uint8), torch.eye(4).expand(9, 4, 4), 1.0
    )
    moved = spikes.spikes_on("meta")  # the poses go with the spikes (a step indexes both there)
    assert moved.spikes.device.type == moved.poses.device.type == "meta"
    window = spikes.spikes_on("cpu").window(torch.arange(2, 6), pixels)
    assert window.shape == (4, 3, 1)
    for j, (x, y) in enumerate(pixels.tolist()):  # steps 2..5 at pixel (x, y)
        assert torch.equal(window[:, j], spikes.spikes[2:6, y, x].float())


def test_a_batch_that_does_not_fit_the_gpu_is_refused_up_front(
    dataset_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = test_train._config(dataset_dir, method="nerf-gt")
    field = model_config(cfg)
    need = batch_bytes(cfg.field, field, 1 << 20, 0.0)
    assert need > 2 * batch_bytes(cfg.field, field, 1 << 19, 0.0) - 1  # linear in the rays
    check_batch_fits(cfg.field, field, 1 << 20, 0.0, CUDA, free=int(need) + 1)  # fits
    with pytest.raises(InputError, match=r"batch: 1048576 rays a step need about .* of GPU memory") as err:
        check_batch_fits(cfg.field, field, 1 << 20, 0.0, CUDA, free=int(need) - 1)
    assert err.value.params == ("batch", "no_limits") and "\n" not in str(err.value)
    check_batch_fits(cfg.field, field, 1 << 20, 0.0, torch.device("cpu"), free=1)  # a CPU: not checked
    monkeypatch.setenv(NO_LIMITS_ENV, "1")
    check_batch_fits(cfg.field, field, 1 << 20, 0.0, CUDA, free=1)  # --no-limits: not checked
    monkeypatch.delenv(NO_LIMITS_ENV)
    cfg.batch = 10**8  # the trainer's check: the batch and the spike window, before any work
    with pytest.raises(InputError, match="rays a step need about"):
        check_step_memory(cfg, make_method(cfg), CUDA, free=80 * 2**30)


@pytest.mark.parametrize("method", ["spike-integral", "nerf-gt"])
def test_the_default_batch_is_four_times_larger_on_cuda_where_it_fits(
    dataset_dir: Path, monkeypatch: pytest.MonkeyPatch, method: str
) -> None:
    monkeypatch.delenv(NO_LIMITS_ENV, raising=False)
    given = test_train._config(dataset_dir, method=method, batch=None)
    config = given.resolved()
    cpu_rays = {"spike-integral": 4096, "nerf-gt": 1024}[method]
    assert config.batch == cpu_rays == given.rays_per_step("cpu") == given.rays_per_step("cuda") // 4
    big = 80 * 2**30
    assert gpu_default_batch(given, config, CUDA, free=big).batch == 4 * cpu_rays
    assert gpu_default_batch(given, config, torch.device("cpu"), free=big) is config
    need = batch_bytes(config.field, model_config(config), 4 * cpu_rays, 0.0)
    assert gpu_default_batch(given, config, CUDA, free=int(need) // 2) is config  # does not fit: CPU's
    asked = test_train._config(dataset_dir, method=method, batch=512)
    assert gpu_default_batch(asked, asked.resolved(), CUDA, free=big).batch == 512  # asked for: kept


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks a machine without CUDA")
@pytest.mark.parametrize("command", ["train", "eval"])
def test_device_cuda_without_cuda_is_one_line_with_exit_2(
    dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    args = [command, str(dataset_dir), "--device", "cuda", "--quiet"]
    if command == "train":
        args += ["--iters", "1", "--out", str(tmp_path / "run")]
    else:  # eval of a finished run
        main(["train", str(dataset_dir), "--iters", "1", "--batch", "16", "--device", "cpu", "--quiet",
              "--eval-every", "0", "--out", str(tmp_path / "run")])  # fmt: skip
        args[1] = str(tmp_path / "run")
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        main(args)
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in err
    assert err.startswith("spikenerf: error: ") and "--device" in err and "no CUDA device" in err


def _host_reads(trainer, steps: int) -> dict[tuple[str, str], int]:  # type: ignore[no-untyped-def]
    """(tensor method, calling file) → calls of the ways a tensor's value reaches the host (a sync on a GPU)
    during ``steps`` training steps."""
    reads: dict[tuple[str, str], int] = {}
    names = ("item", "tolist", "cpu", "numpy", "__int__", "__float__", "__bool__", "__index__")
    originals = {name: getattr(torch.Tensor, name) for name in names}

    def hooked(name: str):  # type: ignore[no-untyped-def]
        def read(self, *args, **kw):  # type: ignore[no-untyped-def]
            caller = traceback.extract_stack(limit=2)[0].filename.split("spikenerf/")[-1]
            reads[(name, caller)] = reads.get((name, caller), 0) + 1
            return originals[name](self, *args, **kw)

        return read

    try:
        for name in names:
            setattr(torch.Tensor, name, hooked(name))
        trainer.train(stop_after=steps)
    finally:
        for name, original in originals.items():
            setattr(torch.Tensor, name, original)
    return reads


@pytest.mark.parametrize("field", ["mlp", "grid"])
def test_the_training_loop_reads_no_device_value_per_step(
    dataset_dir: Path, dataset, tmp_path: Path, field: str, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """Methods, losses, targets and the trainer read nothing back per step (logged values are read every
    log_every steps); with the grid, only its renderer (the packed march's sample count) and the occupancy
    updates on their schedule do."""
    from spikenerf.core import tensor_checks
    from spikenerf.train.trainer import Trainer

    cfg = test_train._config(dataset_dir, method="spike-nerf", field=field)
    cfg.iters, cfg.eval_every, cfg.ckpt_every, cfg.log_every = 40, 0, 1000, 1000
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    trainer.checkpoint = lambda *_a, **_k: None  # type: ignore[method-assign]
    trainer.evaluate = lambda *_a, **_k: float("nan")  # type: ignore[method-assign]
    trainer.train(stop_after=12)  # past the spike loss's warm-up and ramp
    monkeypatch.setattr(tensor_checks, "readable", lambda x: False)  # as on a GPU: input checks read nothing
    reads = _host_reads(trainer, 10)
    assert {caller for _, caller in reads} <= {"train/logger.py", "render/grid_model.py", "fields/grid.py",
                                               "fields/occupancy.py"}, reads  # fmt: skip
    assert sum(n for (_, caller), n in reads.items() if caller == "train/logger.py") <= 2  # the last read
    if field == "mlp":
        assert {caller for _, caller in reads} == {"train/logger.py"}


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_targets_and_spikes_stay_on_the_gpu_while_training(
    dataset_dir: Path, dataset, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    from spikenerf.train.trainer import Trainer

    cfg = test_train._config(dataset_dir, method="spike-nerf")
    cfg.device = "cuda"
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    assert trainer.resident == ["targets", "spikes"]
    assert trainer.method.targets.images.is_cuda and trainer.method.spikes.spikes.is_cuda
    assert trainer.train().iteration == cfg.iters

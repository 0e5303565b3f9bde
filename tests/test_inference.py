"""Inference settings of eval and render: chunked renders, autocast precision, automatic chunks sized from
the free GPU memory (a fake free-memory value on the CPU), and on CUDA half precision within 0.05 dB."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

import test_train
from spikenerf.core.errors import InputError
from spikenerf.eval.evaluate import evaluate_run
from spikenerf.fields import GridFieldConfig, MLPFieldConfig
from spikenerf.fields.memory import ray_bytes, samples_per_ray
from spikenerf.render import build_model, render_image
from spikenerf.render.inference import (
    CPU_CHUNK,
    MAX_CHUNK,
    MEMORY_SHARE,
    auto_chunk,
    inference_chunk,
    resolve_precision,
)
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.trajectory import Intrinsics
from spikenerf.train.trainer import Trainer

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures
BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
GRID = GridFieldConfig(n_voxels_init=24**3, n_voxels_final=24**3, occupancy=False, init_scale=0.5,
                       density_shift=0.0, distance_scale=5.0)  # fmt: skip
K = Intrinsics.from_fov(24, 20, 0.8)


def _model(kind: str):  # type: ignore[no-untyped-def]
    torch.manual_seed(0)
    return build_model(kind, 3, BOX, GRID if kind == "grid" else MLPFieldConfig.tiny()).eval()


def _pose() -> np.ndarray:
    return look_at(np.array([0.3, 2.5, 1.2]), np.zeros(3))


@pytest.mark.parametrize("kind", ["grid", "mlp"])
def test_chunked_renders_equal_one_render_call(kind: str) -> None:
    model = _model(kind)
    whole = render_image(model, _pose(), K, chunk=10**6)
    assert whole.opacity.max() > 0.05  # the random field is not empty: the comparison means something
    for chunk in (7, 100, 24 * 20):
        part = render_image(model, _pose(), K, chunk=chunk)
        for a, b in ((part.color, whole.color), (part.depth, whole.depth), (part.opacity, whole.opacity)):
            assert torch.allclose(a, b, atol=1e-6, rtol=1e-5)
        assert part.num_samples == whole.num_samples


@pytest.mark.parametrize("kind", ["grid", "mlp"])
def test_bf16_autocast_renders_float32_close_to_fp32(kind: str) -> None:
    model = _model(kind)
    fp32 = render_image(model, _pose(), K)
    assert torch.equal(fp32.color, render_image(model, _pose(), K, precision="fp32").color)
    bf16 = render_image(model, _pose(), K, precision="bf16")
    assert bf16.color.dtype == bf16.depth.dtype == torch.float32
    assert (bf16.color - fp32.color).abs().max() < 0.05


def test_precision_is_checked_and_fp16_needs_cuda() -> None:
    assert resolve_precision("bf16", torch.device("cpu")) == "bf16"
    assert resolve_precision("auto", torch.device("cpu")) == "fp32"
    assert resolve_precision("auto", torch.device("cuda")) == "fp16"
    with pytest.raises(InputError, match="precision fp16 needs a CUDA device") as err:
        resolve_precision("fp16", torch.device("cpu"))
    assert err.value.params == ("precision",)
    with pytest.raises(InputError, match="precision must be one of auto, fp32, fp16, bf16"):
        resolve_precision("fp8", torch.device("cpu"))


def test_automatic_chunk_follows_the_free_memory() -> None:
    model = _model("grid")
    assert inference_chunk(model, 0) == auto_chunk(model, None) == CPU_CHUNK  # a CPU: as before
    assert inference_chunk(model, 123) == 123
    per_ray = ray_bytes("grid", GRID, training=False)
    free = 40 * 2**30
    expected = int(MEMORY_SHARE * free / per_ray) // CPU_CHUNK * CPU_CHUNK
    assert inference_chunk(model, 0, free=free) == auto_chunk(model, free) == max(CPU_CHUNK, expected)
    assert auto_chunk(model, 2**50) == MAX_CHUNK and auto_chunk(model, 1) == CPU_CHUNK
    with pytest.raises(InputError, match="chunk must be an integer ≥ 0"):
        inference_chunk(model, -1)


def test_ray_estimates_grow_with_the_field() -> None:
    small, large = GridFieldConfig(n_voxels_final=64**3), GridFieldConfig(n_voxels_final=300**3)
    assert samples_per_ray("grid", large) > samples_per_ray("grid", small)
    assert ray_bytes("grid", large) > ray_bytes("grid", small)
    assert samples_per_ray("mlp", MLPFieldConfig()) == 64 + 64 + 128
    for kind in ("grid", "mlp"):  # training keeps the activations for the backward pass
        assert ray_bytes(kind, training=True) > ray_bytes(kind, training=False) > 0


def test_eval_in_bf16_on_a_cpu_records_its_precision(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    run = tmp_path / "run"
    Trainer(test_train._config(dataset_dir, method="nerf-gt"), run, dataset, progress=False).train()
    fp32 = evaluate_run(run, lpips_backbone=None, progress=False, chunk=0)
    assert fp32["precision"] == "fp32"
    again = evaluate_run(run, lpips_backbone=None, progress=False, chunk=37)
    assert again["mean"]["psnr"] == pytest.approx(fp32["mean"]["psnr"], abs=1e-4)  # chunks: same renders
    bf16 = evaluate_run(run, lpips_backbone=None, progress=False, precision="bf16")
    assert json.loads((run / "metrics.json").read_text())["precision"] == "bf16"
    assert abs(bf16["mean"]["psnr"] - fp32["mean"]["psnr"]) < 0.5
    with pytest.raises(InputError, match="precision fp16 needs a CUDA device"):
        evaluate_run(run, lpips_backbone=None, progress=False, precision="fp16")


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("precision", ["fp16", "bf16"])
def test_half_precision_eval_on_cuda_within_005_db(
    dataset_dir: Path, dataset, tmp_path: Path, precision: str
) -> None:  # type: ignore[no-untyped-def]
    cfg = test_train._config(dataset_dir, method="nerf-gt")
    cfg.device, cfg.iters = "cuda", 60
    run = tmp_path / "run"
    Trainer(cfg, run, dataset, progress=False).train()
    fp32 = evaluate_run(run, device="cuda", lpips_backbone=None, progress=False, chunk=0)
    half = evaluate_run(run, device="cuda", lpips_backbone=None, progress=False, chunk=0, precision=precision)
    assert abs(half["mean"]["psnr"] - fp32["mean"]["psnr"]) <= 0.05

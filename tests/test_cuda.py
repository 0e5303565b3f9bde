"""The CUDA path: train, render and eval on ``cuda``, checkpoint resume, bf16/fp16 autocast (skipped without
a CUDA device; run them with ``pytest -m cuda`` on a GPU host)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import torch

import test_train
from spikenerf.cli import main
from spikenerf.train.checkpoint import CHECKPOINT, load_checkpoint
from spikenerf.train.trainer import Trainer

_config = test_train._config
dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures

pytestmark = [
    pytest.mark.cuda,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device"),
]


def _cuda_config(dataset_dir: Path, **kw):  # type: ignore[no-untyped-def]
    cfg = _config(dataset_dir, method="spike-nerf", **kw)
    cfg.device = "cuda"
    return cfg


def test_train_render_eval_on_cuda(dataset_dir: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    main(["train", str(dataset_dir), "--out", str(run), "--iters", "4", "--batch", "64", "--device", "cuda"])
    if importlib.util.find_spec("imageio_ffmpeg") is not None:  # render writes an mp4; a GPU host may lack it
        main(["render", str(run), "--out", str(tmp_path / "renders")])
    main(["eval", str(run), "--device", "cuda"])
    summary = json.loads((run / "summary.json").read_text())
    assert summary["device"].startswith("cuda") and summary["iteration"] == 4
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["mean"]["psnr"] > 0


@pytest.mark.parametrize("amp", ["none", "bf16", "fp16"])
def test_training_step_on_cuda_with_autocast(dataset_dir: Path, dataset, tmp_path: Path, amp: str) -> None:  # type: ignore[no-untyped-def]
    trainer = Trainer(_cuda_config(dataset_dir, amp=amp), tmp_path / "run", dataset, progress=False)
    summary = trainer.train()
    assert summary.iteration == 6 and all(p.is_cuda for p in trainer.model.parameters())
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())


def test_checkpoint_resume_on_cuda(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The checkpoint restores the state bit for bit; the continued run matches an uninterrupted one.

    Bit for bit after the resume point needs deterministic kernels: CUDA ``index_add``/``grid_sample``
    backward accumulate with atomics, so the comparison of the two finished runs uses a tolerance.
    """
    cfg = _cuda_config(dataset_dir)
    first = Trainer(cfg, tmp_path / "b", dataset, progress=False)
    first.train(stop_after=3)
    saved = load_checkpoint(tmp_path / "b" / CHECKPOINT)
    resumed = Trainer(cfg, tmp_path / "b", dataset, resume=True, progress=False)
    state = resumed.model.state_dict()
    assert all(torch.equal(state[k].cpu(), v) for k, v in saved["model"].items())
    resumed.train()
    straight = Trainer(cfg, tmp_path / "a", dataset, progress=False)
    straight.train()
    sa, sb = straight.model.state_dict(), resumed.model.state_dict()
    assert all(torch.allclose(sa[k].float(), sb[k].float(), atol=1e-4) for k in sa)

"""Learned training targets on the training device: batched inference equals frame-by-frame inference, and the
whole-stream reconstruction is cached in the run folder (written once, reused on resume, rebuilt when its key
changes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

import test_train
from spikenerf.core.errors import InputError
from spikenerf.data import recon_cache
from spikenerf.data.recon_cache import CACHE_DIR, learned_targets_in
from spikenerf.data.targets import load_stream, stream_targets
from spikenerf.recon.infer import reconstruct_learned
from spikenerf.train.trainer import Trainer

dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures


def _stream(mode: str) -> np.ndarray:
    rng = np.random.default_rng(4)
    shape = (50, 3, 20, 12) if mode == "rgb" else (50, 20, 12)
    return (rng.random(shape) < 0.3).astype(np.uint8)


@pytest.mark.parametrize("mode", ["gray", "rgb"])
def test_batched_learned_inference_equals_frame_by_frame(mode: str) -> None:
    spikes = _stream(mode)
    one = reconstruct_learned(spikes, mode, 1.5, batch=1)
    for batch in (4, 7):
        many = reconstruct_learned(spikes, mode, 1.5, device="cpu", batch=batch)
        np.testing.assert_allclose(many, one, rtol=1e-5, atol=1e-5)
    assert np.array_equal(reconstruct_learned(spikes, mode, 1.5), one)  # the CPU default: frame by frame


def _count_builds(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls: list[int] = []
    build = recon_cache.build_learned

    def counted(*args, **kw):  # type: ignore[no-untyped-def]
        calls.append(1)
        return build(*args, **kw)

    monkeypatch.setattr(recon_cache, "build_learned", counted)
    return calls


def test_learned_targets_are_cached_in_the_run_and_reused_on_resume(
    dataset_dir: Path, dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    calls = _count_builds(monkeypatch)
    cfg = test_train._config(dataset_dir, method="nerf-recon")
    cfg.targets.recon, cfg.targets.window_poses = "learned", 1
    run = tmp_path / "run"
    first = Trainer(cfg, run, dataset, progress=False)
    first.train(stop_after=2)
    files = list((run / CACHE_DIR).glob("learned-*.npy"))
    assert len(calls) == 1 and len(files) == 1 and np.load(files[0]).dtype == np.float16
    resumed = Trainer(cfg, run, dataset, resume=True, progress=False)
    assert len(calls) == 1  # read back, not rebuilt
    assert first.method.targets is not None and resumed.method.targets is not None
    assert torch.equal(first.method.targets.images, resumed.method.targets.images)
    # the cache is exact: the same float16 targets as without it
    plain = stream_targets(dataset, "gray", "learned", 41, mask=False)
    assert torch.equal(plain.images, resumed.method.targets.images.cpu())
    resumed.train()
    assert resumed.iteration == cfg.iters


def test_a_changed_key_rebuilds_and_replaces_the_cache(
    dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    calls = _count_builds(monkeypatch)
    stream = load_stream(dataset, "gray")
    folder = tmp_path / "run"

    def build(spikes: np.ndarray, fingerprint: dict) -> np.ndarray:
        with learned_targets_in(folder, "cpu", fingerprint):
            return recon_cache.learned_stream(spikes, dataset.threshold, None, 41)

    a = build(stream, {"steps": len(stream)})
    assert build(stream, {"steps": len(stream)}) is not None and len(calls) == 1
    build(stream, {"steps": len(stream), "size": [1, 1]})  # another dataset fingerprint
    assert len(calls) == 2
    changed = stream.copy()
    changed[5, 3, 3] ^= 1  # one spike differs: the stream's digest is in the key
    b = build(changed, {"steps": len(stream), "size": [1, 1]})
    assert len(calls) == 3 and not np.array_equal(a, b)
    assert len(list((folder / CACHE_DIR).glob("learned-*.npy"))) == 1  # the old keys' files are gone
    outside = recon_cache.learned_stream(stream, dataset.threshold, None, 41)  # no context: no cache
    assert len(calls) == 3 and np.array_equal(outside.astype(np.float16).astype(np.float32), a)


def test_a_damaged_cache_is_built_again_and_missing_weights_are_named(
    dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """A cache filled with NaN was used (the run "diverged: lower --lr"); missing weights were an OSError."""
    calls = _count_builds(monkeypatch)
    stream, folder = load_stream(dataset, "gray"), tmp_path / "run"
    with learned_targets_in(folder, "cpu", {"steps": len(stream)}):
        good = recon_cache.learned_stream(stream, dataset.threshold, None, 41)
        (cached,) = (folder / CACHE_DIR).glob("learned-*.npy")
        np.save(cached, np.full(stream.shape, np.nan, np.float16))
        again = recon_cache.learned_stream(stream, dataset.threshold, None, 41)
    assert len(calls) == 2 and np.array_equal(again, good) and np.isfinite(np.load(cached)).all()
    monkeypatch.setattr("spikenerf.recon.net.shipped_weights", lambda: tmp_path / "gone.pt")
    with (
        learned_targets_in(folder, "cpu", {"steps": len(stream)}),
        pytest.raises(InputError, match=r"gone\.pt: weights file not found"),
    ):
        recon_cache.learned_stream(stream, dataset.threshold, None, 41)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_batched_learned_inference_on_cuda_equals_the_cpu() -> None:
    spikes = _stream("rgb")
    cpu = reconstruct_learned(spikes, "rgb", 1.5)
    gpu = reconstruct_learned(spikes, "rgb", 1.5, device="cuda")  # CUDA_BATCH frames per call
    # cuDNN convolves in TF32 by default (10-bit mantissa): 5.8e-4 apart on an H200, about one float16 step
    # of the stored targets at 0.5 (4.9e-4); a wrong frame order or tile seam would be off by far more
    np.testing.assert_allclose(gpu, cpu, rtol=0, atol=2e-3)


def test_a_target_refusal_names_the_dataset(dataset, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    """``train --recon learned`` on a 30-step dataset gave "window of 41 steps is longer…" and no path."""
    from spikenerf.data import targets

    def refuses(*args, **kw):  # type: ignore[no-untyped-def]
        raise InputError(
            "the learned reconstructor's window of 41 steps is longer than the stream (30 steps)"
        )

    monkeypatch.setattr(targets, "masked_reconstruction", refuses)
    with pytest.raises(InputError, match="longer than the stream") as err:
        stream_targets(dataset, "gray", "learned", 41, mask=False)
    assert err.value.path is not None and Path(err.value.path) == Path(dataset.root)

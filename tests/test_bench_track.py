"""``benchmarks/experiments/bench_track_windows.py``: a track of one step is that step's count at the
rendered pixel, and a longer track reads the spikes around it."""

from __future__ import annotations

from pathlib import Path

import torch

import test_train
from helpers import load_benchmark
from spikenerf.data.rays import pixel_rays
from spikenerf.train.trainer import Trainer

BENCH = load_benchmark("experiments/bench_track_windows")
dataset_dir, dataset = test_train.dataset_dir, test_train.dataset  # the module's fixtures


def test_a_one_step_track_is_the_steps_count_at_the_pixel(dataset_dir: Path, dataset, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    cfg = test_train._config(dataset_dir, method="spike-integral")
    trainer = Trainer(cfg, tmp_path / "run", dataset, progress=False)
    counts = trainer.method.counts
    _, _, pixels, steps = trainer.method.draw(trainer)
    step = steps[:, 0]
    origins, dirs = pixel_rays(counts.poses[step], dataset.intrinsics, pixels)
    points = origins + 2.5 * dirs  # any depth: the point lies on the pixel's ray
    one = BENCH.track_counts(trainer, points, step, 0)
    torch.testing.assert_close(one, counts.window_mean(step, step + 1, pixels), atol=0, rtol=0)
    longer = BENCH.track_counts(trainer, points, step, 3)
    assert longer.shape == one.shape and not torch.equal(longer, one)
    assert torch.all((longer >= 0) & (longer <= counts.threshold))  # a mean of 0/1 spikes

"""The memory and disk a benchmark (or demo) will need, checked before its first step starts."""

from __future__ import annotations

from typing import Any

from spikenerf.camera.modes import COLORS
from spikenerf.capture.simulate import estimate_resources
from spikenerf.core.limits import check_resources
from spikenerf.fields.registry import field_config, field_memory
from spikenerf.pipelines.benchmark.cells import training_seeds

#: the streams ``simulate --color all`` writes (the benchmark's dataset command when it needs gray and rgb)
SIMULATE_ALL = COLORS


def check_benchmark_resources(cfg: Any) -> None:
    """Refuse (naming ``size/frames``) a benchmark whose datasets, runs and renders exceed the machine.

    Memory: the larger of one ``simulate`` and one ``train`` step (stream targets, field, a batch of 1024
    rays), times ``jobs`` steps at once. Disk: every scene's dataset plus every cell's checkpoint and
    renders, per training seed (the datasets hold every stream ``simulate`` writes).
    """
    colors = SIMULATE_ALL if len(cfg.colors) > 1 else tuple(cfg.colors)
    sim_memory, sim_disk = estimate_resources(
        cfg.size, cfg.size, cfg.frames, colors, cfg.test_views, 4, 10, max(1, cfg.frames // 100)
    )
    cfg_field = field_config(cfg.field_kind, None)
    params, per_ray, ckpt = field_memory(cfg.field_kind, cfg_field)
    channels = 3 if "rgb" in cfg.colors else 1
    train_memory = float(cfg.frames) * cfg.size * cfg.size * channels * 10 + params + 1024 * per_ray
    cells = len(cfg.scenes) * len(cfg.colors) * len(cfg.variants) * len(training_seeds(cfg))
    render = cfg.test_views * float(cfg.size) * cfg.size * 14 if cfg.render else 0.0
    memory = max(sim_memory, train_memory) * max(1, cfg.jobs)
    disk = len(cfg.scenes) * sim_disk + cells * (ckpt + render)
    check_resources(memory, disk, cfg.out, "size/frames")

"""What a run settles and checks before any work: the arguments of the API, the dataset folder it records,
the field config of its settings, its memory and disk estimate, whether a step fits the GPU, and the CUDA
default batch. Each check raises an InputError naming the parameter, before anything is written or built.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import torch

from spikenerf.core.errors import InputError, as_path, is_integer
from spikenerf.core.limits import check_resources
from spikenerf.data.dataset import SpikeDataset
from spikenerf.fields.registry import field_config, field_memory
from spikenerf.train.config import TrainConfig
from spikenerf.train.device import check_batch_fits
from spikenerf.train.methods import make_method


def model_config(config: TrainConfig) -> Any:
    """The field config: defaults + ``config.field_config``; its schedules (the grid's) rescaled to
    ``config.iters`` unless ``field_config`` sets ``iterations``."""
    cfg = field_config(config.field, dict(config.field_config))
    if "iterations" not in config.field_config:
        cfg = cfg.for_iterations(config.iters)
    return cfg


def check_api_args(config: object, out: object, dataset: object) -> None:
    """InputError naming ``config``, ``out`` or ``dataset`` when it is not what
    :func:`~spikenerf.train.trainer.train` and :class:`~spikenerf.train.trainer.Trainer` take (a dict for
    the config, None or a number for the folder, a path for the loaded dataset: each failed deep inside as an
    AttributeError or a TypeError)."""
    if not isinstance(config, TrainConfig):
        raise InputError(
            f"config must be a TrainConfig (TrainConfig.from_dict for a mapping), found "
            f"{type(config).__name__}",
            param="config",
        )
    as_path(out, "out")
    if dataset is not None and not isinstance(dataset, SpikeDataset):
        raise InputError(
            f"dataset must be a loaded SpikeDataset or None (config.dataset gives the folder), found "
            f"{type(dataset).__name__}",
            param="dataset",
        )


def dataset_recorded(config: TrainConfig, dataset: SpikeDataset | None) -> TrainConfig:
    """``config`` with ``dataset`` the absolute path of the folder the run trains on: ``dataset``'s, when a
    loaded one is given (``config.dataset`` empty or the same folder; another one is an InputError), else
    ``config.dataset`` resolved. ``config.yaml`` records it, so that ``load_run`` and ``evaluate_run`` find
    the data from any working directory (a relative path held only from the folder training ran in)."""
    named = str(config.dataset) if isinstance(config.dataset, (str, os.PathLike)) else config.dataset
    if dataset is None:
        if not isinstance(named, str) or not named:
            return config  # validate() names the problem
        return dataclasses.replace(config, dataset=str(Path(named).resolve()))
    root = Path(dataset.root).resolve()
    if isinstance(named, str) and named and Path(named).resolve() != root:
        raise InputError(
            f"config.dataset names {named} but the dataset given was loaded from {dataset.root}: give one "
            "(or the same folder in both)",
            param=("dataset", "config.dataset"),
        )
    return dataclasses.replace(config, dataset=str(root))


def check_stop_after(stop_after: object) -> None:
    """InputError naming ``stop_after`` unless it is None or an integer ≥ 1."""
    integer = is_integer(stop_after)
    if stop_after is not None and not (integer and stop_after >= 1):  # type: ignore[operator]
        raise InputError(
            f"stop_after must be None or an integer ≥ 1, found {stop_after!r}", param="stop_after"
        )


def learned_cache(method: Any) -> bool:
    """Whether the run caches whole-stream learned reconstructions in its folder (``data/recon_cache.py``)."""
    return bool(method.uses_learned)


def check_train_resources(config: TrainConfig, dataset: SpikeDataset, out: Path) -> None:
    """Refuse a run whose estimated memory (targets, field, one batch) or checkpoint (and learned-target
    cache) exceeds the machine's."""
    k, steps = dataset.intrinsics, len(dataset.trajectory)
    method = make_method(config)
    if method.uses_spike_loss and config.spike.window > steps:  # before its memory: the clearer complaint
        raise InputError(
            f"spike.window: a {config.spike.window}-step window exceeds the {steps} recorded steps",
            param="spike.window",
        )
    targets = float(steps) * k.height * k.width * method.channels * 10 if method.uses_stream else 0.0
    params, per_ray, ckpt = field_memory(config.field, model_config(config))
    spike_rays = config.spike.window * config.spike.pixels if method.uses_spike_loss else 0
    rays = (config.rays_per_step() + spike_rays) * per_ray
    cache = float(steps) * k.height * k.width * method.channels * 2 if learned_cache(method) else 0
    sizes = "batch/spike.window/spike.pixels" if spike_rays else "batch"
    sizes = sizes if rays >= params else "field_config"
    check_resources(targets + params + rays, 2 * ckpt + cache, out, sizes)


def check_step_memory(
    config: TrainConfig, method: Any, device: torch.device, free: int | None = None
) -> None:
    """Refuse, before any work, a step whose rays (the batch and a spike window) do not fit in a CUDA
    device's free memory by estimate (:func:`spikenerf.train.device.check_batch_fits`)."""
    check_batch_fits(config.field, model_config(config), *step_size(config, method), device, free)


def step_size(config: TrainConfig, method: Any) -> tuple[int, float]:
    """(rays, parameter bytes) of a training step: the batch and a spike window's rays; the field's
    parameters with their gradients and Adam state (:func:`spikenerf.train.device.batch_bytes`)."""
    spike_rays = config.spike.window * config.spike.pixels if method.uses_spike_loss else 0
    params, _, _ = field_memory(config.field, model_config(config))
    return config.rays_per_step() + spike_rays, params


def gpu_default_batch(
    given: TrainConfig, config: TrainConfig, device: torch.device, free: int | None = None
) -> TrainConfig:
    """``config`` with the CUDA default batch (``given.rays_per_step("cuda")``, 4× the CPU one) where
    ``given`` named no batch, the run trains on CUDA and that step fits the device's ``free`` bytes (None:
    read from the device) by estimate; else ``config`` unchanged (its batch the CPU default, or the one
    asked for or stored)."""
    if given.batch is not None or device.type != "cuda":
        return config
    wide = dataclasses.replace(config, batch=given.rays_per_step("cuda"))
    try:
        check_step_memory(wide, make_method(wide), device, free)
    except InputError:
        return config
    return wide

"""The training GPU: what is kept on it, and whether a batch fits in it.

* :func:`keep_targets_on_device`: the target images and the recorded spikes move to a CUDA device once, at
  setup, so that each step gathers its batch there instead of on the host. The CPU path is unchanged.
* :func:`check_batch_fits`: the batch's estimated device memory (:func:`spikenerf.fields.memory.ray_bytes`
  × rays per step) against the free GPU memory, refused in one line before training.
"""

from __future__ import annotations

from typing import Any

import torch

from spikenerf.core.errors import InputError
from spikenerf.core.limits import human, limits_disabled
from spikenerf.fields.memory import ray_bytes
from spikenerf.render.inference import free_device_memory

#: the share of the free GPU memory that the targets kept on the training GPU may take
RESIDENT_SHARE = 0.5


def resident_names(sizes: dict[str, int], free: int | None) -> list[str]:
    """Which of the tensors ``sizes`` (name → bytes, in order) go to the GPU: while their sum stays within
    :data:`RESIDENT_SHARE` of ``free`` bytes (None: not a GPU, none)."""
    if free is None:
        return []
    budget, names = RESIDENT_SHARE * free, []
    for name, size in sizes.items():
        if size <= budget:
            names.append(name)
            budget -= size
    return names


def keep_targets_on_device(
    method: Any, device: torch.device, free: int | None = None, reserve: float = 0.0
) -> list[str]:
    """Move the method's target images and recorded spikes to a CUDA ``device`` once, so that every step
    gathers them there (no per-step host gather and copy); the names moved. Nothing moves off CUDA (the CPU
    path is unchanged) or what does not fit (:func:`resident_names` of ``free`` less ``reserve``, the bytes
    a training step will take; ``free`` None: read from the device)."""
    if device.type != "cuda":
        return []
    sizes = {}
    if getattr(method, "targets", None) is not None:
        sizes["targets"] = method.targets.images.nbytes
    if getattr(method, "spikes", None) is not None:
        sizes["spikes"] = method.spikes.spikes.nbytes
    if getattr(method, "counts", None) is not None:  # spike-integral's prefix counts
        sizes["counts"] = method.counts.nbytes
    free = free_device_memory(device) if free is None else free
    names = resident_names(sizes, None if free is None else max(0, int(free - reserve)))
    if "targets" in names:
        method.targets = method.targets.images_on(device)
    if "spikes" in names:
        method.spikes = method.spikes.spikes_on(device)
    if "counts" in names:
        method.counts = method.counts.on(device)
    return names


def batch_bytes(kind: str, field_config: Any, rays: int, params: float) -> float:
    """Estimated GPU bytes of a training step: ``rays`` rays through a ``kind`` field (forward and
    backward, :func:`~spikenerf.fields.memory.ray_bytes`) plus ``params`` bytes of parameters, gradients and
    Adam state."""
    return rays * ray_bytes(kind, field_config, training=True) + params


def check_batch_fits(
    kind: str, field_config: Any, rays: int, params: float, device: torch.device, free: int | None = None
) -> None:
    """InputError (naming ``batch``) when a step's estimated memory (:func:`batch_bytes`) exceeds the free
    memory of a CUDA ``device`` (``free``: its free bytes; None: read with ``torch.cuda.mem_get_info``).
    Nothing is checked off CUDA or with ``--no-limits``."""
    if device.type != "cuda" or limits_disabled():
        return
    free = free_device_memory(device) if free is None else free
    need = batch_bytes(kind, field_config, rays, params)
    if free is not None and need > free:
        raise InputError(
            f"batch: {rays} rays a step need about {human(need)} of GPU memory by estimate, but {device} has "
            f"{human(free)} free; lower batch, or pass no_limits to try anyway",
            param=("batch", "no_limits"),
        )

"""Inference settings of ``eval`` and ``render``: the precision of a render and the rays per render call.

* ``precision``: ``fp32`` (the default; a CPU render is bit-identical to before these settings existed),
  ``fp16`` or ``bf16`` (autocast: the networks' matrix products in half precision, the compositing and its
  output in float32). Half precision is meant for CUDA; ``bf16`` also runs on a CPU (used by the CPU
  tests), ``fp16`` needs CUDA.
* ``chunk``: rays per render call; 0 = automatic: :data:`CPU_CHUNK` off CUDA (as before), and on CUDA as
  many rays as :data:`MEMORY_SHARE` of the free GPU memory holds by :func:`spikenerf.fields.memory.ray_bytes`
  (between :data:`CPU_CHUNK` and :data:`MAX_CHUNK`), so a view renders in one or a few calls.
"""

from __future__ import annotations

import contextlib
import numbers

import torch

from spikenerf.core.errors import InputError
from spikenerf.fields.memory import ray_bytes
from spikenerf.render.base import RadianceModel
from spikenerf.render.choices import PRECISIONS
from spikenerf.render.choices import Precision as Precision  # (defined there, without torch)

_DTYPES = {"fp16": torch.float16, "bf16": torch.bfloat16}
#: rays per render call off CUDA (the fixed chunk before the automatic one)
CPU_CHUNK = 8192
#: the largest automatic chunk on CUDA
MAX_CHUNK = 1 << 20
#: the share of the free GPU memory an automatic chunk may fill
MEMORY_SHARE = 0.5


def resolve_precision(precision: str, device: torch.device) -> str:
    """The render precision that ``precision`` names on ``device``: ``auto`` is fp16 on CUDA (within
    0.05 dB of fp32 there, ``tests/test_inference.py``) and fp32 elsewhere. InputError (naming
    ``precision``) for an unknown one, or ``fp16`` off CUDA."""
    if precision not in PRECISIONS:
        raise InputError(
            f"precision must be one of {', '.join(PRECISIONS)}, found {precision!r}", param="precision"
        )
    if precision == "auto":
        return "fp16" if device.type == "cuda" else "fp32"
    if precision == "fp16" and device.type != "cuda":
        raise InputError(
            f"precision fp16 needs a CUDA device (this render runs on {device.type}; use fp32 or bf16)",
            param="precision",
        )
    return precision


def render_autocast(device: torch.device, precision: str = "fp32") -> contextlib.AbstractContextManager:
    """The autocast context of ``precision`` (:func:`resolve_precision`) on ``device`` (a no-op for fp32)."""
    precision = resolve_precision(precision, device)
    if precision == "fp32":
        return contextlib.nullcontext()
    return torch.autocast(device.type, dtype=_DTYPES[precision])


def free_device_memory(device: torch.device) -> int | None:
    """Free bytes on a CUDA ``device`` (``torch.cuda.mem_get_info``); None elsewhere."""
    if device.type != "cuda":
        return None
    free, _ = torch.cuda.mem_get_info(device)
    return int(free)


def auto_chunk(model: RadianceModel, free: int | None) -> int:
    """Rays per render call for ``free`` bytes of device memory (None: not a GPU → :data:`CPU_CHUNK`)."""
    if free is None:
        return CPU_CHUNK
    per_ray = ray_bytes(model.kind, model.config, training=False)
    rays = int(MEMORY_SHARE * free / per_ray)
    return max(CPU_CHUNK, min(MAX_CHUNK, rays // CPU_CHUNK * CPU_CHUNK))


def inference_chunk(model: RadianceModel, chunk: int, free: int | None = None) -> int:
    """``chunk`` when > 0; 0 → :func:`auto_chunk` for the model's device (``free``: its free bytes, read
    from the device when None). InputError (naming ``chunk``) when it is not an integer ≥ 0."""
    if isinstance(chunk, bool) or not isinstance(chunk, numbers.Integral) or chunk < 0:
        raise InputError(f"chunk must be an integer ≥ 0 (0 = automatic), found {chunk!r}", param="chunk")
    if chunk > 0:
        return int(chunk)
    return auto_chunk(model, free if free is not None else free_device_memory(model.device))

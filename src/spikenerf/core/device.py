"""``--device auto|cpu|cuda|mps`` resolution."""

from __future__ import annotations

import torch

from spikenerf.core.errors import InputError


def resolve_device(name: str = "auto") -> torch.device:
    """Map ``auto`` to CUDA when present, else CPU; ``cuda`` and ``mps`` (Apple GPUs) only where torch sees
    one. ``auto`` never picks MPS: ask for it (``--device mps``)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(
            "device cuda was asked for, but torch sees no CUDA device (use auto or cpu)", param="device"
        )
    if name == "mps":
        mps = getattr(torch.backends, "mps", None)
        if mps is None or not mps.is_available():
            raise InputError(
                "device mps was asked for, but torch sees no Apple-GPU (MPS) device (use auto or cpu)",
                param="device",
            )
    elif name != "cpu" and not name.startswith("cuda"):
        raise InputError(f"device must be auto, cpu, cuda or mps, got {name!r}", param="device")
    return torch.device(name)

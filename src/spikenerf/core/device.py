"""``--device auto|cpu|cuda[:N]|mps``: the names (no torch import: the CLI's option) and their resolution."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from spikenerf.core.errors import InputError

if TYPE_CHECKING:
    import torch

#: the device names every command takes: ``cuda:N`` is the N-th CUDA device
DEVICE_NAME = re.compile(r"auto|cpu|mps|cuda(:(0|[1-9]\d{0,3}))?")
DEVICE_CHOICES = "auto | cpu | cuda[:N] | mps"


def check_device_name(name: str) -> str:
    """``name`` if it is a device name (:data:`DEVICE_NAME`), else InputError naming ``device``."""
    if not isinstance(name, str) or not DEVICE_NAME.fullmatch(name):
        raise InputError(f"device must be one of {DEVICE_CHOICES}, got {name!r}", param="device")
    return name


def resolve_device(name: str = "auto") -> torch.device:
    """Map ``auto`` to CUDA when present, else CPU; ``cuda[:N]`` and ``mps`` (Apple GPUs) only where torch
    sees one (``cuda:N`` where it sees N + 1). ``auto`` never picks MPS: ask for it (``--device mps``)."""
    import torch

    check_device_name(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(
            f"device {name} was asked for, but torch sees no CUDA device (use auto or cpu)", param="device"
        )
    if name == "mps":
        mps = getattr(torch.backends, "mps", None)
        if mps is None or not mps.is_available():
            raise InputError(
                "device mps was asked for, but torch sees no Apple-GPU (MPS) device (use auto or cpu)",
                param="device",
            )
    index = int(name.partition(":")[2] or -1)  # checked here: torch reads a large index modulo 256
    if name.startswith("cuda") and index >= torch.cuda.device_count():
        raise InputError(
            f"device {name} was asked for, but torch sees {torch.cuda.device_count()} CUDA device(s)",
            param="device",
        )
    return torch.device(name)

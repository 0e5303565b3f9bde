"""Checks of tensor arguments that cost no device sync and keep a ``torch.compile`` graph whole: shapes, types
and Python numbers always, a tensor's values only where reading them is free (:func:`readable`).

Imported by the modules that use torch already (``core``'s others do not import it).
"""

from __future__ import annotations

import math

import torch

from spikenerf.core.errors import InputError, is_number


def readable(x: torch.Tensor) -> bool:
    """Whether a check may read ``x``'s values: on the CPU (no device sync) and not while ``torch.compile``
    traces (a data-dependent branch would break the graph). Elsewhere the values are trusted. Callers look
    it up on this module (``tensor_checks.readable``), so that a test can play a GPU, where it is False."""
    return x.device.type == "cpu" and not torch.compiler.is_compiling()


def check_threshold(threshold: float | torch.Tensor) -> None:
    """InputError naming ``threshold`` unless it is a finite number > 0 (a tensor only where it is
    :func:`readable`: no sync). Pure Python, unlike :func:`spikenerf.camera.streams.check_threshold`
    (numpy): it runs inside the compiled training step, where a numpy call would break the one graph
    (``tests/test_step_graph.py``)."""
    if isinstance(threshold, torch.Tensor):
        if threshold.numel() != 1 or not readable(threshold):
            return
        threshold = float(threshold)
    number = is_number(threshold)
    if not (number and math.isfinite(threshold) and threshold > 0):
        raise InputError(f"threshold φ must be a finite number > 0, found {threshold!r}", param="threshold")


def as_tensor_arg(x: object, name: str, device: torch.device | str | None = None) -> torch.Tensor:
    """``torch.as_tensor(x, device=device)``, or an InputError naming ``name`` where ``x`` is no array of
    numbers (a string, a ragged list, None: torch's own TypeError or ValueError named no parameter)."""
    try:
        return torch.as_tensor(x, device=device)
    except (TypeError, ValueError, RuntimeError) as err:
        found = f"{type(x).__name__} {x!r:.40}"
        raise InputError(
            f"{name} must be an array or tensor of numbers, found {found} ({err})", param=name
        ) from None

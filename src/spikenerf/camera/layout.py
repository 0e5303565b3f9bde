"""The one spike layout convention, and the one place where it turns into channels-last and back.

Across package boundaries a spike stream, and everything indexed like one (TFP/TFI reconstructions, spike
masks, the radiance frames fed to the camera), has the **camera layout**: ``(T, H, W)`` gray or Bayer
(RGGB pattern, see :mod:`spikenerf.camera.bayer`), ``(T, 3, H, W)`` per-channel RGB; one step drops ``T``:
``(H, W)`` or ``(3, H, W)``. The ``.dat`` files hold one ``(T, H, W)`` stream per channel.

Code that works per ray (render/, the training targets in ``data/targets.py``) and images (PNG, the scene
sources) keep colour **channels last**: ``(T, H, W, C)`` or ``(H, W, C)``, with ``C = 1`` for gray, because a
ray gathers the ``C`` values of one pixel. :func:`to_channels_last` and :func:`to_camera_layout` are the only
conversions between the two; both return views (no copy) of numpy arrays or torch tensors.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np

from spikenerf.core.color import is_tensor
from spikenerf.core.errors import InputError

Array = TypeVar("Array")


def _movedim(x: Array, source: int, destination: int) -> Array:
    """``x`` with axis ``source`` moved to ``destination``: a numpy transpose (a view; far cheaper per call
    than ``np.moveaxis``, and the simulator calls this once per step) or torch's ``movedim``."""
    if isinstance(x, np.ndarray):
        axes = list(range(x.ndim))
        axes.insert(destination % x.ndim, axes.pop(source % x.ndim))
        return x.transpose(axes)  # type: ignore[return-value]
    return x.movedim(source, destination)  # type: ignore[attr-defined]


def _check_array(x: object, name: str) -> None:
    """InputError naming ``name`` unless ``x`` is a numpy array or a torch tensor (a string or a list has no
    axes to move: an AttributeError before)."""
    if not (isinstance(x, np.ndarray) or is_tensor(x)):
        raise InputError(
            f"{name} must be a numpy array or a torch tensor, found {type(x).__name__}", param=name
        )


def to_channels_last(x: Array, frame: bool = False, name: str = "spikes") -> Array:
    """Camera layout → channels last, as a view.

    Args:
        x: a stream (T, H, W) or (T, 3, H, W); with ``frame=True`` one step (H, W) or (3, H, W).
        name: the parameter that the InputError on any other shape names.
    Returns:
        (T, H, W, 1) or (T, H, W, 3); one step: (H, W, 1) or (H, W, 3).
    """
    _check_array(x, name)
    ndim, gray = len(x.shape), 2 if frame else 3  # type: ignore[attr-defined]
    if ndim == gray:
        return x[..., None]  # type: ignore[index]
    if ndim == gray + 1 and x.shape[-3] == 3:  # type: ignore[attr-defined]
        return _movedim(x, -3, -1)
    want = "(H, W) or (3, H, W)" if frame else "(T, H, W) or (T, 3, H, W)"
    raise InputError(f"{name} must be {want}, found shape {tuple(x.shape)}", param=name)  # type: ignore[attr-defined]


def to_camera_layout(x: Array, frame: bool = False, name: str = "spikes") -> Array:
    """Channels last → camera layout, as a view; the inverse of :func:`to_channels_last`.

    Args:
        x: a stream (T, H, W, C), C = 1 or 3; with ``frame=True`` one step (H, W, C).
        name: the parameter that the InputError on any other shape names.
    Returns:
        (T, H, W) or (T, 3, H, W); one step: (H, W) or (3, H, W).
    """
    _check_array(x, name)
    shape = tuple(x.shape)  # type: ignore[attr-defined]
    if len(shape) == (3 if frame else 4) and shape[-1] in (1, 3):
        return x[..., 0] if shape[-1] == 1 else _movedim(x, -1, -3)  # type: ignore[index]
    want = "(H, W, C)" if frame else "(T, H, W, C)"
    raise InputError(f"{name} must be {want} with C = 1 or 3, found shape {shape}", param=name)

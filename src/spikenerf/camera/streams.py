"""The spike-stream plumbing every reconstruction shares (TFP, TFI, TFSTP, the masks, the learned
reconstructor): the one check of a stream's shape, the one reading of its values, the array type of a result,
the threshold check, and the first-spikes scan.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from spikenerf.camera.dat_codec import as_numpy
from spikenerf.camera.frame_range import resolve_frames
from spikenerf.core.color import is_tensor
from spikenerf.core.errors import InputError, is_number

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", np.ndarray, "torch.Tensor")
#: a selection of output frames: a slice, one index, None (all), or distinct ascending indices (N,)
Frames = slice | int | np.ndarray | list | tuple | None


def frame_indices(frames: Frames, total: int, param: str = "frames") -> np.ndarray:
    """The frames a selection picks from a ``total``-frame stream, int64 (N,) ascending: a slice, an index
    or None as :func:`~spikenerf.camera.io.resolve_frames` takes them, or a sequence / 1-D integer array of
    distinct indices in ``[0, total)``, ascending. InputError naming ``param`` for anything else (an
    empty, unsorted, repeated or out-of-range index list included)."""
    if frames is None or isinstance(frames, (slice, int, np.integer)):
        return np.asarray(resolve_frames(frames, total, param=param), dtype=np.int64)
    if not isinstance(frames, (np.ndarray, list, tuple)):
        raise InputError(
            f"{param} must be a slice, an int, None or a list of frame indices, found "
            f"{type(frames).__name__}",
            param=param,
        )
    idx = np.asarray(frames)
    if idx.ndim != 1 or idx.size == 0 or idx.dtype.kind not in "iu":
        raise InputError(f"{param}: expected a non-empty 1-D list of integer frame indices", param=param)
    idx = idx.astype(np.int64)
    if idx[0] < 0 or idx[-1] >= total or (idx.size > 1 and not bool(np.all(np.diff(idx) > 0))):
        raise InputError(
            f"{param}: frame indices must be distinct, ascending and within 0..{total - 1}, found "
            f"{idx[:8].tolist()}{' ...' if idx.size > 8 else ''}",
            param=param,
        )
    return idx


def flat_stream(spikes: np.ndarray | torch.Tensor, frames: Frames) -> tuple[np.ndarray, tuple, np.ndarray]:
    """(T, H, W) or (T, 3, H, W) spikes as a (T, P) numpy view, the trailing shape and the output frame
    indices (N,) ascending (:func:`frame_indices`): the one check of a stream's shape for TFP, TFI, TFSTP
    and the masks.

    InputError naming ``spikes`` for any other shape (one frame (H, W), channels last (T, H, W, 3)), and
    ``frames`` for a bad selection. Values are checked where they are read (:func:`spike_bytes`: a float
    stream must hold only 0.0 and 1.0; bool and integers are not checked, any non-zero is a spike).
    """
    x = as_numpy(spikes)
    if not (x.ndim == 3 or (x.ndim == 4 and x.shape[1] == 3)):
        hint = ""
        if x.ndim == 2:
            hint = " (one frame? add a time axis: spikes[None])"
        elif x.ndim == 4 and x.shape[-1] in (1, 3):
            hint = " (channels last? camera.layout.to_camera_layout converts it)"
        raise InputError(
            f"spikes must be (T, H, W) or (T, 3, H, W), found shape {x.shape}{hint}", param="spikes"
        )
    out_idx = frame_indices(frames, x.shape[0])
    return x.reshape(x.shape[0], int(np.prod(x.shape[1:]))), x.shape[1:], out_idx


def spike_bytes(x: np.ndarray) -> np.ndarray:
    """Spikes (...) of any shape as 0/1 uint8 (...) for counting (the one reading of a spike array's values,
    for TFP, TFI, the masks and the learned reconstructor): bool is viewed, other dtypes become
    ``x != 0``; InputError naming ``spikes`` when a float (or complex) array holds a value other than 0
    and 1 (intensities are not spikes). The check costs one comparison more, on float input only (bool
    and integers pass unchecked)."""
    if x.dtype == np.bool_:
        return x.view(np.uint8)
    fired = x != 0
    if x.dtype.kind in "fc" and not np.equal(fired, x).all():
        bad = x[np.not_equal(fired, x)].flat[0].item()
        raise InputError(
            f"spikes must be 0/1 (bool, integers, or floats 0.0 and 1.0), found the float value {bad!r} "
            "(intensities? simulate spikes with camera.simulation.simulate)",
            param="spikes",
        )
    return fired.view(np.uint8)


def row_uint8(row: np.ndarray) -> np.ndarray:
    """One frame's spikes (P,) as 0/1 uint8 (P,), unchecked (the scans' fast path; :func:`spike_bytes`
    checks values)."""
    return (row if row.dtype == np.bool_ else row != 0).view(np.uint8)


def like(result: np.ndarray, spikes: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """``result`` (any shape (...)) as the array type of ``spikes``: a torch tensor on its device, or numpy
    unchanged."""
    if is_tensor(spikes):
        return sys.modules["torch"].from_numpy(result).to(spikes.device)
    return result


def first_two(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the first and second spike index (int32 (P,), T = none), by a backward scan.

    Scans keep ``T − index`` (0 = none) and update with ``max(state, row · value)``: two cheap ufuncs per
    frame, an order of magnitude faster than ``np.copyto(where=)``.
    """
    total = flat.shape[0]
    first_r = np.zeros(flat.shape[1], np.int32)
    second_r = first_r.copy()
    tmp = np.empty_like(first_r)
    for i in range(total - 1, -1, -1):
        row = spike_bytes(flat[i])  # (checks a float stream's values: the one scan that reads every row)
        np.maximum(second_r, np.multiply(row, first_r, out=tmp), out=second_r)
        np.maximum(first_r, np.multiply(row, np.int32(total - i), out=tmp), out=first_r)
    return total - first_r, total - second_r


def check_threshold(threshold: float) -> None:
    """InputError (naming ``threshold``) unless φ is a number > 0 that float32 holds (the images are float32:
    a φ past its range would give inf, one below it 0); a string, None or an array is refused too."""
    try:  # a number (numpy's scalars are numbers.Real; a list or an array is not)
        with np.errstate(over="ignore", under="ignore"):
            held = is_number(threshold)
            held = held and bool(np.isfinite(threshold) and 0 < np.float32(threshold) < np.inf)
    except (TypeError, ValueError):  # "1", None
        held = False
    if not held:
        shown = threshold if isinstance(threshold, (int, float)) else repr(threshold)
        raise InputError(
            f"threshold φ must be a positive number within float32's range, found {shown}",
            param="threshold",
        )

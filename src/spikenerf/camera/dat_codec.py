"""The SpikeCV ``.dat`` frame layout: a stored frame's bytes ↔ a (H, W) frame of 0/1 spikes, and the checks of
what is encoded (:mod:`spikenerf.camera.io` reads and writes the files).

Layout (SpikeCV, the ecosystem standard): no header; frames concatenated, ``H·W/8`` bytes each; pixel ``p`` of
the row-major *stored* frame is bit ``p % 8`` (LSB first) of byte ``p // 8``; rows are stored bottom-up, so a
reader flips them vertically. ``layout="topdown"`` (the Spike-NeRF paper code) stores rows top-down and is
only used when asked for. Raw sps10 camera files store 416 columns per row, of which the trailing 16
(columns 400–415) are not pixels; ``raw_width=416`` strips them (SpikeCV's ``with_head`` option).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from spikenerf.camera.modes import LAYOUTS
from spikenerf.core.color import is_tensor
from spikenerf.core.errors import InputError, is_integer

if TYPE_CHECKING:
    import torch

#: the non-pixel columns at the end of each stored row of a raw sps10 recording (416 for a 400-pixel row)
RAW_PADDING = 16


def as_numpy(x: Any) -> np.ndarray:
    """A numpy array (a torch tensor is detached and moved to the CPU; no copy when already there)."""
    return x.detach().cpu().numpy() if is_tensor(x) else np.asarray(x)


def frame_bytes(height: int, width: int, raw_width: int | None = None, path: str | Path | None = None) -> int:
    """Bytes per stored frame, ``H·W_stored/8``; InputError when the sizes are bad or H·W % 8 != 0."""
    whole = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (height, width))
    if not whole or height <= 0 or width <= 0:
        raise InputError(
            f"height and width must be positive integers, found {height!r}×{width!r}",
            path=path,
            param=("height", "width"),
        )
    stored = stored_width(width, raw_width, path)
    if (height * stored) % 8:
        raise InputError(
            f"H·W must be a multiple of 8 for a .dat file, found {height}×{stored} = {height * stored} "
            f"(remainder {(height * stored) % 8})",
            path=path,
        )
    return height * stored // 8


def decode_frames(
    raw: np.ndarray, height: int, width: int, layout: str = "spikecv", raw_width: int | None = None
) -> np.ndarray:
    """Unpack stored frames (T, H·W_stored/8) uint8 into uint8 (T, H, W) 0/1 spikes (see module doc)."""
    check_layout(layout)
    stored = width if raw_width is None else raw_width
    n = raw.shape[0]
    if stored % 8 == 0:
        # Flip the packed rows (1/8 of the data), then unpack: flat when nothing is stripped (the fast path).
        rows = raw.reshape(n, height, stored // 8)
        if layout == "spikecv":
            rows = np.ascontiguousarray(rows[:, ::-1])
        if stored == width:
            return np.unpackbits(rows.reshape(-1), bitorder="little").reshape(n, height, width)
        return np.unpackbits(rows, axis=-1, count=width, bitorder="little")
    bits = np.unpackbits(raw, axis=-1, bitorder="little").reshape(n, height, stored)[:, :, :width]
    return np.ascontiguousarray(bits[:, ::-1] if layout == "spikecv" else bits)


def encode_frames(spikes: np.ndarray, layout: str = "spikecv") -> np.ndarray:
    """Pack uint8/bool (T, H, W) 0/1 spikes into stored frames uint8 (T, H·W/8) (see module doc)."""
    check_layout(layout)
    n, height, width = spikes.shape
    if layout == "spikecv" and width % 8 == 0:
        # Pack flat (the fast path), then flip the packed rows (1/8 of the data).
        packed = np.packbits(spikes.reshape(-1), bitorder="little").reshape(n, height, width // 8)
        return np.ascontiguousarray(packed[:, ::-1]).reshape(n, -1)
    frames = spikes[:, ::-1] if layout == "spikecv" else spikes
    return np.packbits(frames.reshape(n, -1), axis=-1, bitorder="little")


def as_binary(chunk: np.ndarray | torch.Tensor, path: str | Path) -> np.ndarray:
    """A (T, H, W) chunk as a numpy bool/uint8 array; InputError on other shapes or non-0/1 values."""
    arr = as_numpy(chunk)
    if arr.ndim != 3:
        hint = " (use write_dat_rgb for (T, 3, H, W) streams)" if arr.ndim == 4 else ""
        raise InputError(f"spikes must be (T, H, W), found shape {arr.shape}{hint}", path=path)
    if arr.dtype == np.bool_ or arr.size == 0:
        return arr
    if arr.dtype == np.uint8 and arr.max() <= 1:  # the common case, checked in one cheap pass
        return arr
    bad = (arr != 0) & (arr != 1)
    if bad.any():
        first = arr[np.unravel_index(np.argmax(bad), arr.shape)].item()  # 255, not np.uint8(255) (numpy 2)
        raise InputError(
            f"spikes must be binary (0/1 or bool), found {int(bad.sum())} other values (e.g. {first!r})",
            path=path,
        )
    return arr.astype(np.uint8, copy=False)


def stored_width(width: int, raw_width: int | None, path: str | Path | None = None) -> int:
    """The stored row width: ``raw_width`` (an integer ≥ ``width``, else an InputError), or ``width``."""
    if raw_width is None:
        return width
    if not is_integer(raw_width):
        raise InputError(
            f"raw_width must be an integer (the stored row width) or None, found {raw_width!r}",
            path=path,
            param="raw_width",
        )
    if raw_width < width:
        raise InputError(
            f"raw_width {raw_width} is smaller than the image width {width}", path=path, param="raw_width"
        )
    return raw_width


def check_layout(layout: str, path: str | Path | None = None) -> None:
    """An InputError naming ``layout`` unless it is one of ``LAYOUTS`` (``camera/modes.py``)."""
    if layout not in LAYOUTS:
        raise InputError(
            f"layout must be one of {', '.join(LAYOUTS)}, found {layout!r}", path=path, param="layout"
        )

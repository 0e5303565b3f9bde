"""SpikeCV ``.dat`` spike files: memory-mapped reading, atomic writing, frame counting, chunked streaming, the
three files of an RGB stream, and the tell-tale silent columns of a raw sps10 recording. The frame layout (a
stored frame's bytes ↔ a frame of spikes) is :mod:`spikenerf.camera.dat_codec`; a frame selection's indices,
:mod:`spikenerf.camera.frame_range`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from spikenerf.camera.dat_codec import (
    RAW_PADDING,
    as_binary,
    as_numpy,
    check_layout,
    decode_frames,
    encode_frames,
    frame_bytes,
    stored_width,
)
from spikenerf.camera.frame_range import resolve_frames
from spikenerf.core.atomic import atomic_path
from spikenerf.core.color import is_tensor
from spikenerf.core.errors import InputError, as_path

if TYPE_CHECKING:
    import torch

#: the suffixes of the three per-channel files of an RGB stream: ``{prefix}_r.dat`` etc.
RGB_SUFFIXES = ("r", "g", "b")
#: frames decoded or encoded per block when streaming (bounds memory, keeps numpy calls large)
CHUNK_FRAMES = 256


def count_frames(path: str | Path, height: int, width: int, raw_width: int | None = None) -> int:
    """The number of frames in a ``.dat`` file; InputError if the size is not a whole number of frames."""
    path = _existing_file(path)
    fb = frame_bytes(height, width, raw_width, path)
    size = path.stat().st_size
    if size % fb:
        raw = width + RAW_PADDING
        explained = raw_width is None and _silent_padding(path, height, width, raw)
        hint = f" — a raw sps10 file? pass raw_width {raw}" if explained else ""
        if not hint and size // fb:  # a capture cut short keeps its whole frames
            hint = f"; to read the whole frames of a capture cut short: truncate -s {size // fb * fb} a copy"
        stored, whole = stored_width(width, raw_width, path), size // fb
        raise InputError(
            f"file size {size} bytes is not a multiple of the frame size {fb} bytes ({stored} pixels "
            f"wide, {height} high, / 8): {whole} whole frame{'' if whole == 1 else 's'} and a remainder of "
            f"{size % fb} bytes (wrong height/width, or a truncated file?){hint}",
            path=path,
            param=("height", "width", "raw_width") if explained else ("height", "width"),
        )
    return size // fb


def _silent_padding(path: Path, height: int, width: int, raw: int, frames: int = 64) -> bool:
    """Whether the file is whole frames of ``height × raw`` columns whose last ``raw − width`` stay silent
    over its first ``frames`` frames while the others fire: what a raw sps10 recording looks like (a size
    that merely divides is no evidence)."""
    row_bytes = height * raw
    size = path.stat().st_size
    if row_bytes % 8 or size % (row_bytes // 8):
        return False
    head = read_dat(path, height, raw, slice(0, min(frames, size // (row_bytes // 8))))
    return bool(head[:, :, :width].any() and not head[:, :, width:].any())


def raw_width_guess(path: str | Path, height: int, width: int, frames: int = 64) -> int | None:
    """``width + RAW_PADDING`` when the file, read as such raw rows, is whole raw frames whose extra columns
    stay silent over its first ``frames`` frames while its pixels fire: a raw sps10 recording whose size
    also fits plain ``width``-column frames (every 25th frame count at 250×400). None otherwise.

    Only a file that is whole frames both ways is examined (one that is not gets :func:`count_frames`'s
    hint); a plain stream that is dark exactly where the padding would lie is guessed raw, so callers ask
    the user to say which rather than pick."""
    sizes = (height, width)
    whole = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0 for v in sizes)
    raw = width + RAW_PADDING if whole else 0
    if not whole or (height * raw) % 8 or (height * width) % 8:
        return None  # (bad sizes: count_frames names them)
    path = _existing_file(path)
    size = path.stat().st_size
    if not size or size % (height * width // 8):
        return None
    return raw if _silent_padding(path, height, width, raw, frames) else None


def stripped_columns_fire(
    path: str | Path, height: int, width: int, raw_width: int, frames: int = 64
) -> bool:
    """Whether the ``raw_width − width`` columns that ``raw_width`` strips from each row fire in the file's
    first ``frames`` frames. A raw sps10 recording's padding columns stay silent, so columns that fire say
    that the file is not one (or ``raw_width`` is wrong). False where the file is not whole raw frames
    (:func:`count_frames` names that)."""
    try:
        total = count_frames(path, height, width, raw_width)
    except InputError:
        return False
    if not total:
        return False
    head = read_dat(path, height, raw_width, slice(0, min(frames, total)))
    return bool(head[:, :, width:].any())


def read_dat(
    path: str | Path,
    height: int,
    width: int,
    frames: slice | int | None = None,
    layout: str = "spikecv",
    raw_width: int | None = None,
) -> np.ndarray:
    """Read (a range of) a ``.dat`` spike file through a memory map: only the selected frames are read.

    Args:
        path: the ``.dat`` file.
        height, width: the frame size in pixels (``width`` after stripping, see ``raw_width``).
        frames: a slice (or one index) of frames; ``None`` reads all. Out-of-range → InputError.
        layout: ``"spikecv"`` (rows stored bottom-up) or ``"topdown"``.
        raw_width: the stored row width when it exceeds ``width`` (416 for raw 250×400 sps10 files); the
            trailing ``raw_width - width`` columns of each stored row are dropped.
    Returns:
        uint8 (T, H, W) of 0/1, C-contiguous, row 0 at the top of the image.
    """
    path = _existing_file(path)
    check_layout(layout, path)
    total = count_frames(path, height, width, raw_width)
    selected = resolve_frames(frames, total, path)
    stored = stored_width(width, raw_width, path)
    if total == 0:
        return np.zeros((0, height, width), np.uint8)
    fb = frame_bytes(height, width, raw_width, path)
    mm = np.memmap(
        path, np.uint8, "r", offset=selected.start * fb, shape=(selected.stop - selected.start, fb)
    )
    try:
        out = decode_frames(mm[:: selected.step], height, width, layout, stored)
    finally:
        del mm
    return out


def iter_dat(
    path: str | Path,
    height: int,
    width: int,
    chunk_frames: int = CHUNK_FRAMES,
    frames: slice | None = None,
    layout: str = "spikecv",
    raw_width: int | None = None,
) -> Iterator[tuple[int, np.ndarray]]:
    """Stream a ``.dat`` file in chunks of at most ``chunk_frames`` frames (contiguous selections only).

    Yields:
        ``(first_index, spikes)`` with spikes uint8 (n, H, W), as :func:`read_dat` would return them.
    """
    path = _existing_file(path)
    if chunk_frames <= 0:
        raise InputError(
            f"chunk_frames must be positive, found {chunk_frames}", path=path, param="chunk_frames"
        )
    selected = resolve_frames(frames, count_frames(path, height, width, raw_width), path)
    if selected.step != 1:
        raise InputError(
            f"frames: iter_dat streams contiguous ranges only, found step {selected.step}",
            path=path,
            param="frames",
        )
    for start in range(selected.start, selected.stop, chunk_frames):
        stop = min(start + chunk_frames, selected.stop)
        yield start, read_dat(path, height, width, slice(start, stop), layout, raw_width)


def write_dat(
    path: str | Path,
    spikes: np.ndarray | torch.Tensor | Iterable[np.ndarray | torch.Tensor],
    layout: str = "spikecv",
) -> int:
    """Write spikes to a ``.dat`` file atomically (nothing is left behind on error).

    Args:
        path: the output file.
        spikes: bool or 0/1-valued (T, H, W) array or tensor, or an iterable of such chunks of equal H, W
            (streamed: the whole stream never needs to be in memory).
        layout: ``"spikecv"`` (default) or ``"topdown"``.
    Returns:
        The number of frames written.
    """
    path = as_path(path, "path")  # (None was a TypeError deep in pathlib)
    check_layout(layout, path)
    chunks = [spikes] if isinstance(spikes, np.ndarray) or is_tensor(spikes) else spikes
    written, shape = 0, None
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        for chunk in chunks:
            arr = as_binary(chunk, path)
            if shape is None:
                shape = arr.shape[1:]
                frame_bytes(*shape, path=path)
            elif arr.shape[1:] != shape:
                raise InputError(
                    f"chunk frame size {arr.shape[1:]} differs from the first chunk's {shape}", path
                )
            for start in range(0, arr.shape[0], CHUNK_FRAMES):
                fh.write(encode_frames(arr[start : start + CHUNK_FRAMES], layout).data)
            written += arr.shape[0]
    return written


def rgb_paths(prefix: str | Path) -> list[Path]:
    """The three per-channel files of an RGB stream: ``{prefix}_r.dat``, ``_g.dat``, ``_b.dat``. A trailing
    ``.dat`` of ``prefix`` is dropped (``rgb.dat`` → ``rgb_r.dat``, not ``rgb.dat_r.dat``)."""
    prefix = Path(prefix)
    stem = prefix.name[: -len(".dat")] if prefix.name.lower().endswith(".dat") else prefix.name
    if not stem:
        raise InputError(
            "prefix: expected a file name before '.dat', found none", path=prefix, param="prefix"
        )
    return [prefix.with_name(f"{stem}_{c}.dat") for c in RGB_SUFFIXES]


def write_dat_rgb(
    prefix: str | Path, spikes: np.ndarray | torch.Tensor, layout: str = "spikecv"
) -> list[Path]:
    """Write a per-channel RGB stream (T, 3, H, W) as three gray ``.dat`` files; returns their paths
    (:func:`rgb_paths`: ``{prefix}_r.dat`` …; a trailing ``.dat`` of ``prefix`` is dropped). ``spikes`` is
    bool or 0/1 (T, 3, H, W): an array, a tensor or an array-like such as a list of (3, H, W) steps. The
    stream is checked whole first and the three files are written before any replaces an old one, so an
    error in the data or while writing leaves the old files as they were (a kill between the three quick
    renames can still mix old and new channels; :func:`read_dat_rgb` refuses unequal frame counts)."""
    try:
        arr = as_numpy(spikes)
    except (TypeError, ValueError) as err:  # a ragged list, a list of unequal steps, ...
        raise InputError(
            f"spikes: expected a (T, 3, H, W) array, found {type(spikes).__name__} ({err})",
            path=prefix,
            param="spikes",
        ) from None
    if arr.ndim != 4 or arr.shape[1] != 3:
        raise InputError(
            f"spikes: RGB spikes must be (T, 3, H, W), found shape {tuple(arr.shape)}",
            path=prefix,
            param="spikes",
        )
    check_layout(layout, prefix)
    arr = as_binary(arr.reshape(-1, *arr.shape[2:]), prefix).reshape(arr.shape)  # checked whole, first
    frame_bytes(*arr.shape[2:], path=prefix)
    paths = rgb_paths(prefix)
    with contextlib.ExitStack() as stack:
        temps = [stack.enter_context(atomic_path(p)) for p in paths]
        for c, tmp in enumerate(temps):
            write_dat(tmp, arr[:, c], layout)
    return paths


def read_dat_rgb(
    prefix: str | Path,
    height: int,
    width: int,
    frames: slice | int | None = None,
    layout: str = "spikecv",
    raw_width: int | None = None,
) -> np.ndarray:
    """Read the three files written by :func:`write_dat_rgb` into uint8 (T, 3, H, W)."""
    paths = rgb_paths(prefix)
    counts = [count_frames(p, height, width, raw_width) for p in paths]
    if len(set(counts)) != 1:
        raise InputError(f"the r, g, b files hold different frame counts {counts}", path=prefix)
    return np.stack([read_dat(p, height, width, frames, layout, raw_width) for p in paths], axis=1)


def _existing_file(path: str | Path) -> Path:
    path = Path(path)
    if not path.exists():
        raise InputError("spike file not found", path=path)
    if not path.is_file():
        raise InputError("expected a .dat file, found a directory or special file", path=path)
    return path

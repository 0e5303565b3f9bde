"""Image reconstruction from spike streams: TFP (texture from playback) and TFI (texture from interval); TFSTP
(short-term plasticity) is in :mod:`spikenerf.camera.tfstp` and dispatched here.

Both work on gray or Bayer streams (T, H, W) and per-channel streams (T, 3, H, W) (the camera layout; any
other shape, such as one frame (H, W) or channels last (T, H, W, 3), is an InputError), given as numpy
arrays or torch tensors of 0/1 spikes (bool, integers: any non-zero is a spike; floats: only 0.0 and 1.0),
and return linear intensity in simulator units (φ = threshold; 1.0 = white when φ = 1). Every frame is
computed by scans over time that are vectorised over all pixels (a running window count for TFP and masks;
previous/next-spike scans for TFI), reading only the frames needed and keeping memory at O(output).
Formulas and edge rules: docs/reconstruction.md.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Literal, get_args

import numpy as np

from spikenerf.camera.streams import (
    Array,
    Frames,
    check_threshold,
    first_two,
    flat_stream,
    frame_indices,
    like,
    row_uint8,
    spike_bytes,
)
from spikenerf.camera.tfstp import tfstp
from spikenerf.core.errors import InputError, check_choice, is_integer

#: image reconstructions from spikes
ReconMethod = Literal["tfp", "tfi", "tfstp"]
METHODS: tuple[str, ...] = get_args(ReconMethod)
#: the reconstructions without a window, which read out to the neighbouring spikes (TFSTP: from frame 0)
#: and compute a range of frames in one call
WINDOWLESS: tuple[str, ...] = ("tfi", "tfstp")


def window_sum(spikes: np.ndarray, half: int, frames: Frames = None) -> tuple[np.ndarray, np.ndarray]:
    """Spike counts over the window ``[k-half, k+half]`` clipped to the stream, for each selected frame k.

    Args:
        spikes: (T, H, W) or (T, 3, H, W) 0/1 spikes (see :func:`flat_stream`).
        half: the half window h ≥ 0 (window length 2h+1 before clipping).
        frames: which output frames (slice, index or None = all).
    Returns:
        counts: int32 (N, ...) spikes in each clipped window; used: int32 (N,) frames in each window.
    """
    flat, rest, out_idx = flat_stream(spikes, frames)
    counts = np.empty((out_idx.size, flat.shape[1]), np.int32)
    used = np.empty(out_idx.size, np.int32)
    for j, acc, n in iter_window_counts(flat, half, out_idx):
        counts[j], used[j] = acc, n
    return counts.reshape(out_idx.size, *rest), used


def iter_window_counts(
    flat: np.ndarray, half: int, out_idx: np.ndarray
) -> Iterator[tuple[int, np.ndarray, int]]:
    """Yield ``(j, counts (P,), frames used)`` for each output frame ``out_idx[j]`` (ascending); counts are
    uint8/uint16/int32, the narrowest type that holds ``2·half + 1``, and the buffer is reused.

    A running sum over frames: each step adds the frame entering the window and subtracts the one leaving
    it (one vectorised op per frame over all pixels; far faster than ``np.cumsum(axis=0)``, whose inner loop
    strides across rows). Only the frames the windows touch are read.
    """
    total = flat.shape[0]
    if out_idx.size == 0:
        return
    lo_all, hi_all = np.maximum(out_idx - half, 0), np.minimum(out_idx + half + 1, total)
    base = int(lo_all[0])
    src = spike_bytes(flat[base : int(hi_all[-1])])
    # the narrowest counter that holds 2h+1 (less memory traffic per frame)
    acc = np.zeros(flat.shape[1], np.min_scalar_type(2 * half + 1) if half < 32767 else np.int32)
    cur_lo = cur_hi = base
    for j, (lo, hi) in enumerate(zip(lo_all.tolist(), hi_all.tolist(), strict=True)):
        if lo >= cur_hi or (hi - cur_hi) + (lo - cur_lo) > hi - lo:  # no overlap: restart the sum
            np.sum(src[lo - base : hi - base], axis=0, dtype=acc.dtype, out=acc)
        else:
            for r in range(cur_hi, hi):
                np.add(acc, src[r - base], out=acc)
            for r in range(cur_lo, lo):
                np.subtract(acc, src[r - base], out=acc)
        cur_lo, cur_hi = lo, hi
        yield j, acc, hi - lo


#: the TFP window in frames (odd) that every default in spikenerf uses: targets, previews, videos, figures
DEFAULT_WINDOW = 41


def fitting_window(steps: int, window: int = DEFAULT_WINDOW) -> int:
    """The largest odd TFP window of at most ``window`` frames that a ``steps``-step stream holds."""
    return min(window, steps if steps % 2 else steps - 1)


def tfp(spikes: Array, window: int = DEFAULT_WINDOW, threshold: float = 1.0, frames: Frames = None) -> Array:
    """Texture from playback: ``Î_k = φ · (spikes in the window around k) / (frames in the window)``.

    The window is ``K = 2h+1`` frames centred on k, clipped to the stream; the count is divided by the
    number of frames actually used, so edge frames are unbiased (just noisier).

    Args:
        spikes: (T, H, W) or (T, 3, H, W) 0/1 spikes (numpy or torch; bool, integer, or float 0.0/1.0).
        window: K, the full window length in frames; odd and ≥ 1.
        threshold: φ, the camera threshold (intensity units per spike), a number > 0.
        frames: the output frames (slice, index, None = all, or ascending indices (N,)).
    Returns:
        float32 (N, ...) linear intensity in [0, φ], the same array type as ``spikes``.
    """
    check_window(window)
    check_threshold(threshold)
    flat, rest, out_idx = flat_stream(spikes, frames)
    out = np.empty((out_idx.size, flat.shape[1]), np.float32)
    for j, acc, used in iter_window_counts(flat, (window - 1) // 2, out_idx):
        np.multiply(acc, np.float32(threshold / used), out=out[j], casting="unsafe")
    return like(out.reshape(out_idx.size, *rest), spikes)


def tfi(spikes: Array, threshold: float = 1.0, frames: Frames = None) -> Array:
    """Texture from interval: ``Î_k = φ / Δ_k``, Δ_k the inter-spike interval that contains step k.

    With ``p`` the last spike strictly before k and ``n`` the first spike at or after k, ``Δ_k = n − p``:
    the light of step k is part of the φ integrated over steps p+1..n. Edges of the stream:
    before the first spike f, ``Δ = max(f + 1, first complete interval)``; after the last spike l,
    ``Δ = max(T − l, last complete interval)`` (the edge-bounded interval is a lower bound on the true one;
    the nearest complete interval is the locally-constant estimate); a pixel with no spike at all gives 0.

    Args:
        spikes: (T, H, W) or (T, 3, H, W) 0/1 spikes (numpy or torch; bool, integer, or float 0.0/1.0).
        threshold: φ, a number > 0.
        frames: the output frames (slice, index, None = all, or ascending indices (N,)).
    Returns:
        float32 (N, ...) linear intensity in [0, φ], the same array type as ``spikes``.
    """
    check_threshold(threshold)
    flat, rest, out_idx = flat_stream(spikes, frames)
    total = flat.shape[0]
    # Edge rules as virtual spikes: a virtual previous spike first − start_gap and a virtual next spike
    # last + end_gap make every interval a plain n − p (no masking in the per-frame arithmetic).
    first, second = first_two(flat)
    start_extra = np.where(second < total, np.maximum(second - 2 * first - 1, 0), 0).astype(np.int32)
    prev1, last, penult = _scan_prev(flat, out_idx, -start_extra)
    end_extra = np.where(penult >= 0, np.maximum(2 * last - penult - total, 0), 0).astype(np.int32)
    # pixels that never fire get a zero numerator; the output overwrites prev1 in place (one (N, P) array)
    numerator = np.where(first < total, np.float32(threshold), np.float32(0)).astype(np.float32)
    out = _scan_next_divide(flat, out_idx, -end_extra, prev1, numerator)
    return like(out.reshape(out_idx.size, *rest), spikes)


def _scan_prev(
    flat: np.ndarray, out_idx: np.ndarray, virtual: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Forward scan. Returns ``prev + 1`` for each output frame, int32 (N, P), where prev is the last spike
    strictly before it (``virtual`` ≤ 0 before the first spike), and per pixel the last and second-to-last
    spikes of the stream ((P,), -1 = none).

    States are stored offset by ``C = T + 1`` so a virtual value stays positive (above the 0 that a silent
    row contributes to the max) yet below every real one.
    """
    offset = np.int32(flat.shape[0] + 1)
    prev1 = np.empty((out_idx.size, flat.shape[1]), np.int32)
    last1 = (virtual + offset).astype(np.int32)
    penult1 = np.zeros_like(last1)
    tmp = np.empty_like(last1)
    wanted = dict(zip(out_idx.tolist(), range(out_idx.size), strict=True))
    for i in range(flat.shape[0]):
        if i in wanted:
            np.subtract(last1, offset, out=prev1[wanted[i]])
        row = row_uint8(flat[i])
        np.maximum(penult1, np.multiply(row, last1, out=tmp), out=penult1)
        np.maximum(last1, np.multiply(row, np.int32(i + 1) + offset, out=tmp), out=last1)
    last, penult = last1 - offset - 1, penult1 - offset - 1
    return prev1, np.maximum(last, -1), np.maximum(penult, -1)


def _scan_next_divide(
    flat: np.ndarray, out_idx: np.ndarray, virtual: np.ndarray, prev1: np.ndarray, numerator: np.ndarray
) -> np.ndarray:
    """Backward scan for next, the first spike at or after each output frame (``virtual`` ≤ 0 after the last
    spike; states offset as in :func:`_scan_prev`), finishing each output row as it is reached:
    ``Î = numerator / (next − prev)`` written over ``prev1`` (int32 (N, P)), returned as float32 (N, P)."""
    total = flat.shape[0]
    offset = np.int32(total + 1)
    out = prev1.view(np.float32)
    first_r = (virtual + offset).astype(np.int32)  # (T − next) + C
    tmp, delta = np.empty_like(first_r), np.empty_like(first_r)
    wanted = dict(zip(out_idx.tolist(), range(out_idx.size), strict=True))
    for i in range(total - 1, -1, -1):
        row = row_uint8(flat[i])
        np.maximum(first_r, np.multiply(row, np.int32(total - i) + offset, out=tmp), out=first_r)
        if i in wanted:
            j = wanted[i]
            # Δ = next − prev = (T − (first_r − C)) − (prev1 − 1) = 2T + 2 − first_r − prev1
            np.add(first_r, prev1[j], out=delta)
            np.subtract(np.int32(2 * total + 2), delta, out=delta)
            np.divide(numerator, delta, out=out[j], casting="unsafe")
    return out


def reconstruct_frames(
    read: Callable[[int, int], np.ndarray],
    total: int,
    start: int,
    stop: int,
    method: str = "tfp",
    window: int = DEFAULT_WINDOW,
    threshold: float = 1.0,
    step: int = 1,
) -> np.ndarray:
    """Reconstruct frames ``start:stop:step`` of a long stream, reading only the frames the result depends on.

    The result equals ``tfp/tfi/tfstp(whole_stream)[start:stop:step]`` exactly; only those frames are
    computed and held (TFI still reads every frame of the range, a byte a pixel each). TFP reads the window
    margin ``(window-1)/2`` on each side. TFI doubles a margin until every pixel has two spikes on each side
    of the range or the margin reaches the stream edge (a pixel that never fires makes TFI read the whole
    stream). TFSTP reads from frame 0 (its state is the whole history) to the end margin TFI would read.

    Args:
        read: ``read(a, b)`` returns frames ``a:b`` of the stream, (b-a, ...) 0/1.
        total: T, the frames in the stream.
        start, stop: the output frames, ``0 <= start < stop <= total``; step: keep every ``step``-th of
            them (an integer ≥ 1).
        method: ``tfp``, ``tfi`` or ``tfstp``. window: TFP window, odd (TFI, TFSTP have none).
            threshold: φ (intensity = rate · φ).
    Returns:
        float32 (len(range(start, stop, step)), ...) linear intensity.
    """
    check_choice(method, METHODS, "method")
    whole = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (total, start, stop))
    if not whole or not 0 <= start < stop <= total:
        raise InputError(
            f"start, stop: need integers 0 <= start < stop <= total = {total}, found {start}, {stop}",
            param=("start", "stop"),
        )
    if not (isinstance(step, (int, np.integer)) and not isinstance(step, bool) and step >= 1):
        raise InputError(f"step must be an integer ≥ 1, found {step!r}", param="step")
    if method == "tfp":
        check_window(window)
    return _span(read, total, [np.arange(start, stop, step, dtype=np.int64)], method, window, threshold)[1]


#: TFI's first reading margin on each side of a range (doubled until the edge rules cannot reach it)
TFI_MARGIN = 64
#: the most frames one TFP or TFI call of :func:`reconstruct_at` spans (its read adds the margins): frames
#: asked for all along a long stream are read a piece at a time, not the whole stream at once
RUN_SPAN = 1024


def reconstruct_at(
    read: Callable[[int, int], np.ndarray],
    total: int,
    frames: Frames,
    method: str = "tfp",
    window: int = DEFAULT_WINDOW,
    threshold: float = 1.0,
) -> np.ndarray:
    """Reconstruct the frames ``frames`` (N,) of a long stream (distinct ascending indices, or a slice or
    an index) in as few reads and scans as the method allows, holding only those N output frames.

    The result equals ``reconstruct_frames(read, total, k, k + 1)`` stacked over each k exactly (and so the
    whole stream's reconstruction at ``frames``). TFSTP makes one call (its forward scan starts at frame 0
    whatever frames are asked for, so N frames cost what the last of them alone costs). TFP and TFI make
    one call per run of frames at most their reach apart (TFP: its window; TFI: twice its first margin,
    128 frames) and spanning fewer than :data:`RUN_SPAN` frames, each reading that run's span as
    :func:`reconstruct_frames` reads it: the frames between two far-apart ones are not read, and however
    many frames are asked for, one read holds at most ``RUN_SPAN`` frames and the margins (where TFI's
    margins reach both ends of the stream, a pixel that never fires, that one read of the whole stream makes
    every frame).

    Args:
        read, total, method, window, threshold: as :func:`reconstruct_frames`.
        frames: the output frames of the ``total``-frame stream (InputError naming ``frames`` for an empty,
            unsorted, repeated or out-of-range list).
    Returns:
        float32 (N, ...) linear intensity.
    """
    check_choice(method, METHODS, "method")
    if not is_integer(total) or total < 1:
        raise InputError(f"total must be an integer ≥ 1, found {total!r}", param="total")
    if method == "tfp":
        check_window(window)
    idx = frame_indices(frames, int(total))
    reach = {"tfp": window, "tfi": 2 * TFI_MARGIN}.get(method)
    runs = [idx] if reach is None else _runs(idx, reach)
    parts: list[np.ndarray] = []
    while runs:
        done, part = _span(read, int(total), runs, method, window, threshold)
        parts.append(part)
        runs = runs[done:]
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _runs(idx: np.ndarray, reach: int) -> list[np.ndarray]:
    """``idx`` (N,) (ascending) cut where two neighbours lie more than ``reach`` apart, and each piece cut
    again into runs that span fewer than :data:`RUN_SPAN` frames."""
    runs = []
    for near in np.split(idx, np.flatnonzero(np.diff(idx) > reach) + 1):
        runs += np.split(near, np.flatnonzero(np.diff((near - near[0]) // RUN_SPAN)) + 1)
    return runs


def _span(
    read: Callable[[int, int], np.ndarray],
    total: int,
    runs: list[np.ndarray],
    method: str,
    window: int,
    threshold: float,
) -> tuple[int, np.ndarray]:
    """The frames of ``runs[0]`` (N,) (ascending, checked) in one read of the span they and their reach
    need: TFP's window margins; TFI's margins doubled until the edge rules cannot reach them; TFSTP from
    frame 0 to TFI's end margin. Where that read is the whole stream (TFI with a pixel that never fires),
    the frames of every run, from the one read. Returns how many runs it made and float32 (N, ...)."""
    idx = runs[0]
    start, stop = int(idx[0]), int(idx[-1]) + 1
    if method == "tfp":
        half = (window - 1) // 2
        lo, hi = max(0, start - half), min(total, stop + half)
        return 1, tfp(read(lo, hi), window, threshold, idx - lo)
    margin = TFI_MARGIN
    while True:  # TFSTP's state carries the whole history: it always reads from frame 0
        lo, hi = (0 if method == "tfstp" else max(0, start - margin)), min(total, stop - 1 + margin)
        sub = read(lo, hi)
        before = np.count_nonzero(sub[: start - lo], axis=0)
        after = np.count_nonzero(sub[stop - 1 - lo :], axis=0)
        if (lo == 0 or before.min() >= 2) and (hi == total or after.min() >= 2):
            done = len(runs) if (lo, hi) == (0, total) else 1  # (read whole: not again for the next run)
            idx = idx if done == 1 else np.concatenate(runs)
            return done, (tfstp if method == "tfstp" else tfi)(sub, threshold, idx - lo)
        margin *= 2


def check_window(window: object, param: str = "window", least: int = 1, path: Path | None = None) -> int:
    """``window`` as an int if it is an odd integer ≥ ``least`` (K = 2h + 1 steps centred on its step),
    else InputError naming ``param`` (and ``path``): the one check of every window of the toolkit."""
    bad = not is_integer(window)
    if bad or window < least or window % 2 == 0:  # type: ignore[operator]
        raise InputError(
            f"{param} must be an odd number of steps ≥ {least} (K = 2h+1, centred), found {window!r}",
            path=path,
            param=param,
        )
    return int(window)  # type: ignore[arg-type]

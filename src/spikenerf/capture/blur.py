"""The conventional (blurred) camera of a dataset: which exposures, and their images by a running sum.

A blur view is the mean of the step renders over an exposure ``[start, end)`` of ``round(fps / blur_fps)``
steps (100 for a 400 fps camera beside a 40 kHz spike camera). ``--blur-views`` picks the exposures:

* ``frames``: consecutive, non-overlapping frames (a 400 fps video; 10 frames for 1000 steps; a trailing
  partial frame keeps its real, shorter exposure);
* ``all``: the paper's baseline, one exposure centred on every spike step (overlapping; 1000 views);
* ``N``: ``N`` exposures centred on evenly spaced steps ``floor((j + 0.5) · T / N)``, j = 0…N−1.

A centred exposure covers steps ``[c − L//2, c − L//2 + L)`` clipped to the path, so near the ends of the
path it is shorter (its ``step_start``/``step_end`` record the real window).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from spikenerf.core.errors import InputError, parse_int

BLUR_VIEW_NAMES = ("frames", "all")


def parse_blur_views(spec: str | int) -> str | int:
    """``frames`` | ``all`` | a positive integer (``"10"`` → 10); InputError naming ``blur_views``."""
    text = str(spec).strip()
    if text in BLUR_VIEW_NAMES:
        return text
    count = parse_int(text, "blur_views", "all, frames or a positive integer")
    if count < 1:
        raise InputError(f"blur_views must be ≥ 1 (or all, frames), found {count}", param="blur_views")
    return count


def check_blur_views(spec: str | int, num_steps: int) -> str | int:
    """:func:`parse_blur_views`, and a count must not exceed the ``num_steps`` spike steps."""
    views = parse_blur_views(spec)
    if isinstance(views, int) and views > num_steps:
        raise InputError(f"blur_views {views} exceeds the {num_steps} spike steps", param="blur_views")
    return views


def exposure_length(fps: float, blur_fps: float) -> int:
    """Steps per exposure: ``round(fps / blur_fps)``; InputError if the blur camera is faster than ``fps``."""
    size = round(fps / blur_fps)
    if blur_fps > fps or size < 1:
        raise InputError(
            f"blur_fps {blur_fps:g} exceeds the spike rate {fps:g} Hz (need blur_fps ≤ fps)", param="blur_fps"
        )
    return size


def blur_windows(
    num_steps: int, fps: float, blur_fps: float, views: str | int = "frames"
) -> list[tuple[int, int]]:
    """Exposure windows ``[start, end)`` in step positions (module docstring); [] if ``blur_fps`` is 0.

    Both ``start`` and ``end`` are non-decreasing along the list.
    """
    if blur_fps <= 0:
        return []
    size = exposure_length(fps, blur_fps)
    views = check_blur_views(views, num_steps)
    if views == "frames":
        return [(a, min(a + size, num_steps)) for a in range(0, num_steps, size)]
    if views == "all":
        centres = np.arange(num_steps)
    else:
        centres = np.floor((np.arange(views) + 0.5) * num_steps / int(views)).astype(np.int64)
    starts = centres - size // 2
    return [(max(int(a), 0), min(int(a) + size, num_steps)) for a in starts]


def blur_window_count(num_steps: int, fps: float, blur_fps: float, views: str | int = "frames") -> int:
    """``len(blur_windows(...))`` without building the list (the resource estimate runs it before a size
    is known to fit)."""
    if blur_fps <= 0:
        return 0
    views = check_blur_views(views, num_steps)
    if views == "frames":
        return -(-num_steps // exposure_length(fps, blur_fps))
    return num_steps if views == "all" else int(views)


class RunningExposures:
    """Mean image of every exposure window by a running sum over frames pushed in step order.

    Args:
        windows: ``[start, end)`` with non-decreasing starts and ends (from :func:`blur_windows`).
        frame_at: re-reads the frame (H, W, C) of step position i when it leaves the running sum.

    Memory: one float64 (H, W, C) sum, whatever the overlap; each frame is read at most twice.
    """

    def __init__(self, windows: list[tuple[int, int]], frame_at: Callable[[int], np.ndarray]) -> None:
        self.windows, self.frame_at = windows, frame_at
        self.total: np.ndarray | None = None
        self.lo = self.hi = self.next = 0  # the running sum covers step positions [lo, hi)

    def push(self, frame: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Add the frame (H, W, C) of the next step; returns (window index, float64 (H, W, C) mean) of every
        window that ends with it (fresh arrays)."""
        if self.next == len(self.windows):
            return []
        self.total = frame.astype(np.float64) if self.total is None else self.total + frame
        self.hi += 1
        done = []
        while self.next < len(self.windows) and self.windows[self.next][1] == self.hi:
            start = self.windows[self.next][0]
            while self.lo < start:
                self.total -= self.frame_at(self.lo)
                self.lo += 1
            done.append((self.next, self.total / (self.hi - self.lo)))
            self.next += 1
        return done

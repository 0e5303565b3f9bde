"""A selection of a stream's frames (a slice, one index or None) as the ``range`` of indices it means, checked
strictly: what every reader of spikes (``.dat`` files, reconstructions, the learned reconstructor) takes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError


def resolve_frames(
    frames: slice | int | None, total: int, path: str | Path | None = None, param: str = "frames"
) -> range:
    """A frame selection as a ``range`` of indices into a ``total``-frame stream, checked strictly.

    ``None`` selects all frames; an int ``i`` selects ``i:i+1``; negative indices count from the end (as in
    Python); unlike Python slicing, a start/stop outside ``[0, total]``, a non-positive step or an empty
    selection is an InputError naming ``param`` (the caller's name for the selection).
    """
    if frames is None:
        return range(total)
    if isinstance(frames, (int, np.integer)) and not isinstance(frames, bool):
        i = int(frames) + total if frames < 0 else int(frames)
        if not 0 <= i < total:
            raise InputError(
                f"{param}: frame {frames} is outside the {total}-frame stream (valid 0..{total - 1}, or "
                f"-{total}..-1 from the end)",
                path,
                param=param,
            )
        return range(i, i + 1)
    if not isinstance(frames, slice):
        raise InputError(
            f"{param} must be a slice, an int or None, found {type(frames).__name__}", path=path, param=param
        )
    try:
        step = 1 if frames.step is None else int(frames.step)
        start = 0 if frames.start is None else int(frames.start)
        stop = total if frames.stop is None else int(frames.stop)
    except (TypeError, ValueError):
        raise InputError(
            f"{param}: a slice of integers expected, found {frames!r}", path=path, param=param
        ) from None
    if step <= 0:
        raise InputError(f"{param}: frame step must be positive, found {step}", path=path, param=param)
    start, stop = (start + total if start < 0 else start), (stop + total if stop < 0 else stop)
    if not 0 <= start < stop <= total:
        raise InputError(
            f"{param}: frame range {frames.start}:{frames.stop} is empty or outside the {total}-frame stream "
            f"(need 0 <= start < stop <= {total}, a negative index counting from the end: -{total} is 0)",
            path=path,
            param=param,
        )
    return range(start, stop, step)

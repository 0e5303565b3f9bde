"""The one mp4 writer: H.264 (yuv420p) through imageio-ffmpeg's bundled ffmpeg, fed frame by frame.

``spikenerf render`` (:mod:`spikenerf.eval.video`) writes its views with it and ``spikenerf reconstruct --out
FILE.mp4`` its reconstructed frames, streamed block by block so that a long recording never sits in
memory. The file is written atomically: a temporary beside it, renamed when the last frame is encoded, and
removed on any error or interrupt.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from spikenerf.core.atomic import atomic_path
from spikenerf.core.color import display_uint8
from spikenerf.core.errors import InputError

#: the video rates an mp4 holds faithfully (below, ffmpeg drops frames; above about 10⁶ it clamps the rate)
FPS_VIDEO = (1e-2, 1e5)


def check_fps(fps: float, param: str = "fps_video") -> None:
    """InputError naming ``param`` unless ``fps`` (frames a second of the video) lies in :data:`FPS_VIDEO`."""
    if not FPS_VIDEO[0] <= fps <= FPS_VIDEO[1]:  # (NaN is refused too)
        raise InputError(
            f"{param} must lie in [{FPS_VIDEO[0]:g}, {FPS_VIDEO[1]:g}] frames a second, found {fps}",
            param=param,
        )


def to_uint8(display: np.ndarray) -> np.ndarray:
    """Display values [0, 1] (H, W, C) → uint8 (H, W) for C = 1, (H, W, 3) for C = 3."""
    q = display_uint8(display)
    return q[..., 0] if q.shape[-1] == 1 else q


def ffmpeg_module(command: str = "render") -> Any:
    """``imageio_ffmpeg``; an InputError with the install line where it is missing (it is a dependency, but
    a source checkout run with another Python, e.g. on a GPU host, may lack it). ``command``: who writes the
    mp4, named in the message."""
    try:
        import imageio_ffmpeg
    except ImportError as err:
        raise InputError(
            f"{command} writes an mp4 and needs imageio-ffmpeg: pip install imageio-ffmpeg"
        ) from err
    return imageio_ffmpeg


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: float) -> int:
    """Write ``frames`` — uint8 (H, W) gray or (H, W, 3) RGB, all of one shape — as an H.264 mp4 (yuv420p)
    at ``fps`` frames a second; returns the number of frames written.

    ``frames`` may be any iterable, e.g. a generator that reconstructs or renders frames as they are
    encoded: it is consumed one frame at a time and never held whole. Odd sizes are edge-padded to even
    (yuv420p needs even sizes). The file appears only complete (:func:`~spikenerf.core.atomic.atomic_path`):
    an error raised by ``frames`` or by ffmpeg, or Ctrl-C, leaves no file and no temporary behind.

    Raises:
        InputError: imageio-ffmpeg is missing (:func:`ffmpeg_module`), ``fps`` is outside :data:`FPS_VIDEO`,
            ``frames`` is empty or its frames differ in shape or are not uint8 (H, W) / (H, W, 3).
    """
    imageio_ffmpeg = ffmpeg_module()
    check_fps(fps, "fps")
    path = Path(path)
    count, writer, shape = 0, None, None
    with atomic_path(path) as tmp:
        try:
            for frame in frames:
                frame = np.asarray(frame)
                if shape is None:
                    shape = _frame_shape(frame)
                    h, w = shape[:2]
                    writer = imageio_ffmpeg.write_frames(
                        str(tmp), (w + w % 2, h + h % 2), fps=fps, codec="libx264",
                        pix_fmt_in="gray" if frame.ndim == 2 else "rgb24", pix_fmt_out="yuv420p",
                        macro_block_size=1, output_params=["-f", "mp4"], ffmpeg_log_level="error",
                    )  # fmt: skip
                    writer.send(None)
                elif frame.shape != shape or frame.dtype != np.uint8:
                    raise InputError(
                        f"frames: frame {count} is {frame.dtype} {frame.shape}, the first was uint8 {shape}",
                        param="frames",
                    )
                pad = ((0, shape[0] % 2), (0, shape[1] % 2), *(((0, 0),) if frame.ndim == 3 else ()))
                writer.send(np.ascontiguousarray(np.pad(frame, pad, mode="edge")))
                count += 1
        finally:
            if writer is not None:
                writer.close()
        if count == 0:
            raise InputError("frames: no frame to write", param="frames")
    return count


def _frame_shape(frame: np.ndarray) -> tuple[int, ...]:
    """The shape of a valid first frame: uint8 (H, W) or (H, W, 3), H and W ≥ 1; else an InputError."""
    ok = frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3)
    if frame.dtype != np.uint8 or not ok or 0 in frame.shape:
        raise InputError(
            f"frames: need uint8 (H, W) or (H, W, 3) frames, found {frame.dtype} {frame.shape}",
            param="frames",
        )
    return tuple(frame.shape)

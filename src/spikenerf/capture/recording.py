"""A dataset's gray stream as a camera would deliver it: a raw ``.dat`` + SpikeCV ``config.yaml``, no poses.

``simulate --raw-width N`` writes it to ``DATASET/raw/`` so that the real-data workflow (``spikenerf import``,
docs/real-data.md) can be tried where the truth is known. Each stored row carries ``N − W`` extra columns,
written as zeros (raw sps10 files carry 16 such non-pixel columns: 416 for a 400-pixel row).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spikenerf.camera.dat_codec import frame_bytes
from spikenerf.camera.io import iter_dat, write_dat
from spikenerf.camera.spikecv import write_spikecv_config
from spikenerf.core.errors import InputError

RAW_DIR = "raw"
RAW_FILE = "recording.dat"


def raw_width_limit(width: int) -> int:
    """The widest stored row that :func:`check_raw_width` accepts for an image ``width``: 2·W, at least W + 64
    (real cameras pad a few columns: 416 for 400)."""
    return max(2 * width, width + 64)


def check_raw_width(raw_width: int | None, height: int, width: int) -> None:
    """InputError unless H·W % 8 == 0 (naming ``width``/``height``: the dataset's ``.dat`` files pack 8
    pixels a byte) and, where ``raw_width`` is given, W ≤ ``raw_width`` ≤ :func:`raw_width_limit` with
    H·raw_width % 8 == 0 (naming ``raw_width``)."""
    if height > 0 and width > 0 and (height * width) % 8:
        raise InputError(
            f"width × height must be a multiple of 8 (a .dat file packs 8 pixels a byte), found "
            f"{width}×{height} = {width * height}",
            param=("width", "height"),
        )
    if raw_width is None:
        return
    if not width <= raw_width <= raw_width_limit(width):
        raise InputError(
            f"raw_width must be from the image width {width} to {raw_width_limit(width)} (stored rows hold a "
            f"few padding columns), found {raw_width}",
            param="raw_width",
        )
    if (height * raw_width) % 8:
        raise InputError(
            f"raw_width: H·raw_width must be a multiple of 8, found {height}×{raw_width}", param="raw_width"
        )
    frame_bytes(height, width, raw_width)


def write_raw_recording(
    spikes_dat: str | Path, height: int, width: int, fps: float, out_dir: str | Path, raw_width: int
) -> Path:
    """Copy the (T, H, W) stream ``spikes_dat`` to ``out_dir/recording.dat`` with ``raw_width`` columns per
    row (chunk by chunk, atomically) and write the SpikeCV ``config.yaml`` beside it: spike_h, spike_w,
    raw_width, fps — no poses, no intrinsics. Returns the recording's path."""
    check_raw_width(raw_width, height, width)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    pad = raw_width - width

    def chunks():
        for _, chunk in iter_dat(spikes_dat, height, width):
            yield np.concatenate([chunk, np.zeros((len(chunk), height, pad), np.uint8)], axis=2)

    rec = out_dir / RAW_FILE
    write_dat(rec, chunks())
    write_spikecv_config(out_dir, height, width, fps, raw_width=raw_width)
    return rec

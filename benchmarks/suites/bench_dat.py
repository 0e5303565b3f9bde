""".dat decoding and reconstruction throughput, in frames per second.

Run: ``.venv/bin/python -m benchmarks.suites.bench_dat``. The workload is a 2000-frame 250×400 stream (mean
spike rate 0.3, 25 MB on disk) written to a temporary folder, read back while in the page cache.

References, measured in the same process:
- ``np.unpackbits``: a bare ``np.unpackbits(bitorder="little")`` of the same bytes already in memory — no file
  access, no row flip, no reshape: the decode floor. ``read_dat`` adds the memory map and the bottom-up row
  flip (target ≥ 0.7×);
- ``np.packbits``: the same for writing (``write_dat`` adds the row flip, binary check and file write);
- ``per-frame loop``: the textbook reconstruction, one numpy window sum (TFP) or ``any`` (masks) per output
  frame, timed on 100 frames and scaled to frames/s;
- TFI is reported against ``tfp`` of this module (both vectorised; the ratio is the relative cost).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from benchmarks._table import Row, best_seconds, format_table
from spikenerf.camera.io import read_dat, write_dat
from spikenerf.camera.masks import spike_masks
from spikenerf.camera.reconstruct import tfi, tfp

HEIGHT, WIDTH, FRAMES, RATE = 250, 400, 2000, 0.3
WINDOW, MASK_N = 41, 5
#: output frames for the vectorised reconstructions, and for the per-frame loop references
OUT_FRAMES, LOOP_FRAMES = 400, 100


def _stream() -> np.ndarray:
    return (np.random.default_rng(0).random((FRAMES, HEIGHT, WIDTH), dtype=np.float32) < RATE).astype(
        np.uint8
    )


def loop_tfp(spikes: np.ndarray, frames: int, window: int = WINDOW) -> np.ndarray:
    """Reference TFP: one window sum per output frame (the window clipped at the stream edges)."""
    half, total = (window - 1) // 2, spikes.shape[0]
    out = np.empty((frames, *spikes.shape[1:]), np.float32)
    for k in range(frames):
        lo, hi = max(0, k - half), min(total, k + half + 1)
        out[k] = spikes[lo:hi].sum(axis=0, dtype=np.int32) / (hi - lo)
    return out


def loop_masks(spikes: np.ndarray, frames: int, n: int = MASK_N) -> np.ndarray:
    """Reference masks: one ``any`` over 2n+1 frames per output frame."""
    total = spikes.shape[0]
    return np.stack([spikes[max(0, k - n) : min(total, k + n + 1)].any(axis=0) for k in range(frames)])


def measure(repeats: int = 3) -> list[Row]:
    spikes = _stream()
    rows: list[Row] = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.dat"
        write_dat(path, spikes)
        packed = np.fromfile(path, np.uint8)
        assert np.array_equal(read_dat(path, HEIGHT, WIDTH), spikes)
        decode = best_seconds(lambda: read_dat(path, HEIGHT, WIDTH), repeats)
        topdown = best_seconds(lambda: read_dat(path, HEIGHT, WIDTH, layout="topdown"), repeats)
        unpack = best_seconds(lambda: np.unpackbits(packed, bitorder="little"), repeats)
        rows.append(Row("read_dat (spikecv)", FRAMES / decode, FRAMES / unpack, "frames/s", "np.unpackbits"))
        rows.append(Row("read_dat (topdown)", FRAMES / topdown, FRAMES / unpack, "frames/s", "np.unpackbits"))
        encode = best_seconds(lambda: write_dat(Path(tmp) / "w.dat", spikes), repeats)
        pack = best_seconds(
            lambda: np.packbits(spikes.reshape(FRAMES, -1), axis=-1, bitorder="little"), repeats
        )
        rows.append(Row("write_dat (spikecv)", FRAMES / encode, FRAMES / pack, "frames/s", "np.packbits"))
    middle = slice(FRAMES // 2 - OUT_FRAMES // 2, FRAMES // 2 + OUT_FRAMES // 2)
    t_tfp = best_seconds(lambda: tfp(spikes, WINDOW, frames=middle), repeats)
    t_loop = best_seconds(lambda: loop_tfp(spikes, LOOP_FRAMES), repeats)
    rows.append(
        Row(f"tfp window {WINDOW}", OUT_FRAMES / t_tfp, LOOP_FRAMES / t_loop, "frames/s", "per-frame loop")
    )
    t_masks = best_seconds(lambda: spike_masks(spikes, MASK_N, frames=middle), repeats)
    t_loop = best_seconds(lambda: loop_masks(spikes, LOOP_FRAMES), repeats)
    rows.append(
        Row(
            f"spike_masks n={MASK_N}",
            OUT_FRAMES / t_masks,
            LOOP_FRAMES / t_loop,
            "frames/s",
            "per-frame loop",
        )
    )
    t_tfi = best_seconds(lambda: tfi(spikes[:OUT_FRAMES]), repeats)
    rows.append(
        Row(f"tfi ({OUT_FRAMES}-frame stream)", OUT_FRAMES / t_tfi, OUT_FRAMES / t_tfp, "frames/s", "tfp")
    )
    return rows


if __name__ == "__main__":
    print(f"{FRAMES} frames of {HEIGHT}×{WIDTH}, spike rate {RATE}; best of 3")
    print(format_table(measure()))

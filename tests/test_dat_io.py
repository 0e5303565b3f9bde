"""SpikeCV .dat I/O: bit/row layout, round trips, frame ranges, 416-column stripping and every error path."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from spikenerf.camera import io
from spikenerf.camera.frame_range import resolve_frames
from spikenerf.camera.io import count_frames, iter_dat, read_dat, read_dat_rgb, write_dat, write_dat_rgb
from spikenerf.core.errors import InputError


def _naive_decode(data: bytes, height: int, stored_w: int, width: int, flip: bool) -> np.ndarray:
    """Decode by the written rule, one pixel at a time: pixel p is bit p % 8 of byte p // 8."""
    frame = height * stored_w // 8
    out = np.zeros((len(data) // frame, height, width), np.uint8)
    for t in range(out.shape[0]):
        for p in range(height * stored_w):
            row, col = divmod(p, stored_w)
            if col < width:
                bit = (data[t * frame + p // 8] >> (p % 8)) & 1
                out[t, height - 1 - row if flip else row, col] = bit
    return out


@st.composite
def streams(draw: st.DrawFn) -> np.ndarray:
    height = draw(st.integers(1, 9))
    width = draw(st.integers(1, 4)) * (8 // math.gcd(height, 8))
    frames = draw(st.integers(1, 6))
    bits = draw(st.lists(st.booleans(), min_size=frames * height * width, max_size=frames * height * width))
    return np.array(bits, np.uint8).reshape(frames, height, width)


@settings(max_examples=60, deadline=None)
@given(spikes=streams(), layout=st.sampled_from(["spikecv", "topdown"]), data=st.data())
def test_round_trip_and_frame_ranges(tmp_path_factory, spikes: np.ndarray, layout: str, data) -> None:
    path = tmp_path_factory.mktemp("rt") / "s.dat"
    t, h, w = spikes.shape
    assert write_dat(path, spikes, layout=layout) == t
    assert path.stat().st_size == t * h * w // 8
    assert count_frames(path, h, w) == t
    np.testing.assert_array_equal(read_dat(path, h, w, layout=layout), spikes)
    np.testing.assert_array_equal(
        read_dat(path, h, w, layout=layout), _naive_decode(path.read_bytes(), h, w, w, layout == "spikecv")
    )
    start = data.draw(st.integers(0, t - 1))
    stop = data.draw(st.integers(start + 1, t))
    step = data.draw(st.integers(1, 3))
    got = read_dat(path, h, w, frames=slice(start, stop, step), layout=layout)
    np.testing.assert_array_equal(got, spikes[start:stop:step])
    assert got.dtype == np.uint8 and got.flags.c_contiguous


def test_known_bits_2x8(tmp_path: Path) -> None:
    # byte 0 bit 0 = stored pixel 0 (stored row 0, col 0); byte 1 bit 7 = stored pixel 15 (row 1, col 7)
    path = tmp_path / "k.dat"
    path.write_bytes(bytes([0b0000_0001, 0b1000_0000]))
    spikecv = read_dat(path, 2, 8)
    topdown = read_dat(path, 2, 8, layout="topdown")
    assert spikecv.shape == (1, 2, 8) and int(spikecv.sum()) == 2 == int(topdown.sum())
    assert spikecv[0, 1, 0] == 1 and spikecv[0, 0, 7] == 1  # bottom-left, top-right
    assert topdown[0, 0, 0] == 1 and topdown[0, 1, 7] == 1  # top-left, bottom-right
    write_dat(tmp_path / "w.dat", spikecv)
    assert (tmp_path / "w.dat").read_bytes() == path.read_bytes()


def test_bit_order_within_byte(tmp_path: Path) -> None:
    path = tmp_path / "b.dat"
    path.write_bytes(bytes([0b0000_0110]))  # bits 1 and 2 → columns 1 and 2 of a 1×8 frame
    np.testing.assert_array_equal(read_dat(path, 1, 8)[0, 0], [0, 1, 1, 0, 0, 0, 0, 0])


def test_raw_width_416_strips_trailing_columns(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    pixels = (rng.random((3, 4, 400)) < 0.3).astype(np.uint8)
    stored = np.concatenate([pixels, np.ones((3, 4, 16), np.uint8)], axis=2)  # extra columns 400..415 set
    write_dat(tmp_path / "raw.dat", stored)
    got = read_dat(tmp_path / "raw.dat", 4, 400, raw_width=416)
    np.testing.assert_array_equal(got, pixels)
    assert count_frames(tmp_path / "raw.dat", 4, 400, raw_width=416) == 3
    np.testing.assert_array_equal(
        read_dat(tmp_path / "raw.dat", 4, 400, frames=slice(1, 2), raw_width=416), pixels[1:2]
    )
    # rows that are not byte-aligned take the generic path
    small = (rng.random((2, 2, 4)) < 0.5).astype(np.uint8)
    write_dat(tmp_path / "s.dat", np.concatenate([small, np.ones((2, 2, 4), np.uint8)], axis=2))
    np.testing.assert_array_equal(read_dat(tmp_path / "s.dat", 2, 4, raw_width=8), small)
    odd = (rng.random((2, 4, 3)) < 0.5).astype(np.uint8)  # 6-column stored rows straddle bytes
    write_dat(tmp_path / "o.dat", np.concatenate([odd, np.ones((2, 4, 3), np.uint8)], axis=2))
    np.testing.assert_array_equal(read_dat(tmp_path / "o.dat", 4, 3, raw_width=6), odd)
    np.testing.assert_array_equal(
        read_dat(tmp_path / "o.dat", 4, 3, raw_width=6, layout="topdown"), odd[:, ::-1]
    )


def test_iter_dat_chunks_match_read(tmp_path: Path) -> None:
    spikes = (np.random.default_rng(1).random((23, 4, 6)) < 0.4).astype(np.uint8)
    write_dat(tmp_path / "a.dat", spikes)
    parts = list(iter_dat(tmp_path / "a.dat", 4, 6, chunk_frames=5, frames=slice(2, 21)))
    assert [start for start, _ in parts] == [2, 7, 12, 17]
    np.testing.assert_array_equal(np.concatenate([c for _, c in parts]), spikes[2:21])


def test_memmap_maps_only_the_selected_frames(tmp_path: Path, monkeypatch) -> None:
    write_dat(tmp_path / "a.dat", np.zeros((50, 8, 8), np.uint8))
    calls = []
    real = np.memmap

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(io.np, "memmap", spy)
    read_dat(tmp_path / "a.dat", 8, 8, frames=slice(40, 43))
    assert [(c["offset"], c["shape"]) for c in calls] == [(40 * 8, (3, 8))]


def test_write_streams_chunks_and_torch(tmp_path: Path) -> None:
    spikes = np.random.default_rng(2).random((10, 4, 4)) < 0.5
    chunks = (torch.from_numpy(spikes[a : a + 3]) for a in range(0, 10, 3))
    assert write_dat(tmp_path / "c.dat", chunks) == 10
    np.testing.assert_array_equal(read_dat(tmp_path / "c.dat", 4, 4), spikes)


def test_rgb_round_trip(tmp_path: Path) -> None:
    spikes = (np.random.default_rng(3).random((5, 3, 4, 6)) < 0.5).astype(np.uint8)
    paths = write_dat_rgb(tmp_path / "spikes_rgb", spikes)
    assert [p.name for p in paths] == ["spikes_rgb_r.dat", "spikes_rgb_g.dat", "spikes_rgb_b.dat"]
    np.testing.assert_array_equal(read_dat_rgb(tmp_path / "spikes_rgb", 4, 6), spikes)
    write_dat(paths[1], spikes[:4, 1])
    with pytest.raises(InputError, match=r"different frame counts \[5, 4, 5\]"):
        read_dat_rgb(tmp_path / "spikes_rgb", 4, 6)
    bad = spikes.copy()
    bad[2, 2, 0, 0] = 7  # in the last channel: refused before any file is written
    with pytest.raises(InputError, match="binary"):
        write_dat_rgb(tmp_path / "other", bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in paths)


def test_size_not_a_multiple_of_the_frame(tmp_path: Path) -> None:
    path = tmp_path / "t.dat"
    path.write_bytes(bytes(250 * 400 // 8 * 2 + 7))
    with pytest.raises(InputError) as err:
        count_frames(path, 250, 400)
    msg = str(err.value)
    assert (
        "12500 bytes" in msg and "25007 bytes" in msg and "remainder of 7 bytes" in msg and str(path) in msg
    )
    assert "(400 pixels wide, 250 high, / 8)" in msg  # (it read 250×400, against width × height elsewhere)
    assert msg.endswith("a capture cut short: truncate -s 25000 a copy") and "raw_width" not in msg
    with pytest.raises(InputError, match="remainder"):
        read_dat(path, 250, 400)
    path.write_bytes(bytes(7))  # not one whole frame: nothing to truncate to
    with pytest.raises(InputError) as err:
        count_frames(path, 250, 400)
    assert "truncate -s" not in str(err.value)


def test_shape_and_argument_errors(tmp_path: Path) -> None:
    path = tmp_path / "a.dat"
    write_dat(path, np.zeros((4, 2, 4), np.uint8))
    with pytest.raises(InputError, match=r"multiple of 8.*3×5 = 15"):
        read_dat(path, 3, 5)
    with pytest.raises(InputError, match="layout"):
        read_dat(path, 2, 4, layout="bottomup")
    with pytest.raises(InputError, match="raw_width 3 is smaller"):
        read_dat(path, 2, 4, raw_width=3)
    with pytest.raises(InputError, match="not found"):
        read_dat(tmp_path / "missing.dat", 2, 4)
    with pytest.raises(InputError, match="directory"):
        read_dat(tmp_path, 2, 4)
    with pytest.raises(InputError, match="write_dat_rgb"):
        write_dat(tmp_path / "x.dat", np.zeros((2, 3, 2, 4), np.uint8))
    with pytest.raises(InputError, match=r"\(T, 3, H, W\)"):
        write_dat_rgb(tmp_path / "x", np.zeros((2, 2, 4), np.uint8))


@pytest.mark.parametrize(
    ("frames", "pattern"),
    [
        (slice(3, 3), "empty or outside"),
        (slice(2, 9), "empty or outside the 4-frame"),
        (slice(-9, None), "empty or outside"),
        (slice(0, 4, 0), "step must be positive"),
        (4, "frame 4 is outside the 4-frame stream"),
        ("1:2", "must be a slice"),
    ],
)
def test_bad_frame_ranges(tmp_path: Path, frames, pattern: str) -> None:
    path = tmp_path / "a.dat"
    write_dat(path, np.zeros((4, 2, 4), np.uint8))
    with pytest.raises(InputError, match=pattern):
        read_dat(path, 2, 4, frames=frames)


def test_resolve_frames_negative_indices() -> None:
    assert resolve_frames(slice(-3, None), 10) == range(7, 10)
    assert resolve_frames(-1, 10) == range(9, 10)
    assert resolve_frames(None, 0) == range(0)


def test_non_binary_write_leaves_nothing(tmp_path: Path) -> None:
    path = tmp_path / "keep.dat"
    write_dat(path, np.ones((1, 2, 4), np.uint8))
    before = path.read_bytes()
    bad = np.zeros((3, 2, 4), np.uint8)
    bad[2, 1, 1] = 255
    with pytest.raises(InputError, match=r"binary .* found 1 other values \(e.g. 255\)"):
        write_dat(path, bad)
    assert path.read_bytes() == before
    with pytest.raises(InputError, match="binary"):
        write_dat(tmp_path / "new.dat", np.full((1, 2, 4), 0.5))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.dat"]


def test_empty_file_reads_zero_frames(tmp_path: Path) -> None:
    (tmp_path / "e.dat").write_bytes(b"")
    assert read_dat(tmp_path / "e.dat", 2, 4).shape == (0, 2, 4)
    assert count_frames(tmp_path / "e.dat", 2, 4) == 0

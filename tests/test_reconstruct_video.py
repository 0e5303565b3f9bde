"""``spikenerf reconstruct --out FILE.mp4`` (a video preview), ``--stride``, and the shared mp4 writer."""

from __future__ import annotations

import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from helpers import run_cli
from spikenerf.camera.firing import fire
from spikenerf.camera.io import write_dat
from spikenerf.camera.reconstruct import tfi, tfp
from spikenerf.cli.reconstruct import BLOCK_FRAMES, blocks
from spikenerf.core.color import srgb_encode
from spikenerf.core.errors import InputError
from spikenerf.core.video import write_video

H, W, T = 32, 32, 300


def _moving_stream(height: int, width: int, steps: int, seed: int = 0) -> np.ndarray:
    """Spikes (T, H, W) of a smooth sine pattern drifting one period across the frame over the stream."""
    y, x = np.mgrid[0:height, 0:width]
    acc = np.random.default_rng(seed).uniform(0.0, 1.0, (height, width))
    out = []
    for t in range(steps):
        wave = 0.5 + 0.5 * np.sin(2 * np.pi * (x / width + t / steps))
        spikes, acc = fire(acc, 0.1 + 0.8 * wave * (0.6 + 0.4 * y / height), 1.0)
        out.append(spikes)
    return np.stack(out).astype(np.uint8)


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    path = tmp_path / "rec" / "s.dat"
    path.parent.mkdir()
    write_dat(path, _moving_stream(H, W, T))
    (path.parent / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\n")
    return path


def _decode(path: Path, pix_fmt: str = "gray") -> tuple[np.ndarray, float, tuple[int, int]]:
    """(frames uint8 (N, H, W) gray or (N, H, W, 3) rgb24, the container's fps, (width, height))."""
    import imageio_ffmpeg

    channels = 1 if pix_fmt == "gray" else 3
    reader = imageio_ffmpeg.read_frames(str(path), pix_fmt=pix_fmt, bpp=channels)
    meta = next(reader)
    w, h = meta["size"]
    shape = (h, w) if channels == 1 else (h, w, 3)
    frames = [np.frombuffer(b, np.uint8).reshape(shape) for b in reader]
    return np.stack(frames), float(meta["fps"]), (w, h)


def test_the_mp4_holds_the_png_frames_at_the_stride_and_rate(capsys, recording: Path, tmp_path: Path) -> None:
    args = ["reconstruct", recording, "--method", "tfp", "--window", 61, "--frames", "20:280", "--stride", 13]
    code, out, err = run_cli(capsys, *args, "--fps-video", 12, "--out", tmp_path / "v.mp4")
    assert code == 0, err
    assert "wrote" in out and "(20 frames, tfp: 1 in 13 of frames 20:280, 6.5 ms at 40000 Hz; it plays" in out
    assert run_cli(capsys, *args, "--out", tmp_path / "pngs")[0] == 0
    kept = range(20, 280, 13)
    assert sorted(p.name for p in (tmp_path / "pngs").glob("*.png")) == [f"{i:05d}.png" for i in kept]
    pngs = np.stack([iio.imread(tmp_path / "pngs" / f"{i:05d}.png") for i in kept]).astype(float)
    linear = tfp(_moving_stream(H, W, T), 61)[20:280:13].astype(np.float64)  # the recording's frames
    np.testing.assert_array_equal(pngs, np.round(srgb_encode(linear) * 255))
    video, fps, size = _decode(tmp_path / "v.mp4")
    assert video.shape == (len(kept), H, W) and fps == 12.0 and size == (W, H)
    own = np.abs(video - pngs).mean(axis=(1, 2))
    assert own.max() < 3.0, own  # H.264's error on the sRGB frames, in grey levels
    shifted = np.abs(video[1:] - pngs[:-1]).mean()  # the frames are in order: each its own, not its neighbour
    assert shifted > own.mean() + 2.0, (shifted, own.mean())
    rgb, _, _ = _decode(tmp_path / "v.mp4", "rgb24")  # a gray stream → a grey video
    assert np.abs(rgb[..., 0].astype(int) - rgb[..., 2]).max() <= 1


def test_the_default_is_every_frame_at_30_fps_and_odd_sizes_are_padded(capsys, tmp_path: Path) -> None:
    spikes = _moving_stream(7, 24, 150)
    path = tmp_path / "odd.dat"
    write_dat(path, spikes)
    code, _, err = run_cli(capsys, "reconstruct", path, "--height", 7, "--width", 24, "--method", "tfi",
                           "--encoding", "linear", "--out", tmp_path / "v.mp4")  # fmt: skip
    assert code == 0, err
    video, fps, size = _decode(tmp_path / "v.mp4")
    assert video.shape == (150, 8, 24) and fps == 30.0 and size == (24, 8)  # one edge row added
    expect = np.round(np.clip(tfi(spikes), 0, 1) * 255)  # --encoding linear: no gamma
    brightness = np.abs(video[:, :7].mean(axis=(1, 2)) - expect.mean(axis=(1, 2)))  # (TFI's noise: no pixels)
    assert brightness.max() < 4.0, brightness  # sRGB values would be some 40 levels brighter


def test_the_progress_bar_counts_the_video_frames(
    capsys, recording: Path, tmp_path: Path, monkeypatch
) -> None:
    import spikenerf.core.progress as progress

    class Bar:
        """What reconstruct asks of its bar: a total, updates, closing."""

        def __init__(self, total: int, **kwargs: object) -> None:
            self.total, self.n, self.steps = total, 0, 0
            made.append(self)

        def update(self, n: int = 1) -> None:
            self.n, self.steps = self.n + n, self.steps + 1

        def __enter__(self) -> Bar:
            return self

        def __exit__(self, *exc: object) -> None:
            pass

    made: list[Bar] = []
    monkeypatch.setattr(progress, "bar", Bar)
    args = ["reconstruct", recording, "--method", "tfp", "--stride", 2, "--out", tmp_path / "v.mp4"]
    assert run_cli(capsys, *args)[0] == 0
    assert len(made) == 1 and made[0].total == T // 2 and made[0].n == T // 2
    assert made[0].steps == -(-(T // 2) // (BLOCK_FRAMES // 2))  # one update a block of 64 frames


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--frame", "5"], "a video needs a frame range: use --frames A:B"),
        (["--fps-video", "0"], "--fps-video must lie in [0.01, 100000] frames a second, found 0.0"),
        (["--fps-video", "nan"], "--fps-video must lie in"),
        (["--fps-video", "1e6"], "--fps-video must lie in"),
        (["--fps-video", "25", "--out-npy"], "--fps-video applies to --out FILE.mp4 only"),
        (["--stride", "0"], "--stride"),
        (["--stride", "2", "--frame", "3"], "--stride applies to a frame range"),
        (["--frames", "5:10", "--out-avi"], ".png, .npy or .mp4"),
    ],
)
def test_bad_video_options_exit_2_in_one_line_and_write_nothing(
    capsys, recording: Path, tmp_path: Path, extra: list[str], message: str
) -> None:
    out = tmp_path / "out" / "v.mp4"
    if "--out-npy" in extra or "--out-avi" in extra:
        out = out.with_suffix(".npy" if "--out-npy" in extra else ".avi")
        extra = [e for e in extra if not e.startswith("--out-")]
    code, _, err = run_cli(capsys, "reconstruct", recording, "--method", "tfp", *extra, "--out", out)
    assert code == 2 and message in err and err.strip().count("\n") == 0, err
    assert not out.parent.exists()


def test_without_imageio_ffmpeg_it_says_what_to_install(
    capsys, recording: Path, tmp_path, monkeypatch
) -> None:
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # its import now raises ImportError
    code, _, err = run_cli(capsys, "reconstruct", recording, "--method", "tfp", "--out", tmp_path / "v.mp4")
    assert code == 2 and err.strip().count("\n") == 0
    assert "reconstruct writes an mp4 and needs imageio-ffmpeg: pip install imageio-ffmpeg" in err
    assert not (tmp_path / "v.mp4").exists()


def test_an_existing_video_is_replaced_only_with_overwrite(capsys, recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "v.mp4"
    out.write_bytes(b"mine")
    base = ["reconstruct", recording, "--method", "tfp", "--frames", "0:40", "--out", out]
    code, _, err = run_cli(capsys, *base)
    assert code == 2 and "exists; pass --overwrite to replace it" in err and out.read_bytes() == b"mine"
    assert run_cli(capsys, *base, "--overwrite")[0] == 0
    assert len(_decode(out)[0]) == 40


def test_an_interrupt_mid_stream_leaves_the_old_file_and_no_temporary(
    capsys, recording: Path, tmp_path: Path, monkeypatch
) -> None:
    import spikenerf.data.reconstruction as dispatch

    real, calls = dispatch.reconstruct_frames, []

    def interrupted(*args, **kwargs):
        calls.append(args[2:4])
        if len(calls) == 2:  # the second block: the first is already in ffmpeg
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(dispatch, "reconstruct_frames", interrupted)
    out = tmp_path / "v.mp4"
    out.write_bytes(b"an earlier preview")
    code, _, err = run_cli(capsys, "reconstruct", recording, "--method", "tfp", "--overwrite", "--out", out)
    assert code == 130 and "aborted" in err
    assert calls == [(0, BLOCK_FRAMES), (BLOCK_FRAMES, 2 * BLOCK_FRAMES)]
    assert out.read_bytes() == b"an earlier preview"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec", "v.mp4"]


@pytest.mark.parametrize(
    ("method", "span", "stride"),
    [("tfp", (5, 190), 3), ("tfp", (5, 190), 70), ("tfi", (5, 190), 3), ("tfi", (5, 190), 70),
     ("learned", (60, 100), 3)],
)  # fmt: skip
def test_a_stride_keeps_every_kth_frame_of_the_range(
    capsys, tmp_path: Path, method: str, span: tuple[int, int], stride: int
) -> None:
    """TFP at a stride under its window reconstructs spans of frames, over it one frame a call; learned
    one frame a call at any stride > 1; TFI the whole range: each equals every frame's result, subsampled."""
    spikes = _moving_stream(8, 8, 200, seed=1)
    path = tmp_path / "s.dat"
    write_dat(path, spikes)
    a, b = span
    base = ["reconstruct", path, "--height", 8, "--width", 8, "--method", method, "--frames", f"{a}:{b}"]
    assert run_cli(capsys, *base, "--stride", stride, "--out", tmp_path / "k.npy")[0] == 0
    if method == "learned":  # the reference: the same range, every frame, kept after
        assert run_cli(capsys, *base, "--out", tmp_path / "all.npy")[0] == 0
        expect = np.load(tmp_path / "all.npy")[::stride]
    else:
        expect = (tfp(spikes, 41) if method == "tfp" else tfi(spikes))[a:b:stride]
    got = np.load(tmp_path / "k.npy")
    assert got.shape == (len(range(a, b, stride)), 8, 8)
    np.testing.assert_allclose(got, expect, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("method", ["tfp", "tfi", "learned"])
@pytest.mark.parametrize("frames", [range(0, 1000), range(3, 1000, 7), range(3, 1000, 41), range(5, 6, 9)])
def test_blocks_cover_the_frames_in_order_and_bound_the_span(method: str, frames: range) -> None:
    got = list(blocks(frames, method, window=41))
    assert [i for block in got for i in block] == list(frames)
    assert all(block.step == frames.step for block in got)
    if method == "tfi":
        assert len(got) == 1
    elif frames.step == 1 or (method == "tfp" and frames.step < 41):
        assert max(block[-1] + 1 - block.start for block in got) <= BLOCK_FRAMES
        assert len(got) <= -(-len(frames) // max(1, BLOCK_FRAMES // frames.step))
    else:  # a call per frame: cheaper than the skipped frames
        assert all(len(block) == 1 for block in got)


def test_write_video_streams_rgb_and_refuses_bad_frames_writing_nothing(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    smooth = np.linspace(0, 255, 16).astype(np.uint8)
    rgb = np.stack([np.tile(smooth, (10, 1)), np.tile(smooth[:10, None], (1, 16)), np.full((10, 16), 90)], -1)
    pulled = []

    def frames():
        for i in range(5):
            pulled.append(i)
            yield rgb.astype(np.uint8)

    assert write_video(tmp_path / "c.mp4", frames(), 24.0) == 5 and pulled == [0, 1, 2, 3, 4]
    video, fps, size = _decode(tmp_path / "c.mp4", "rgb24")
    assert video.shape == (5, 10, 16, 3) and fps == 24.0 and size == (16, 10)
    assert np.abs(video.astype(float) - rgb).mean() < 10.0  # (4:2:0 chroma of a tiny, saturated image)
    means = video.mean(axis=(0, 1, 2))  # R, G, B in their order
    np.testing.assert_allclose(means, rgb.mean(axis=(0, 1)), atol=3.0)

    def failing():
        yield rng.integers(0, 255, (10, 16), np.uint8)
        raise RuntimeError("reconstruction failed")

    bad = [
        ([], "no frame to write"),
        ([np.zeros((4, 6), np.float32)], "need uint8 (H, W) or (H, W, 3)"),
        ([np.zeros((4, 6), np.uint8), np.zeros((4, 8), np.uint8)], "frame 1 is uint8 (4, 8)"),
    ]
    for given, message in bad:
        with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
            write_video(tmp_path / "bad.mp4", iter(given), 24.0)
    with pytest.raises(RuntimeError, match="reconstruction failed"):
        write_video(tmp_path / "bad.mp4", failing(), 24.0)
    with pytest.raises(InputError, match="fps must lie in"):
        write_video(tmp_path / "bad.mp4", frames(), 0.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.mp4"]


def test_tfi_at_a_stride_computes_only_the_kept_frames(
    capsys, recording: Path, tmp_path: Path, monkeypatch
) -> None:
    """TFI's one block held every frame of its range as float32 whatever --stride (5 bytes a pixel a frame:
    3000 frames of 250 × 400 at --stride 30 peaked at 1.5 GB); it now computes only the frames it keeps."""
    import spikenerf.camera.reconstruct as rec

    real, made = rec.tfi, []

    def counted(*args, **kwargs):  # type: ignore[no-untyped-def]
        out = real(*args, **kwargs)
        made.append(len(out))
        return out

    monkeypatch.setattr(rec, "tfi", counted)
    base = ["reconstruct", recording, "--method", "tfi", "--frames", "10:290"]
    code, _, err = run_cli(capsys, *base, "--stride", 40, "--out", tmp_path / "v.mp4")
    assert code == 0, err
    assert made == [len(range(10, 290, 40))]
    assert run_cli(capsys, *base, "--stride", 40, "--out", tmp_path / "k.npy")[0] == 0
    np.testing.assert_allclose(
        np.load(tmp_path / "k.npy"), real(_moving_stream(H, W, T))[10:290:40], atol=1e-6
    )
    with pytest.raises(InputError, match="step must be an integer") as err_info:
        rec.reconstruct_frames(lambda a, b: np.zeros((b - a, 2, 2)), 9, 0, 9, "tfi", step=0)
    assert err_info.value.params == ("step",)


def test_tfi_refuses_a_range_that_does_not_fit_in_memory_in_one_line(
    capsys, recording: Path, tmp_path: Path, monkeypatch
) -> None:
    """TFI reads its whole range at once: a range beyond the memory was killed by the system mid-work."""
    import spikenerf.core.limits as limits

    monkeypatch.delenv(limits.NO_LIMITS_ENV, raising=False)
    # every frame: H·W·(300 read + 300 kept · 4) = 1.5 MB; one in 50: H·W·(300 + 6 · 4) = 0.33 MB
    monkeypatch.setattr(limits, "available_memory", lambda: 800_000)
    out = tmp_path / "out" / "v.mp4"
    code, _, err = run_cli(capsys, "reconstruct", recording, "--method", "tfi", "--out", out)
    assert code == 2 and err.strip().count("\n") == 0, err
    assert "--frames/--stride: this needs about 1.46 MiB of memory" in err and "--no-limits" in err, err
    assert not out.parent.exists()
    code, _, err = run_cli(capsys, "reconstruct", recording, "--method", "tfi", "--stride", 50, "--out", out)
    assert code == 0 and len(_decode(out)[0]) == 6, err

"""``spikenerf info`` and ``spikenerf reconstruct`` on .dat files: outputs, and exit code 2 on bad input."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from helpers import run_cli
from spikenerf.camera.io import read_dat, write_dat
from spikenerf.camera.reconstruct import tfi, tfp
from spikenerf.core.color import srgb_encode

H, W, T = 8, 12, 120


@pytest.fixture
def stream(tmp_path: Path) -> tuple[Path, np.ndarray]:
    """A 120-frame 8×12 stream: a horizontal intensity ramp, random phases, one column never fires."""
    rng = np.random.default_rng(0)
    intensity = np.tile(np.linspace(0.0, 1.0, W), (H, 1))
    acc = rng.uniform(0, 1, (H, W)) * (intensity > 0)
    frames = []
    for _ in range(T):
        acc = acc + intensity
        spikes = acc >= 1.0
        acc = acc - spikes
        frames.append(spikes)
    spikes = np.stack(frames).astype(np.uint8)
    path = tmp_path / "s.dat"
    write_dat(path, spikes)
    return path, spikes


def test_info_dat_prints_counts_and_rates(capsys, stream) -> None:
    path, spikes = stream
    code, out, _ = run_cli(capsys, "info", path, "--height", H, "--width", W)
    assert code == 0
    assert "frames: 120" in out and "duration: 3 ms at 40000 Hz" in out
    rate = spikes.mean()
    assert f"mean spike rate: {rate:.4g} spikes/pixel/step" in out
    median = np.median(spikes.mean(axis=0))
    assert f"p50 {median:.4g}" in out
    assert f"silent pixels: {100 / W:.3g}%" in out  # the first column (intensity 0)
    saturated = np.mean(spikes.sum(axis=0) == len(spikes)) * 100
    assert f"saturated (a spike every step): {saturated:.3g}%" in out


def test_info_needs_the_frame_size(capsys, stream) -> None:
    code, _, err = run_cli(capsys, "info", stream[0], "--height", H)
    assert code == 2
    assert err.strip().count("\n") == 0 and "--width" in err and "s.dat" in err


def test_info_on_a_folder_that_is_not_a_dataset_exits_2(capsys, tmp_path: Path) -> None:
    code, _, err = run_cli(capsys, "info", tmp_path)
    assert code == 2 and err.strip().count("\n") == 0
    assert "not a dataset folder" in err and tmp_path.name in err
    from spikenerf.core.marker import mark

    bench = tmp_path / "bench"
    bench.mkdir()
    mark(bench, "benchmark")  # a folder of ours that info does not summarise: what to read instead
    code, _, err = run_cli(capsys, "info", bench)
    assert code == 2 and "a benchmark folder: its tables are table1.md, table2.md and report.html" in err
    (tmp_path / "ds.partial").mkdir()  # an unfinished simulate: not "no such file"
    code, _, err = run_cli(capsys, "info", tmp_path / "ds")
    assert code == 2 and f"not written yet: {tmp_path / 'ds.partial'} is its unfinished work folder" in err


def test_info_on_a_folder_refuses_the_options_of_a_dat_file(capsys, tmp_path: Path) -> None:
    """A folder's sizes, rate and layout come from its own files: a .dat option given with one is an error,
    not silently ignored."""
    for option in (["--fps", "20000"], ["--layout", "topdown"], ["--height", "8"], ["--raw-width", "16"]):
        code, _, err = run_cli(capsys, "info", tmp_path, *option)
        assert code == 2 and err.strip().count("\n") == 0
        assert f"{option[0]}: for a .dat file only" in err and tmp_path.name in err


def test_reconstruct_png_is_srgb_of_tfp(capsys, stream, tmp_path: Path) -> None:
    path, spikes = stream
    out = tmp_path / "f.png"
    code, _, _ = run_cli(capsys, "reconstruct", path, "--height", H, "--width", W, "--method", "tfp",
                         "--window", 21, "--frame", 60, "--out", out)  # fmt: skip
    assert code == 0
    expect = np.round(srgb_encode(tfp(spikes, 21)[60].astype(np.float64)) * 255).astype(np.uint8)
    image = iio.imread(out)
    assert image.dtype == np.uint8 and image.shape == (H, W)
    np.testing.assert_array_equal(image, expect)
    assert image[:, 0].max() == 0 and image[:, -1].min() == 255


@pytest.mark.parametrize("method", ["tfp", "tfi"])
def test_reconstruct_npy_frame_and_range(capsys, stream, tmp_path: Path, method: str) -> None:
    path, spikes = stream
    full = tfp(spikes, 41) if method == "tfp" else tfi(spikes)
    base = ["reconstruct", path, "--height", H, "--width", W, "--method", method]
    assert run_cli(capsys, *base, "--frame", 7, "--out", tmp_path / "one.npy")[0] == 0
    one = np.load(tmp_path / "one.npy")
    assert one.shape == (H, W) and one.dtype == np.float32
    np.testing.assert_array_equal(one, full[7])
    assert run_cli(capsys, *base, "--frames", "10:110", "--out", tmp_path / "r.npy")[0] == 0
    np.testing.assert_array_equal(np.load(tmp_path / "r.npy"), full[10:110])


def test_reconstruct_dir_and_topdown(capsys, stream, tmp_path: Path) -> None:
    _, spikes = stream
    topdown = tmp_path / "td.dat"
    write_dat(topdown, spikes, layout="topdown")
    out = tmp_path / "frames"
    args = ["reconstruct", topdown, "--height", H, "--width", W, "--method", "tfp", "--layout", "topdown"]
    assert run_cli(capsys, *args, "--frames", "5:9", "--out", out)[0] == 0
    frames = ["00005.png", "00006.png", "00007.png", "00008.png"]
    assert sorted(p.name for p in out.iterdir()) == [".spikenerf", *frames]
    expect = np.round(srgb_encode(tfp(spikes, 41)[8].astype(np.float64)) * 255).astype(np.uint8)
    np.testing.assert_array_equal(iio.imread(out / "00008.png"), expect)
    (out / "notes.txt").write_text("mine")  # the frames it wrote before are replaced; the user's file stays
    assert run_cli(capsys, *args, "--frames", "0:2", "--out", out)[0] == 0
    assert sorted(p.name for p in out.iterdir()) == [".spikenerf", "00000.png", "00001.png", "notes.txt"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--window", "40"], "odd"),
        (["--window", "121"], "--window 121 is longer than the 120-frame stream"),
        (["--frame", "120"], "--frame: frame 120 is outside the 120-frame stream"),
        (["--frames", "100:130"], "--frames: frame range 100:130 is empty or outside the 120-frame stream"),
        (["--frames", "1-3"], "A:B"),
        (["--frame", "1", "--frames", "1:3"], "not both"),
        (["--method", "tfi", "--window", "41"], "--window applies to --method tfp and learned"),
        (["--method", "tfp", "--color", "bayer"], "--color applies to --method learned only"),
        (["--method", "tfi", "--weights", "w.pt"], "--weights applies to --method learned only (tfi has no"),
        (["--threshold", "0"], "threshold"),
        (["--frames", "1:3", "--out-png"], "one frame"),
        (["--frame", "1", "--out-jpg"], ".png, .npy or .mp4"),
    ],
)
def test_reconstruct_bad_input_exits_2_and_writes_nothing(capsys, stream, tmp_path, extra, message) -> None:
    path, _ = stream
    out = tmp_path / "out" / "o.npy"
    if "--out-png" in extra or "--out-jpg" in extra:
        out = out.with_suffix(".png" if "--out-png" in extra else ".jpg")
        extra = [e for e in extra if not e.startswith("--out-")]
    method = [] if "--method" in extra else ["--method", "tfp"]
    code, _, err = run_cli(
        capsys, "reconstruct", path, "--height", H, "--width", W, *method, *extra, "--out", out
    )
    assert code == 2
    assert message in err and err.strip().count("\n") == 0
    assert not out.exists() and not (out.parent.exists() and any(out.parent.iterdir()))


def test_a_stream_shorter_than_the_learned_window_is_named(capsys, stream, tmp_path: Path) -> None:
    _, spikes = stream
    short = tmp_path / "short.dat"
    write_dat(short, spikes[:20])
    code, _, err = run_cli(capsys, "reconstruct", short, "--height", H, "--width", W, "--method", "learned",
                           "--frame", 3, "--out", tmp_path / "l.npy")  # fmt: skip
    assert code == 2 and err.startswith(f"spikenerf: error: {short}: the learned reconstructor's window of")
    assert not (tmp_path / "l.npy").exists()


def test_reconstruct_truncated_file_and_refused_folder(capsys, stream, tmp_path: Path) -> None:
    path, _ = stream
    truncated = tmp_path / "t.dat"
    truncated.write_bytes(path.read_bytes()[:-5])
    base = ["--height", H, "--width", W, "--method", "tfp", "--frame", 0]
    code, _, err = run_cli(capsys, "reconstruct", truncated, *base, "--out", tmp_path / "x.npy")
    assert code == 2 and "remainder of 7 bytes" in err and "t.dat" in err
    assert not (tmp_path / "x.npy").exists()
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("keep me")
    code, _, err = run_cli(capsys, "reconstruct", path, *base[:-2], "--frames", "0:2", "--out", busy)
    assert code == 2 and "refusing" in err
    assert (busy / "notes.txt").read_text() == "keep me"
    code, _, err = run_cli(
        capsys, "reconstruct", tmp_path / "missing.dat", *base, "--out", tmp_path / "y.png"
    )
    assert code == 2 and "not found" in err


def test_reconstruct_reads_only_the_needed_frames(capsys, stream, tmp_path: Path, monkeypatch) -> None:
    path, spikes = stream
    calls = []
    import spikenerf.camera.io as io

    real = io.read_dat

    def spy(*args, **kwargs):
        calls.append(args[3])
        return real(*args, **kwargs)

    monkeypatch.setattr(io, "read_dat", spy)
    args = ["--height", H, "--width", W, "--method", "tfp", "--window", 11, "--frame", 50]
    assert run_cli(capsys, "reconstruct", path, *args, "--out", tmp_path / "a.npy")[0] == 0
    assert calls == [slice(45, 56)]
    np.testing.assert_array_equal(read_dat(path, H, W), spikes)


def test_threads_option_sets_torch_and_child_processes(capsys, stream, monkeypatch) -> None:
    import os

    import torch

    monkeypatch.setenv("OMP_NUM_THREADS", "")
    before = torch.get_num_threads()
    try:
        code, _, _ = run_cli(capsys, "--threads", "1", "info", stream[0], "--height", H, "--width", W)
        assert code == 0 and os.environ["OMP_NUM_THREADS"] == "1" and torch.get_num_threads() == 1
        code, _, err = run_cli(capsys, "--threads", "0", "info", stream[0])
        assert code == 2 and "--threads" in err
    finally:
        torch.set_num_threads(before)


def test_info_and_reconstruct_read_the_size_from_a_spikecv_config(capsys, stream, tmp_path: Path) -> None:
    path, spikes = stream
    (path.parent / "config.yaml").write_text(f"filename: s\nspike_h: {H}\nspike_w: {W}\nis_labeled: false\n")
    code, out, _ = run_cli(capsys, "info", path)
    assert code == 0 and f"frame: {W}×{H} pixels (width × height)" in out and "frames: 120" in out
    out_png = tmp_path / "lin.png"
    code, _, _ = run_cli(capsys, "reconstruct", path, "--method", "tfp", "--frame", 60,
                         "--encoding", "linear", "--out", out_png)  # fmt: skip
    assert code == 0  # linear PNG: round(255 · Î), SpikeCV's convention (no gamma)
    np.testing.assert_array_equal(iio.imread(out_png), np.round(tfp(spikes, 41)[60] * 255).astype(np.uint8))
    out_npy = tmp_path / "s.npy"
    code, _, _ = run_cli(capsys, "reconstruct", path, "--method", "tfp", "--frame", 60,
                         "--encoding", "srgb", "--out", out_npy)  # fmt: skip
    assert code == 0
    np.testing.assert_allclose(
        np.load(out_npy), srgb_encode(tfp(spikes, 41)[60].astype(np.float64)), atol=1e-6
    )
    (path.parent / "config.yaml").write_text("spike_h: 0\nspike_w: 12\n")
    code, _, err = run_cli(capsys, "info", path)
    assert code == 2 and "spike_h" in err and err.strip().count("\n") == 0


def test_a_frame_size_flag_that_differs_from_the_config_beside_the_file_is_named(capsys, stream) -> None:
    path, _ = stream
    (path.parent / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\n")
    code, out, err = run_cli(capsys, "info", path, "--width", H, "--height", W)  # swapped (H ≠ W)
    assert code == 0 and f"frame: {H}×{W} pixels" in out  # the flags win (width {H}, height {W})
    config = path.parent / "config.yaml"
    assert err.splitlines() == [
        f"spikenerf: warning: {path}: --width {H} differs from spike_w {W} in {config}; using --width {H}",
        f"spikenerf: warning: {path}: --height {W} differs from spike_h {H} in {config}; using --height {W}",
    ]
    (path.parent / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\nfps: 20000\n")
    code, out, err = run_cli(capsys, "info", path, "--fps", 1000)
    assert code == 0 and "duration: 120 ms at 1000 Hz" in out
    assert (
        err.strip()
        == f"spikenerf: warning: {path}: --fps 1000 differs from fps 20000 in {config}; using --fps 1000"
    )
    code, _, err = run_cli(capsys, "info", path, "--width", W, "--height", H)  # agreeing flags: no word
    assert code == 0 and err == ""
    out = path.parent / "r.png"  # reconstruct writes what it reads: refused, as import refuses it
    code, _, err = run_cli(capsys, "reconstruct", path, "--width", H, "--height", W, "--method", "tfp",
                           "--frame", 3, "--out", out)  # fmt: skip
    assert code == 2 and f"--width {H} differs from spike_w {W} in {config}, which describes" in err
    assert not out.exists()


def test_reconstruct_takes_the_recordings_threshold_unless_given(capsys, stream, tmp_path: Path) -> None:
    path, spikes = stream
    (path.parent / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\nthreshold: 2.0\n")
    for extra, phi in (((), 2.0), (("--threshold", "0.5"), 0.5)):
        out = tmp_path / f"phi{phi}.npy"
        code, _, _ = run_cli(capsys, "reconstruct", path, "--method=tfp", "--frame=60", "--out", out, *extra)
        assert code == 0
        np.testing.assert_allclose(np.load(out), tfp(spikes, 41, phi)[60], rtol=1e-6)


def test_reconstruct_refuses_its_own_input_and_a_threshold_float32_cannot_hold(
    capsys, stream, tmp_path: Path
) -> None:
    path, _ = stream
    copy = tmp_path / "recording"  # (no suffix: read as .dat; as --out, a folder)
    copy.write_bytes(path.read_bytes())
    before = copy.read_bytes()
    code, _, err = run_cli(capsys, "reconstruct", copy, "--height", H, "--width", W, "--method", "tfp",
                           "--frames", "0:3", "--out", copy, "--overwrite")  # fmt: skip
    assert code == 2 and "spike recording being read" in err and copy.read_bytes() == before
    for phi in ("1e39", "1e-50"):
        code, _, err = run_cli(capsys, "reconstruct", path, "--height", H, "--width", W, "--method", "tfp",
                               "--frame", 3, "--threshold", phi, "--out", tmp_path / "x.npy")  # fmt: skip
        assert code == 2 and "float32" in err and err.strip().count("\n") == 0
    assert not (tmp_path / "x.npy").exists()


def test_a_config_raw_width_narrower_than_the_image_names_the_config(capsys, stream) -> None:
    path, _ = stream
    (path.parent / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\nraw_width: 8\n")
    code, _, err = run_cli(capsys, "info", path)
    assert code == 2 and "config.yaml: field 'raw_width': expected ≥ spike_w 12, found 8" in err


def test_a_file_that_also_reads_as_raw_rows_with_silent_padding_is_named(capsys, tmp_path: Path) -> None:
    """25 raw frames of 10×(16 + 16 padding) columns are also 50 plain 10×16 frames: info and reconstruct
    warn, import asks which; a plain stream (its 'padding' fires) passes without a word."""
    rng = np.random.default_rng(0)
    raw = np.zeros((25, 10, 32), np.uint8)
    raw[:, :, :16] = rng.random((25, 10, 16)) < 0.3
    write_dat(tmp_path / "raw.dat", raw)
    code, _, err = run_cli(capsys, "info", tmp_path / "raw.dat", "--height", 10, "--width", 16)
    assert code == 0 and "warning" in err and "pass --raw-width 32" in err
    code, _, err = run_cli(capsys, "import", tmp_path / "raw.dat", "--height", 10, "--width", 16, "--poses",
                           "orbit", "--orbit", "4,30", "--fov", 40, "--out", tmp_path / "ds")  # fmt: skip
    assert code == 2 and "pass --raw-width 32 for a raw recording, or 16 for plain frames" in err
    assert not (tmp_path / "ds").exists()
    code, out, err = run_cli(capsys, "info", tmp_path / "raw.dat", "--height", 10, "--width", 16,
                             "--raw-width", 32)  # fmt: skip
    assert code == 0 and err == "" and "frames: 25" in out
    write_dat(tmp_path / "plain.dat", (rng.random((50, 10, 16)) < 0.3).astype(np.uint8))
    code, _, err = run_cli(capsys, "info", tmp_path / "plain.dat", "--height", 10, "--width", 16)
    assert code == 0 and err == ""


def test_info_and_reconstruct_refuse_a_file_that_is_not_a_recording(capsys, tmp_path: Path) -> None:
    (tmp_path / "config.yaml").write_text(f"spike_h: {H}\nspike_w: {W}\n")
    for argv in (["info"], ["reconstruct", "--method", "tfp", "--out", tmp_path / "x.npy"]):
        code, _, err = run_cli(capsys, *argv[:1], tmp_path / "config.yaml", *argv[1:])
        assert code == 2 and "is a .yaml file, not a .dat spike recording" in err
    for name in ("cloud.ply", "orbit.mp4"):  # what export and render write, beside a config.yaml
        (tmp_path / name).write_bytes(bytes(H * W))  # (whole frames' worth of bytes: it would read)
        code, _, err = run_cli(capsys, "info", tmp_path / name)
        suffix = name.split(".")[1]
        assert code == 2 and f"{name}: is a .{suffix} file, not a .dat spike recording" in err, err
    (tmp_path / "empty.dat").write_bytes(b"")  # a recording that was never written
    for argv in (["info"], ["reconstruct", "--method", "tfp", "--out", tmp_path / "y.npy"]):
        code, _, err = run_cli(
            capsys, *argv[:1], tmp_path / "empty.dat", "--height", H, "--width", W, *argv[1:]
        )
        assert code == 2 and len(err.strip().splitlines()) == 1 and "holds no frames" in err
        assert not (tmp_path / "y.npy").exists()


def test_a_frame_folder_reused_says_which_frames_it_replaced(capsys, stream, tmp_path: Path) -> None:
    path, _ = stream
    base = ["reconstruct", path, "--height", H, "--width", W, "--method", "tfp", "--out", tmp_path / "f"]
    assert run_cli(capsys, *base, "--frames", "0:3")[0] == 0
    code, out, _ = run_cli(capsys, *base, "--frames", "3:5")
    assert code == 0 and sorted(p.name for p in (tmp_path / "f").glob("*.png")) == ["00003.png", "00004.png"]
    folder = tmp_path / "f"
    assert out.splitlines()[0] == (
        f"removed 3 frames of an earlier reconstruct into {folder} (a frame folder holds one call's frames)"
    )

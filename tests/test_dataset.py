"""The dataset folder: 16-bit PNG codec, writer → loader round trip, and validation of bad folders."""

from __future__ import annotations

import json
import shutil
import struct
import zlib
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import yaml

from spikenerf.camera.io import read_dat
from spikenerf.core.color import srgb_encode
from spikenerf.core.errors import InputError
from spikenerf.core.png16 import decode_png16, encode_png16
from spikenerf.data.camera_path import read_pose_file
from spikenerf.data.dataset import (
    load_dataset,
    load_image,
    near_far,
    read_display,
    write_image,
)
from spikenerf.data.writer import DatasetWriter
from spikenerf.scenes.trajectory import Intrinsics, novel_views, orbit

H, W, T = 8, 12, 30


# ------------------------------------------------------------------------------------------------- PNG
def test_png16_round_trip_is_exact() -> None:
    rng = np.random.default_rng(0)
    q = rng.integers(0, 65536, size=(9, 13, 3)).astype(np.uint16)
    q[0, 0], q[-1, -1] = 0, 65535
    out = decode_png16(encode_png16(q / 65535.0), Path("x.png"))
    assert out.dtype == np.uint16 and out.shape == (9, 13, 3)
    np.testing.assert_array_equal(out, q)


def test_linear_image_round_trip_to_one_65535th(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    linear = rng.random((7, 5, 3)).astype(np.float32)
    linear[0, 0] = [0.0, 1.0, 2.5]  # above 1 is clipped
    write_image(tmp_path / "a.png", linear)
    back = load_image(tmp_path / "a.png")
    assert back.dtype == np.float32 and back.shape == (7, 5, 3)
    want = srgb_encode(np.clip(linear.astype(np.float64), 0, 1))
    assert np.abs(read_display(tmp_path / "a.png") - want).max() <= 0.5 / 65535 + 1e-12
    assert np.abs(srgb_encode(back.astype(np.float64)) - want).max() <= 0.5 / 65535 + 1e-6
    assert back[0, 0, 2] == pytest.approx(1.0)


def _paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def test_png16_decoder_handles_every_row_filter() -> None:
    """Rows filtered with None, Sub, Up, Average, Paeth (as other tools write them) decode exactly."""
    rng = np.random.default_rng(2)
    q = rng.integers(0, 65536, size=(10, 6, 3)).astype(np.uint16)
    rows = q.astype(">u2").reshape(10, -1).view(np.uint8).astype(int)
    bpp, out = 6, bytearray()
    for y in range(10):
        ftype = y % 5
        out.append(ftype)
        for x in range(rows.shape[1]):
            a = rows[y, x - bpp] if x >= bpp else 0
            b = rows[y - 1, x] if y else 0
            c = rows[y - 1, x - bpp] if y and x >= bpp else 0
            pred = [0, a, b, (a + b) // 2, _paeth(a, b, c)][ftype]
            out.append((rows[y, x] - pred) % 256)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    png = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", 6, 10, 16, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(bytes(out)))
        + chunk(b"IEND", b"")
    )
    np.testing.assert_array_equal(decode_png16(png, Path("f.png")), q)


def test_8bit_png_and_corrupt_png(tmp_path: Path) -> None:
    img = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)
    iio.imwrite(tmp_path / "8.png", img)
    np.testing.assert_allclose(read_display(tmp_path / "8.png"), img / 255.0)
    (tmp_path / "bad.png").write_bytes(encode_png16(np.zeros((3, 3, 3)))[:40])
    with pytest.raises(InputError, match=r"bad.png"):
        load_image(tmp_path / "bad.png")


# ------------------------------------------------------------------------------------------ round trip
def _write(root: Path, modes: tuple[str, ...] = ("gray", "rgb", "bayer")) -> dict:
    """A small synthetic dataset written with DatasetWriter; returns what was written."""
    rng = np.random.default_rng(3)
    k = Intrinsics.from_fov(W, H, 0.7)
    traj = orbit(4.0, 30.0, duration=T / 40000.0)
    box = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    near, far = near_far(traj.poses, box)
    writer = DatasetWriter(root, k, traj.fps, box, near, far)
    spikes = {m: rng.random((T, 3, H, W) if m == "rgb" else (T, H, W)) < 0.3 for m in modes}
    writer.start_spikes(list(modes))
    for m in modes:
        for a in range(0, T, 7):  # appended in chunks, as the pipeline does
            writer.append_spikes(m, spikes[m][a : a + 7])
    gt = {s: rng.random((H, W, 3)).astype(np.float32) for s in range(0, T, 10)}
    for s, img in gt.items():
        writer.add_gt(s, img)
    blur = [rng.random((H, W, 3)).astype(np.float32) for _ in range(3)]
    for i, img in enumerate(blur):
        writer.add_blur(img, traj.poses[i * 10 + 5], i * 10, i * 10 + 10)
    test_poses = novel_views(4.0, 2)
    test = [rng.random((H, W, 3)).astype(np.float32) for _ in range(2)]
    for pose, img in zip(test_poses, test, strict=True):
        writer.add_test(img, pose)
    config = {"spike_h": H, "spike_w": W, "fps": 40000.0, "threshold": 1.5, "colors": list(modes), "seed": 4}
    writer.finish(traj, config, blur_fps=400.0)
    return {"k": k, "traj": traj, "box": box, "near": near, "far": far, "spikes": spikes, "gt": gt,
            "blur": blur, "test_poses": test_poses, "test": test, "config": config}  # fmt: skip


def test_dataset_round_trip(tmp_path: Path) -> None:
    want = _write(tmp_path / "ds")
    ds = load_dataset(tmp_path / "ds")
    assert ds.intrinsics == want["k"]
    np.testing.assert_array_equal(ds.trajectory.poses, want["traj"].poses)
    np.testing.assert_array_equal(ds.trajectory.times, want["traj"].times)
    np.testing.assert_array_equal(ds.trajectory.steps, want["traj"].steps)
    assert ds.trajectory.fps == 40000.0 and ds.threshold == 1.5
    np.testing.assert_array_equal(ds.scene_box, want["box"])
    assert (ds.near, ds.far) == (want["near"], want["far"])
    assert ds.config == want["config"] and ds.modes == ["gray", "rgb", "bayer"]
    for mode, spikes in want["spikes"].items():
        got = ds.spikes(mode)
        assert got.dtype == np.uint8 and got.shape == spikes.shape
        np.testing.assert_array_equal(got, spikes)
    np.testing.assert_array_equal(ds.spikes("gray", slice(5, 9)), want["spikes"]["gray"][5:9])
    assert ds.gt.images.dtype == np.float32 and ds.gt.poses.dtype == np.float32
    np.testing.assert_array_equal(ds.gt.steps, [0, 10, 20])
    np.testing.assert_allclose(ds.gt.images, np.stack(list(want["gt"].values())), atol=3e-5)
    np.testing.assert_allclose(ds.gt.poses, want["traj"].poses[[0, 10, 20]].astype(np.float32))
    assert ds.blur is not None and len(ds.blur) == 3 and ds.blur.steps is None
    np.testing.assert_array_equal(ds.blur.step_ranges, [[0, 10], [10, 20], [20, 30]])
    np.testing.assert_allclose(ds.blur.images, np.stack(want["blur"]), atol=3e-5)
    np.testing.assert_allclose(ds.blur.poses, want["traj"].poses[[5, 15, 25]].astype(np.float32))
    np.testing.assert_allclose(ds.test.images, np.stack(want["test"]), atol=3e-5)
    np.testing.assert_allclose(ds.test.poses, want["test_poses"].astype(np.float32))
    frames = json.loads((tmp_path / "ds" / "transforms.json").read_text())["frames"]
    assert [f.get("file_path") for f in frames[:11]] == ["gt/00000.png", *[None] * 9, "gt/00010.png"]
    np.testing.assert_array_equal(
        read_dat(tmp_path / "ds" / "spikes_rgb_g.dat", H, W), want["spikes"]["rgb"][:, 1]
    )


def test_read_pose_file(tmp_path: Path) -> None:
    _write(tmp_path / "ds", modes=("gray",))
    poses = read_pose_file(tmp_path / "ds" / "transforms_test.json", (16, 16))
    np.testing.assert_allclose(poses, novel_views(4.0, 2))


# ------------------------------------------------------------------------------------------ validation
def _edit_json(path: Path, fn) -> None:
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    _write(tmp_path / "ds", modes=("gray", "rgb"))
    return tmp_path / "ds"


def _set(key, value):
    return lambda d: d.__setitem__(key, value)


def _frame(i, key, value):
    return lambda d: d["frames"][i].__setitem__(key, value)


@pytest.mark.parametrize(
    ("name", "edit", "message"),
    [
        ("transforms.json", _set("fps", "fast"), "'fps'"),
        ("transforms.json", lambda d: d.pop("near"), "missing field 'near'"),
        ("transforms.json", _set("scene_box", [[0, 0, 0]]), "scene_box"),
        ("transforms.json", _frame(3, "transform_matrix", [[float("nan")] * 4] * 4), r"frames\[3\].*NaN"),
        ("transforms.json", _frame(2, "transform_matrix", [[1, 0, 0], [0, 1, 0]]), r"frames\[2\].*4×4"),
        ("transforms.json", _frame(0, "file_path", "../../etc/passwd"), "escapes the dataset folder"),
        ("transforms.json", _frame(0, "file_path", "/etc/passwd"), "escapes the dataset folder"),
        ("transforms.json", _frame(0, "file_path", "gt/missing.png"), "not found"),
        ("transforms.json", _frame(5, "step", 2), r"frames\[5\].*'step'"),
        ("transforms_test.json", _frame(1, "file_path", "../outside.png"), "escapes"),
        ("transforms_blur.json", _frame(0, "step_end", 0), "step_start/step_end"),
    ],
)
def test_bad_json_fields_name_file_and_field(folder: Path, name: str, edit, message: str) -> None:
    _edit_json(folder / name, edit)
    with pytest.raises(InputError, match=message) as err:
        load_dataset(folder)
    assert name in str(err.value)


def test_malformed_or_missing_files(folder: Path) -> None:
    text = (folder / "transforms.json").read_text()
    (folder / "transforms.json").write_text(text[:-20])
    with pytest.raises(InputError, match=r"transforms.json: malformed JSON"):
        load_dataset(folder)
    (folder / "transforms.json").unlink()
    with pytest.raises(InputError, match=r"transforms.json: missing file"):
        load_dataset(folder)
    with pytest.raises(InputError, match=r"not found"):
        load_dataset(folder / "nope")


def test_spike_file_size_mismatch(folder: Path) -> None:
    path = folder / "spikes_rgb_b.dat"
    path.write_bytes(path.read_bytes()[: -H * W // 8])  # one frame short
    with pytest.raises(InputError, match=r"spikes_rgb_b.dat: holds 29 steps but transforms.json has 30"):
        load_dataset(folder)
    path.write_bytes(path.read_bytes()[:-1])  # not a whole number of frames
    with pytest.raises(InputError, match=r"spikes_rgb_b.dat"):
        load_dataset(folder)
    path.unlink()
    with pytest.raises(InputError, match=r"spikes_rgb_b.dat"):
        load_dataset(folder)


def test_inconsistent_image_size(folder: Path) -> None:
    write_image(folder / "gt" / "00010.png", np.zeros((H + 1, W, 3)))
    with pytest.raises(InputError, match=r"gt/00010.png: image is 9×12 \(H×W\), expected 8×12"):
        load_dataset(folder)


def test_config_mismatch_and_bad_mode(folder: Path) -> None:
    cfg = yaml.safe_load((folder / "config.yaml").read_text())
    (folder / "config.yaml").write_text(yaml.safe_dump({**cfg, "spike_h": 99}))
    with pytest.raises(InputError, match=r"config.yaml: field 'spike_h' is 99, but transforms.json says 8"):
        load_dataset(folder)
    (folder / "config.yaml").write_text(yaml.safe_dump({**cfg, "colors": ["grey"]}))
    with pytest.raises(InputError, match=r"config.yaml: field 'colors'"):
        load_dataset(folder)
    (folder / "config.yaml").write_text("spike_h: [")
    with pytest.raises(InputError, match=r"config.yaml: malformed YAML"):
        load_dataset(folder)


def test_optional_side_files(folder: Path) -> None:
    (folder / "transforms_blur.json").unlink()
    shutil.rmtree(folder / "blur")
    ds = load_dataset(folder)
    assert ds.blur is None and len(ds.test) == 2
    with pytest.raises(InputError, match=r"'bayer' is not in this dataset"):
        ds.spikes("bayer")


def test_an_unfinished_simulate_work_folder_is_named_as_such(tmp_path: Path) -> None:
    """``train``/``eval`` (load_dataset) and ``info`` (describe) say that OUT.partial is unfinished work to
    resume, not that a file is missing."""
    from spikenerf.data.summary import describe

    work = tmp_path / "ds.partial"
    (work / ".frames").mkdir(parents=True)
    for read in (load_dataset, describe):
        with pytest.raises(InputError, match="unfinished `spikenerf simulate` or `import` work") as err:
            read(work)
        assert err.value.path == str(work)


def test_info_of_a_dataset_it_cannot_write_to_still_summarises_it(
    folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A dataset on read-only media (a share, another user's folder): ``describe`` gives its summary and says
    that the preview was not written, instead of failing on the preview's temporary file."""
    from spikenerf.data import summary

    def refuse(path: Path, data: bytes) -> None:
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(summary, "write_bytes_atomic", refuse)
    lines = summary.describe(folder).splitlines()
    assert lines[-1] == f"preview: not written, {folder} is not writable (Permission denied)"
    assert any(line.startswith("spikes [gray]") for line in lines)
    assert not (folder / summary.PREVIEW).exists()

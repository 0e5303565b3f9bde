"""Property-based tests of the input readers: a mutated valid file (cut, flipped bytes, a JSON/YAML value of
another type, a deleted key, a wrong .npy array) is read, or refused with one InputError line naming it;
never another exception, a traceback or a multi-line message. Plus the regression tests of what they found.

The valid inputs come from the package's own writers: a 16×16 dataset of 40 steps (``simulate``) and a run
of 5 iterations (``train``), built once for the module."""

from __future__ import annotations

import io
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fuzz_helpers import byte_edit, check_refusal, json_edit, tree_edit, yaml_edit
from spikenerf.camera.io import read_dat
from spikenerf.camera.spikecv import read_spikecv_config, recording_config
from spikenerf.core.errors import InputError, is_finite
from spikenerf.core.yamlio import load_yaml
from spikenerf.data.camera_path import read_camera_path, read_pose_file
from spikenerf.data.dataset import load_dataset, read_display
from spikenerf.data.holdout import read_record
from spikenerf.eval.render_record import RECORD, read_render_record
from spikenerf.importing.poses import read_pose_source
from spikenerf.pipelines.benchmark.cells import read_cell
from spikenerf.pipelines.benchmark.results import read_call
from spikenerf.pipelines.benchmark.settings import (
    NAME,
    adopt_integral_defaults,
    check_settings,
    write_settings,
)
from spikenerf.recon.net import load_weights, shipped_weights
from spikenerf.recon.store import read_manifest
from spikenerf.scenes.image_io import read_image
from spikenerf.scenes.sequence_frames import load_sequence
from spikenerf.train.checkpoint import load_checkpoint
from spikenerf.train.config_file import apply_overrides, load_config
from spikenerf.train.evaluate import read_curves

FUZZ = settings(
    max_examples=12, derandomize=True, deadline=None, database=None, suppress_health_check=list(HealthCheck)
)
#: a JSON array nested beyond the parser's stack, and a number beyond a float (JSON allows both)
DEEP_JSON = "[" * 100_000 + "]" * 100_000
HUGE = "1" + "0" * 400


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny dataset (all colour modes, blur frames, a raw recording) and a 5-iteration run of it."""
    from spikenerf.cli import main

    base = tmp_path_factory.mktemp("fuzz")
    ds, run = base / "ds", base / "run"
    common = ["--threads", "1"]
    for args in (
        [
            "simulate",
            "--scene",
            "analytic-orbs",
            "--out",
            ds,
            "--width",
            16,
            "--height",
            16,
            "--frames",
            40,
            "--test-views",
            2,
            "--color",
            "all",
            "--blur-fps",
            4000,
            "--raw-width",
            24,
        ],
        ["train", ds, "--out", run, "--iters", 5, "--method", "nerf-gt", "--device", "cpu"],
    ):
        try:
            main([*common, *map(str, args)])
        except SystemExit as done:
            assert done.code in (0, None)
    return base


@pytest.fixture(scope="module")
def work(made: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of ``made`` that the tests mutate (each example restores what it changed), with the pose files
    of an import: an LLFF ``poses_bounds.npy`` and a COLMAP text model of the dataset's first poses."""
    base = tmp_path_factory.mktemp("work")
    shutil.copytree(made / "ds", base / "ds")
    shutil.copytree(made / "run", base / "run")
    frames = json.loads((base / "ds" / "transforms.json").read_text())["frames"]
    c2w = np.array([f["transform_matrix"] for f in frames])
    rot, hwf = c2w[:, :3, :4], np.tile(np.array([16.0, 16.0, 22.2])[None, :, None], (len(c2w), 1, 1))
    rows = np.concatenate([-rot[:, :, 1:2], rot[:, :, 0:1], rot[:, :, 2:4], hwf], 2).reshape(len(c2w), 15)
    np.save(base / "poses_bounds.npy", np.concatenate([rows, np.tile([[2.0, 6.0]], (len(c2w), 1))], 1))
    colmap = base / "colmap"
    colmap.mkdir()
    (colmap / "cameras.txt").write_text("# cameras\n1 PINHOLE 16 16 22.2 22.2 8 8\n")
    lines = ["# images"]
    for i, m in enumerate(c2w[:5]):
        w2c = np.linalg.inv(m @ np.diag([1.0, -1.0, -1.0, 1.0]))
        q = _quaternion(w2c[:3, :3])
        t = w2c[:3, 3]
        lines += [f"{i + 1} {q[0]} {q[1]} {q[2]} {q[3]} {t[0]} {t[1]} {t[2]} 1 {i * 10:05d}.png", "1.0 2.0 1"]
    (colmap / "images.txt").write_text("\n".join(lines) + "\n")
    (colmap / "points3D.txt").write_text("1 0.1 0.2 0.3 255 0 0 0.5 1 0\n2 -0.1 0.0 0.3 0 255 0 0.5 1 1\n")
    shutil.copy(shipped_weights(), base / "weights.pt")
    other = base / "other"
    other.mkdir()
    (other / "holdout.json").write_text(
        json.dumps({"check_steps": [3, 7], "step_numbers": [3, 7], "radius": 2})
    )
    (other / RECORD).write_text(
        json.dumps({"size": [16, 16], "files": {"video": "v.mp4", "spikes": ["s.dat"]}})
    )
    (other / "metrics.json").write_text(
        json.dumps({"mean": {"psnr": 20.0, "ssim": 0.5, "lpips": 0.3}, "seconds": 2})
    )
    (other / "manifest.json").write_text(json.dumps({"config": {"size": 16, "window": 8, "modes": ["gray"]}}))
    for path in (read_pose_source(base / "poses_bounds.npy"), read_pose_source(colmap)):
        assert len(path.poses) >= 5  # the fixtures are valid
    return base


def _quaternion(rot: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix (its trace is positive enough for the simple formula here)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return w, x, y, z


def _fuzz(path: Path, edit: Callable, read: Callable[[], object], *names: Path, examples: int = 12) -> None:
    """Write ``edit(valid bytes)`` examples over ``path`` (restored after each) and check ``read()``."""
    valid = path.read_bytes()

    @settings(FUZZ, max_examples=examples)
    @given(edit(valid))
    def case(data: bytes) -> None:
        path.write_bytes(data)
        try:
            check_refusal(read, *names)
        finally:
            path.write_bytes(valid)

    case()


# ------------------------------------------------------------------------------------------- properties
@pytest.mark.parametrize(
    "name, edit",
    [
        ("transforms.json", json_edit),
        ("transforms_test.json", json_edit),
        ("transforms_blur.json", json_edit),
        ("config.yaml", yaml_edit),
        ("gt/00010.png", byte_edit),
        ("spikes_rgb_g.dat", byte_edit),
    ],
)
def test_dataset_files(work: Path, name: str, edit: Callable) -> None:
    ds = work / "ds"
    _fuzz(ds / name, edit, lambda: load_dataset(ds), ds, examples=20)


def test_dat_and_spikecv_config(work: Path) -> None:
    ds = work / "ds"
    _fuzz(ds / "spikes_gray.dat", byte_edit, lambda: read_dat(ds / "spikes_gray.dat", 16, 16), ds)
    raw = ds / "raw"
    _fuzz(raw / "config.yaml", yaml_edit, lambda: recording_config(raw / "recording.dat"), raw, examples=25)


def test_pose_files(work: Path) -> None:
    ds = work / "ds"
    _fuzz(
        ds / "transforms.json", json_edit, lambda: read_pose_source(ds / "transforms.json"), ds, examples=20
    )
    test = ds / "transforms_test.json"
    _fuzz(test, json_edit, lambda: read_pose_file(test, (16, 16)), ds)
    _fuzz(test, json_edit, lambda: read_camera_path(test, (16, 16)), ds)
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        _fuzz(work / "colmap" / name, byte_edit, lambda: read_pose_source(work / "colmap"), work / "colmap")


@st.composite
def npy_edit(draw: st.DrawFn, valid: bytes) -> bytes:
    """A byte edit of a .npy file, or another array: wrong shape or dtype, or a NaN/inf/huge value."""
    if draw(st.booleans()):
        return draw(byte_edit(valid))
    shape = draw(st.sampled_from([(0, 17), (1, 17), (3, 17), (3, 16), (17,), (3, 17, 1), (), (2, 18)]))
    dtype = draw(st.sampled_from(["f8", "f4", "f2", "i8", "u1", "?", "c8", "U3", "O"]))
    arr = (
        np.load(io.BytesIO(valid))[: shape[0]]
        if shape[1:] == (17,) and dtype == "f8"
        else np.zeros(shape, dtype)
    )
    if arr.size and arr.dtype.kind == "f":
        arr.flat[draw(st.integers(0, arr.size - 1))] = draw(st.sampled_from([np.nan, -np.inf, 1e300, 0.0]))
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=True)
    return buf.getvalue()


def test_llff_poses(work: Path) -> None:
    path = work / "poses_bounds.npy"
    _fuzz(path, npy_edit, lambda: read_pose_source(path), path, examples=40)


def test_sequence(work: Path) -> None:
    ds = work / "ds"
    _fuzz(
        ds / "transforms_gt.json",
        json_edit,
        lambda: load_sequence(ds / "transforms_gt.json"),
        ds,
        examples=20,
    )
    _fuzz(ds / "gt" / "00010.png", byte_edit, lambda: load_sequence(ds / "transforms_gt.json"), ds)


def test_run_folder(work: Path) -> None:
    run = work / "run"
    _fuzz(run / "config.yaml", yaml_edit, lambda: load_config(run / "config.yaml"), run, examples=30)
    _fuzz(run / "curves.csv", byte_edit, lambda: read_curves(run / "curves.csv"), run)
    _fuzz(run / "checkpoint.pt", byte_edit, lambda: load_checkpoint(run / "checkpoint.pt"), run, examples=4)


@settings(FUZZ, max_examples=40)
@given(st.text(max_size=30) | st.sampled_from(["a=" + "[" * 5000, "spike.lam=" + "9" * 5000, "a.=1", "=1"]))
def test_set_overrides(item: str) -> None:
    """``--set KEY=VALUE``: applied, or one InputError line."""
    try:
        apply_overrides({"spike": {"lam": 1.0}}, [item])
    except InputError as err:
        assert "\n" not in str(err)


def test_small_json_records(work: Path) -> None:
    other = work / "other"
    _fuzz(other / "holdout.json", json_edit, lambda: read_record(other), other)
    _fuzz(other / RECORD, json_edit, lambda: read_render_record(other), other)
    _fuzz(other / "metrics.json", json_edit, lambda: read_cell(other, "s", "gray", "v"), other)
    _fuzz(other / "manifest.json", json_edit, lambda: read_manifest(other), other)


def test_recon_weights(work: Path) -> None:
    _fuzz(work / "weights.pt", byte_edit, lambda: load_weights(work / "weights.pt"), work, examples=8)


# ------------------------------------------------------------------------------------- regression tests
def _refused(read: Callable[[], object], name: Path, words: str) -> None:
    with pytest.raises(InputError) as err:
        read()
    assert str(name) in str(err.value) and words in str(err.value) and "\n" not in str(err.value)


def _edit_text(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def test_is_finite() -> None:
    assert is_finite(1) and is_finite(2.5) and is_finite(np.float32(1))
    assert not any(map(is_finite, [10**400, float("nan"), float("inf"), True, "1", None]))


@pytest.mark.parametrize("old", ['"fps": 40000.0', '"scene_box": [[-1.0'])
def test_dataset_number_beyond_a_float(made: Path, tmp_path: Path, old: str) -> None:
    """An integer beyond a float (``1e400`` written out) was an OverflowError out of math.isfinite/numpy."""
    ds = shutil.copytree(made / "ds", tmp_path / "ds")
    _edit_text(ds / "transforms.json", old, old.replace("40000.0", HUGE).replace("-1.0", "-" + HUGE))
    _refused(lambda: load_dataset(ds), ds / "transforms.json", "fps" if "fps" in old else "scene_box")


@pytest.mark.parametrize(
    "text, words",
    [
        (f"spike_h: {HUGE}\nspike_w: 16\n", "spike_h"),
        ("spike_h: 16\nspike_w: " + "[" * 5000, "nested too deeply"),
        ("spike_h: 16\nspike_w: " + "9" * 5000, "unreadable value"),
        ("spike_h: 2020-13-45\n", "unreadable value"),
    ],
)
def test_spikecv_config_values(tmp_path: Path, text: str, words: str) -> None:
    """A huge integer was an OverflowError; deep nesting a RecursionError; 5000 digits or a bad date a
    ValueError out of PyYAML."""
    path = tmp_path / "config.yaml"
    path.write_text(text)
    _refused(lambda: read_spikecv_config(path), path, words)


def test_load_yaml_refusals_are_yaml_errors() -> None:
    for text in ("[" * 5000, "a: " + "9" * 5000, "a: 2020-02-30"):
        with pytest.raises(yaml.YAMLError):
            load_yaml(text)


def test_train_config_nested_too_deeply(made: Path, tmp_path: Path) -> None:
    path = tmp_path / "config.yaml"
    path.write_text((made / "run" / "config.yaml").read_text().replace("iters: 5", "iters: " + "[" * 5000, 1))
    _refused(lambda: load_config(path), path, "nested too deeply")
    with pytest.raises(InputError, match="nested too deeply"):
        apply_overrides({}, ["iters=" + "[" * 5000])


def test_image_too_short_for_pillow(tmp_path: Path) -> None:
    """Two bytes of a would-be image were a struct.error out of Pillow."""
    path = tmp_path / "x.png"
    path.write_bytes(b"[]")
    _refused(lambda: read_display(path), path, "cannot read image")
    _refused(lambda: read_image(path), path, "cannot read image")


def test_image_header_of_a_decompression_bomb(tmp_path: Path) -> None:
    """An 8-bit PNG whose header claims 10¹⁰ pixels was Pillow's DecompressionBombError in read_display."""
    import struct
    import zlib

    from spikenerf.core.png16 import _PNG_SIGNATURE, _chunk

    path = tmp_path / "bomb.png"
    header = _chunk(b"IHDR", struct.pack(">IIBBBBB", 100_000, 100_000, 8, 2, 0, 0, 0))
    path.write_bytes(_PNG_SIGNATURE + header + _chunk(b"IDAT", zlib.compress(b"")) + _chunk(b"IEND", b""))
    _refused(lambda: read_display(path), path, "decompression bomb")


def _npy_header(shape: tuple[int, ...]) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return buf.getvalue() + bytes(64)


@pytest.mark.parametrize(
    "data, words",
    [
        (b"", "EOFError"),
        (_npy_header((10**12, 17)), "cannot read"),
        (_npy_header((3, 17))[:60], "cannot read"),
        (_npy_header((3, 17))[:10] + _npy_header((3, 17))[11:], "TokenError"),  # its "{" deleted
    ],
)
def test_llff_unreadable(tmp_path: Path, data: bytes, words: str) -> None:
    """An empty file was an EOFError, a header asking for 136 TB a MemoryError, a cut header a TokenError."""
    path = tmp_path / "poses_bounds.npy"
    path.write_bytes(data)
    _refused(lambda: read_pose_source(path), path, words)


def test_npy_image_header_beyond_the_file(tmp_path: Path) -> None:
    path = tmp_path / "frame.npy"
    path.write_bytes(_npy_header((10**6, 10**6, 3)))
    _refused(lambda: read_image(path), path, "cannot read image")


@pytest.mark.parametrize("name", ["holdout.json", RECORD, "metrics.json", "manifest.json", "results.json"])
def test_json_nested_too_deeply(tmp_path: Path, name: str) -> None:
    """A JSON file nested beyond the parser's stack was a RecursionError."""
    (tmp_path / name).write_text(DEEP_JSON)
    read = {
        "holdout.json": lambda: read_record(tmp_path),
        RECORD: lambda: read_render_record(tmp_path),
        "metrics.json": lambda: read_cell(tmp_path, "s", "gray", "v"),
        "manifest.json": lambda: read_manifest(tmp_path),
        "results.json": lambda: read_call(tmp_path / "results.json"),
    }[name]
    _refused(read, tmp_path / name, "")


def test_optional_json_nested_too_deeply(tmp_path: Path) -> None:
    """Files read where present (a folder's marker, a run's summary.json): treated as unreadable (``info``
    reports the marker), not a RecursionError."""
    from spikenerf.core.marker import MARKER, folder_kind, marker_problem
    from spikenerf.pipelines.report_tables import read_json
    from spikenerf.train.run import stored_summary

    for name in (MARKER, "summary.json"):
        (tmp_path / name).write_text(DEEP_JSON)
    assert folder_kind(tmp_path) is None
    assert (marker_problem(tmp_path) or "").startswith("unreadable (RecursionError")
    assert stored_summary(tmp_path, 1) is None
    assert read_json(tmp_path / "summary.json") == {}


def test_metrics_number_beyond_a_float(tmp_path: Path) -> None:
    """A metric or time beyond a float was an OverflowError out of math.isfinite."""
    (tmp_path / "metrics.json").write_text(f'{{"mean": {{"psnr": {HUGE}, "ssim": 0.5}}}}')
    _refused(lambda: read_cell(tmp_path, "s", "gray", "v"), tmp_path / "metrics.json", "mean.psnr")
    (tmp_path / "metrics.json").write_text('{"mean": {"psnr": 20, "ssim": 0.5}}')
    (tmp_path / "summary.json").write_text(f'{{"seconds": {HUGE}}}')
    assert read_cell(tmp_path, "s", "gray", "v").train_seconds is None


@pytest.mark.parametrize(
    "name, key, words",
    [("transforms.json", "step", "'step'"), ("transforms_blur.json", "step_end", "step_start/step_end")],
)
def test_dataset_step_beyond_int64(made: Path, tmp_path: Path, name: str, key: str, words: str) -> None:
    """A step of 1e30 passed the integer check, then was an OverflowError out of numpy's int64."""
    ds = shutil.copytree(made / "ds", tmp_path / "ds")
    meta = json.loads((ds / name).read_text())
    meta["frames"][-1 if key == "step" else 0][key] = 1e30
    (ds / name).write_text(json.dumps(meta))
    _refused(lambda: load_dataset(ds), ds / name, words)


@pytest.fixture(scope="module")
def evaluated(made: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the run with its ``metrics.json`` (``eval``), for ``info``'s reading of a run folder."""
    from spikenerf.cli import main

    run = shutil.copytree(made / "run", tmp_path_factory.mktemp("evaluated") / "run")
    try:
        main(["--threads", "1", "eval", str(run), "--device", "cpu"])
    except SystemExit as done:
        assert done.code in (0, None)
    return run


def test_run_description(evaluated: Path) -> None:
    """``info RUN``: its metrics.json, summary.json and curves.csv mutated."""
    from spikenerf.eval.describe import metrics_lines
    from spikenerf.train.run import describe_run

    run = evaluated
    for name, edit in (("metrics.json", json_edit), ("summary.json", json_edit), ("curves.csv", byte_edit)):
        _fuzz(run / name, edit, lambda: describe_run(run, metrics_lines), run, examples=25)


@pytest.mark.parametrize(
    "key, value",
    [
        ("test_psnr", HUGE),
        ("train_psnr", '"x"'),
        ("test_psnr", "{}"),
        ("test_views", '{"a": 1}'),
        ("seconds", "[]"),
    ],
)
def test_summary_of_another_type(evaluated: Path, tmp_path: Path, key: str, value: str) -> None:
    """A summary.json value of another type was a TypeError/ValueError/OverflowError out of ``info``'s
    formatting; such a summary is unreadable (as a cut one is): ``info`` names it and the field in one line
    (as it names a garbled curves.csv), a resume writes it again."""
    from spikenerf.train.run import describe_run, stored_summary

    run = shutil.copytree(evaluated, tmp_path / "run")
    summary = json.loads((run / "summary.json").read_text())
    assert stored_summary(run, summary["iteration"]) is not None
    summary[key] = "VALUE"
    (run / "summary.json").write_text(json.dumps(summary).replace('"VALUE"', value))
    assert stored_summary(run, summary["iteration"]) is None
    _refused(lambda: describe_run(run), run / "summary.json", f"field '{key}': expected")


@pytest.mark.parametrize(
    "old, new, words",
    [('"psnr": ', f'"psnr": {HUGE}, "_": ', "int too large"), ('"views": 2', '"views": 1.5', "not a count"),
     ('"views": 2', '"views": [1]', "not a count"), ('"split"', '\udcff"split"', "not text")],
)  # fmt: skip
def test_metrics_of_another_type(evaluated: Path, tmp_path: Path, old: str, new: str, words: str) -> None:
    """metrics.json: a PSNR beyond a float was an OverflowError, bytes not UTF-8 a UnicodeDecodeError; a
    count of views that is no count was shown as it was (``1.5 views``)."""
    from spikenerf.eval.describe import metrics_lines

    path = tmp_path / "metrics.json"
    text = (evaluated / "metrics.json").read_text()
    assert old in text
    path.write_bytes(text.replace(old, new, 1).encode("utf-8", "surrogateescape"))
    _refused(lambda: metrics_lines(path, 5), path, words)


@pytest.mark.parametrize("data", [b"[]", b"\x89PNG\r\n\x1a\n" + bytes(30)])
def test_info_frame_folder_broken_png(tmp_path: Path, data: bytes) -> None:
    """``info`` on a reconstruct frame folder: a broken first PNG was a struct.error or SyntaxError."""
    from spikenerf.cli.info import describe_frames

    (tmp_path / "00000.png").write_bytes(data)
    _refused(lambda: describe_frames(tmp_path), tmp_path / "00000.png", "unreadable PNG")


@pytest.fixture(scope="module")
def pairs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny pair folder of ``recon-data`` (16-pixel gray samples, 9-step windows)."""
    from spikenerf.cli import main

    out = tmp_path_factory.mktemp("pairs") / "pairs"
    args = [
        "--out",
        out,
        "--train-draws",
        2,
        "--val-draws",
        2,
        "--size",
        16,
        "--window",
        9,
        "--color",
        "gray",
    ]
    try:
        main(["--threads", "1", "recon-data", *map(str, args)])
    except SystemExit as done:
        assert done.code in (0, None)
    return out


def test_pair_shards(pairs: Path, tmp_path: Path) -> None:
    from spikenerf.recon.store import load_split

    root = shutil.copytree(pairs, tmp_path / "pairs")
    shard = root / "val" / "shard-00000.npz"
    _fuzz(shard, byte_edit, lambda: load_split(root, "val"), root, examples=25)
    _fuzz(root / "manifest.json", json_edit, lambda: load_split(root, "val"), root)


@pytest.mark.parametrize("change", ["deflate", "info"])
def test_pair_shard_damaged(pairs: Path, tmp_path: Path, change: str) -> None:
    """A changed byte of a shard's deflate stream was a zlib.error, an ``info`` nested too deeply a
    RecursionError."""
    from spikenerf.recon.store import read_shard

    path = tmp_path / "shard.npz"
    with np.load(pairs / "val" / "shard-00000.npz") as z:
        arrays = dict(z)
    if change == "info":
        arrays["info"] = np.array([DEEP_JSON] * len(arrays["info"]))
        np.savez(path, **arrays)
    else:
        np.savez_compressed(path, **arrays)
        data = bytearray(path.read_bytes())
        data[data.index(b"spikes.npy") + 40] ^= 0xFF  # inside the deflated spikes
        path.write_bytes(bytes(data))
    _refused(lambda: read_shard(path, 9, 16), path, "unreadable pair shard")


@pytest.mark.parametrize("key, value", [("noises", None), ("val_scenes", 5)])
def test_pair_folder_description_of_another_type(
    pairs: Path, tmp_path: Path, key: str, value: object
) -> None:
    """``info PAIRS``: a manifest's noises or held-out scenes that are no list were a TypeError."""
    from spikenerf.recon.describe import describe_pairs

    root = shutil.copytree(pairs, tmp_path / "pairs")
    manifest = json.loads((root / "manifest.json").read_text())
    (manifest["config"] if key == "noises" else manifest)[key] = value
    (root / "manifest.json").write_text(json.dumps(manifest))
    _refused(lambda: describe_pairs(root), root / "manifest.json", f"{key} must be a list")


def test_pair_folder_description(pairs: Path, tmp_path: Path) -> None:
    from spikenerf.recon.describe import describe_pairs

    root = shutil.copytree(pairs, tmp_path / "pairs")
    _fuzz(root / "manifest.json", json_edit, lambda: describe_pairs(root), root, examples=25)


@pytest.mark.parametrize(
    "entry, key, value, words",
    [("dataset", "box", [[0.0, 0.0, ""], [1.0, 1.0, 1.0]], "entry 'dataset'"),
     ("dataset", "size", [16, "TENSOR"], "entry 'dataset'"),
     ("hparams", "config", "VIEW_FREQS", "field_config.view_freqs")],
)  # fmt: skip
def test_checkpoint_entries_of_another_type(
    made: Path, tmp_path: Path, entry: str, key: str, value: object, words: str
) -> None:
    """A checkpoint's dataset fingerprint holding a string or a tensor was a TypeError/RuntimeError when the
    run's dataset was compared with it; a bad field_config value in its hparams an InputError naming the
    key but not the file."""
    import torch

    from spikenerf.train.run import load_run

    run = shutil.copytree(made / "run", tmp_path / "run")
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)
    if value == "VIEW_FREQS":
        ckpt["hparams"]["config"]["view_freqs"] = float("nan")
    else:
        ckpt[entry][key] = [torch.zeros(3) if v == "TENSOR" else v for v in value]  # type: ignore[union-attr]
    torch.save(ckpt, run / "checkpoint.pt")
    _refused(lambda: load_run(run, train_images=False), run / "checkpoint.pt", words)


@pytest.mark.parametrize("value", [{"a": 1}, "fast", -400])
def test_dataset_description_blur_rate(made: Path, tmp_path: Path, value: object) -> None:
    """``info DATASET``: a transforms_blur.json ``fps`` that is no positive number (load_dataset does not
    use it) was a TypeError out of its formatting, or shown as it was."""
    from spikenerf.data.summary import describe

    ds = shutil.copytree(made / "ds", tmp_path / "ds")
    meta = json.loads((ds / "transforms_blur.json").read_text())
    meta["fps"] = value
    (ds / "transforms_blur.json").write_text(json.dumps(meta))
    _refused(lambda: describe(ds), ds / "transforms_blur.json", "'fps': expected a positive number")


def test_dataset_description(work: Path) -> None:
    """``info DATASET`` (which also writes preview.png): its blur view file mutated."""
    from spikenerf.data.summary import describe

    ds = work / "ds"
    _fuzz(ds / "transforms_blur.json", json_edit, lambda: describe(ds), ds, examples=15)


# ------------------------------------------------------------------ second round: caches, folders, commands
def _cli_refusal(args: list[object], *names: Path) -> str:
    """``spikenerf --threads 1 ARGS`` in this process: exit 0, or exit 2 with one ``spikenerf: error:`` line
    naming one of ``names``; never a traceback. Returns its stderr."""
    import contextlib

    from spikenerf.cli import main

    err = io.StringIO()
    code = 0
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            main(["--threads", "1", "--quiet", *map(str, args)])
        except SystemExit as done:
            code = int(done.code or 0)
    text = err.getvalue()
    lines = [line for line in text.splitlines() if not line.startswith("spikenerf: warning:")]
    if code != 0:
        assert code == 2 and len(lines) == 1 and lines[0].startswith("spikenerf: error: "), text
        assert any(str(name) in lines[0] for name in names), f"names none of {names}: {text!r}"
    return text


def _fresh_cache(out: Path) -> None:
    """A render cache in ``out``: view 0 (4×5, gray) and 33 spike steps of 3×5 (a saved state after 32)."""
    import torch

    from spikenerf.eval.render_cache import CACHE, SPIKE_STATE_EVERY, RenderCache

    shutil.rmtree(out / CACHE, ignore_errors=True)
    cache = RenderCache.open(out, {"model": "m", "seed": 0}, pinned={"chunk": 64}, plan=["v.mp4"])
    cache.put_view(0, np.full((4, 5), 9, np.uint8), np.ones((4, 5), np.float32), np.ones((4, 5), np.float32))
    cache.start_spikes(0, (3, 5))
    for i in range(1, SPIKE_STATE_EVERY + 2):
        cache.put_spike_step(i, np.arange(15).reshape(3, 5) % i == 0, torch.full((3, 5), float(i)))


def _read_cache(out: Path) -> None:
    """What a resumed render reads of its cache: each part is kept whole or dropped, never an exception."""
    from spikenerf.eval.render_cache import RenderCache
    from spikenerf.eval.render_output import listed_files

    listed_files(out)
    cache = RenderCache.open(out, {"model": "m", "seed": 0}, pinned={"chunk": 64}, plan=["v.mp4"])
    assert isinstance(cache.pinned["chunk"], int)
    found = cache.view(0, (4, 5), 1)
    assert found is None or [a.shape for a in found] == [(4, 5)] * 3
    state = cache.spike_state((3, 5))
    assert state is None or (state[1].shape == (3, 5) and all(s.shape == (3, 5) for s in state[0]))


@st.composite
def npz_edit(draw: st.DrawFn, valid: bytes) -> bytes:
    """A byte edit of an .npz, or its arrays with one replaced: another shape or dtype, NaN, huge."""
    if draw(st.booleans()):
        return draw(byte_edit(valid))
    with np.load(io.BytesIO(valid)) as z:
        arrays = dict(z)
    name = draw(st.sampled_from(sorted(arrays)))
    arrays[name] = draw(
        st.sampled_from(
            [np.zeros((4, 5, 3), np.uint8), np.zeros((5, 4), np.float32), np.zeros(()), np.array("x"),
             np.array(np.inf), np.array(10**30, np.float64), np.zeros((4, 5), np.float16), np.zeros(0),
             np.array(-3), np.zeros((4, 5), complex)]
        )
    )  # fmt: skip
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@pytest.mark.parametrize(
    "name, edit",
    [
        ("key.json", json_edit),
        ("views/00000.npz", npz_edit),
        ("spikes.npz", npz_edit),
        ("spikes.bits", byte_edit),
    ],
)
def test_render_cache_files(tmp_path: Path, name: str, edit: Callable) -> None:
    """A damaged file of ``render``'s cache is ignored (the view or state rendered again, the cache started
    afresh), as its docstring says: never an exception."""
    from spikenerf.eval.render_cache import CACHE

    _fresh_cache(tmp_path)
    valid = (tmp_path / CACHE / name).read_bytes()

    @settings(FUZZ, max_examples=15)
    @given(edit(valid))
    def case(data: bytes) -> None:
        _fresh_cache(tmp_path)
        (tmp_path / CACHE / name).write_bytes(data)
        _read_cache(tmp_path)

    case()


@pytest.mark.parametrize(
    "name, data",
    [("key.json", DEEP_JSON.encode()), ("key.json", b"\xff\xfe{"), ("spikes.npz", "inf"), ("view", "depth")],
)
def test_render_cache_damaged(tmp_path: Path, name: str, data: bytes | str) -> None:
    """key.json nested beyond the stack was a RecursionError out of RenderCache.open and of the next render's
    clearing (render_output.listed_files); a saved step count of inf an OverflowError; a cached view whose
    depth was not (H, W) was returned, then a ValueError when the depths were stacked. Each is dropped now."""
    from spikenerf.eval.render_cache import CACHE, RenderCache
    from spikenerf.eval.render_output import listed_files

    _fresh_cache(tmp_path)
    root = tmp_path / CACHE
    if name == "key.json":
        (root / name).write_bytes(data)  # type: ignore[arg-type]
        assert listed_files(tmp_path) == []
    elif name == "spikes.npz":
        np.savez(root / name, steps=np.float64(np.inf), accumulator=np.zeros((3, 5), np.float32))
    else:
        np.savez(root / "views" / "00000.npz", color=np.zeros((4, 5), np.uint8),
                 depth=np.zeros((4, 5, 2), np.float32), opacity=np.zeros((4, 5), np.float32))  # fmt: skip
    cache = RenderCache.open(tmp_path, {"model": "m", "seed": 0}, pinned={"chunk": 64})
    assert cache.view(0, (4, 5), 1) is None if name != "spikes.npz" else cache.spike_state((3, 5)) is None


def test_render_resumes_over_a_damaged_cache(made: Path, tmp_path: Path) -> None:
    """``spikenerf render`` into a folder whose cache's key.json is nested beyond the stack: rebuilt."""
    from spikenerf.eval.render_cache import CACHE

    out = tmp_path / "render"
    args = ["render", made / "run", "--out", out, "--device", "cpu"]
    assert "error" not in _cli_refusal(args)
    (out / CACHE / "views").mkdir(parents=True)
    (out / CACHE / "key.json").write_text(DEEP_JSON)
    assert "error" not in _cli_refusal(args)
    assert not (out / CACHE).exists() and (out / "render.json").is_file()


def _bench_cfg(out: Path):  # type: ignore[no-untyped-def]
    from spikenerf.pipelines.benchmark import BenchmarkConfig

    return BenchmarkConfig(["analytic-orbs"], ["nerf-gt", "spike-integral"], ["gray"], out, size=16,
                           frames=100, test_views=1, render=False, iters=4)  # fmt: skip


def test_benchmark_settings(tmp_path: Path) -> None:
    """``OUT/benchmark.json`` mutated: a resume reads it (check_settings, adopt_integral_defaults) or
    refuses it in one line naming the file or the folder."""
    cfg = _bench_cfg(tmp_path)
    write_settings(cfg, None)

    def read() -> None:
        check_settings(cfg)
        adopt_integral_defaults(cfg)

    _fuzz(tmp_path / NAME, json_edit, read, tmp_path, examples=40)


@pytest.mark.parametrize(
    "change, words",
    [(lambda d: DEEP_JSON, "RecursionError"), (lambda d: {**d, "settings": [1]}, "an object settings"),
     (lambda d: {**d, "nonce": None}, "a string nonce"),
     (lambda d: {**d, "settings": {**d["settings"], "field_defaults": [1]}}, "objects field_defaults"),
     (lambda d: {**d, "settings": {**d["settings"], "integral_defaults": 3}}, "objects field_defaults")],
)  # fmt: skip
def test_benchmark_settings_malformed(tmp_path: Path, change: Callable, words: str) -> None:
    """benchmark.json nested beyond the stack was a RecursionError; settings that are no object, or field or
    spike-integral defaults that are none, an AttributeError or TypeError (adopt_integral_defaults had no
    except at all)."""
    cfg = _bench_cfg(tmp_path)
    write_settings(cfg, None)
    changed = change(json.loads((tmp_path / NAME).read_text()))
    (tmp_path / NAME).write_text(changed if isinstance(changed, str) else json.dumps(changed))
    _refused(lambda: check_settings(cfg), tmp_path / NAME, words)
    _refused(lambda: adopt_integral_defaults(cfg), tmp_path / NAME, words)


def test_holdout_radius_beyond_int64(tmp_path: Path) -> None:
    """A hold-out radius or check step of 10**400 was read as valid; the check steps were then an
    OverflowError out of numpy's int64 (eval's no-reference checks) and the radius shown as it was."""
    for key in ("radius", "check_steps"):
        record = {"check_steps": [3, 7], "step_numbers": [3, 7], "radius": 2}
        record[key] = [3, 10**400] if key == "check_steps" else 10**400
        (tmp_path / "holdout.json").write_text(json.dumps(record))
        _refused(lambda: read_record(tmp_path), tmp_path / "holdout.json", f"{key}: expected")


def test_sequence_fps_beyond_a_float(made: Path) -> None:
    """``SequenceSource(fps=10**400)`` was an OverflowError out of math.isfinite."""
    from spikenerf.scenes.sequence import SequenceSource

    with pytest.raises(InputError, match="fps: expected a positive number"):
        SequenceSource(made / "ds" / "transforms_gt.json", fps=10**400)


RECON_TRAIN = ["--iters", 2, "--batch", 2, "--crop", 16, "--width", 4, "--eval-every", 1, "--ckpt-every", 1]


@pytest.fixture(scope="module")
def recon_run(pairs: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 2-iteration ``recon-train`` folder of the tiny pair folder."""
    out = tmp_path_factory.mktemp("recon") / "rt"
    assert "error" not in _cli_refusal(["recon-train", pairs, "--out", out, *RECON_TRAIN])
    return out


@st.composite
def torch_edit(draw: st.DrawFn, valid: bytes) -> bytes:
    """A byte edit of a torch file (one time in four), or its dict with one entry replaced or deleted."""
    import torch

    if draw(st.integers(0, 3)) == 0:
        return draw(byte_edit(valid))
    data = draw(tree_edit(torch.load(io.BytesIO(valid), weights_only=True)))
    buf = io.BytesIO()
    torch.save(data, buf)
    return buf.getvalue()


def test_recon_train_folder(recon_run: Path, tmp_path: Path) -> None:
    """``info`` of a recon-train folder: its config.json, weights.json and curves.csv mutated."""
    from spikenerf.recon.describe import describe_recon

    run = shutil.copytree(recon_run, tmp_path / "rt")
    for name, edit in (("config.json", json_edit), ("weights.json", json_edit), ("curves.csv", byte_edit)):
        _fuzz(run / name, edit, lambda: describe_recon(run), run, examples=15)


def test_recon_train_resume(recon_run: Path, pairs: Path, tmp_path: Path) -> None:
    """``recon-train --out RUN`` again (a resume) over a mutated checkpoint or curves.csv, and
    ``reconstruct --weights`` of mutated weights: run, or one error line naming the file or folder."""
    run = shutil.copytree(recon_run, tmp_path / "rt")
    args = ["recon-train", pairs, "--out", run, *RECON_TRAIN]
    for name, edit in (("checkpoint.pt", torch_edit), ("curves.csv", byte_edit)):
        _fuzz(run / name, edit, lambda: _cli_refusal(args, run), run, examples=8)
    weights = run / "weights.pt"
    _fuzz(weights, torch_edit, lambda: load_weights(weights), weights, examples=15)


@pytest.mark.parametrize(
    "key, value, words",
    [("iteration", float("nan"), "malformed checkpoint"), ("iteration", None, "malformed checkpoint"),
     ("iteration", -1, "malformed checkpoint"), ("elapsed", None, "malformed checkpoint"),
     ("running_l1", 10**400, "malformed checkpoint"), ("optimizer", None, "does not fit this reconstructor"),
     ("optimizer", "LR", "does not fit this reconstructor")],
    ids=["iteration-nan", "iteration-none", "iteration-negative", "elapsed-none", "running-huge", "adam-none",
         "adam-step-huge"],
)  # fmt: skip
def test_recon_train_resume_checkpoint_entries(
    recon_run: Path, pairs: Path, tmp_path: Path, key: str, value: object, words: str
) -> None:
    """``recon-train`` resuming a checkpoint whose iteration was NaN/None was a ValueError/TypeError (-1 a
    math domain error in the learning rate), elapsed None a TypeError, an optimizer state None an
    AttributeError, an Adam step count of 10**400 an OverflowError: one error line naming the file now."""
    import torch

    run = shutil.copytree(recon_run, tmp_path / "rt")
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)
    if value == "LR":
        ckpt[key]["state"][0]["step"] = 10**400
    else:
        ckpt[key] = value
    torch.save(ckpt, run / "checkpoint.pt")
    err = _cli_refusal(["recon-train", pairs, "--out", run, *RECON_TRAIN], run)
    assert words in err and str(run) in err


IMPORT = ["--keyframe-every", 10, "--window", 5, "--test-every", 2, "--overwrite"]


def test_import_command(work: Path, tmp_path: Path) -> None:
    """``spikenerf import`` of the raw recording: its .dat, its SpikeCV config.yaml and each pose file
    (transforms.json, poses_bounds.npy, a COLMAP text model) mutated: a dataset, or one error line."""
    raw, out = work / "ds" / "raw", tmp_path / "imported"
    rec = raw / "recording.dat"
    orbit = ["import", rec, "--out", out, "--poses", "orbit", "--orbit", "4,30", "--fov", 40, *IMPORT]
    assert "error" not in _cli_refusal(orbit) and (out / "transforms.json").is_file()
    _fuzz(rec, byte_edit, lambda: _cli_refusal(orbit, rec, raw), rec, examples=10)
    _fuzz(raw / "config.yaml", yaml_edit, lambda: _cli_refusal(orbit, raw), raw, examples=15)
    colmap = shutil.copytree(work / "colmap", tmp_path / "colmap")  # its last image within the 40 steps
    _edit_text(colmap / "images.txt", "00040.png", "00039.png")
    for poses, name, edit in (
        (work / "ds" / "transforms.json", None, json_edit),
        (work / "poses_bounds.npy", None, npy_edit),
        (colmap, "images.txt", byte_edit),
        (colmap, "cameras.txt", byte_edit),
        (colmap, "points3D.txt", byte_edit),
    ):
        args = ["import", rec, "--out", out, "--poses", poses, *IMPORT]
        assert "error" not in _cli_refusal(args)
        path = poses / name if name else poses
        _fuzz(path, edit, lambda a=args, p=poses: _cli_refusal(a, p), path, examples=8)


@pytest.mark.parametrize("value", [1e308, -1e300, 1e12])
def test_import_camera_absurdly_far(work: Path, tmp_path: Path, value: float) -> None:
    """A camera position of 1e308 in a --poses file passed the reader (it is finite), then the unit-box fit
    overflowed and import refused its own output ('far' inf in OUT.partial/transforms.json)."""
    meta = json.loads((work / "ds" / "transforms.json").read_text())
    meta["frames"][1]["transform_matrix"][0][3] = value
    poses = tmp_path / "transforms.json"
    poses.write_text(json.dumps(meta))
    rec, out = work / "ds" / "raw" / "recording.dat", tmp_path / "imported"
    err = _cli_refusal(["import", rec, "--out", out, "--poses", poses, *IMPORT], poses)
    assert f"{poses}: poses hold absurdly distant camera positions" in err


@pytest.fixture(scope="module")
def bench_folder(evaluated: Path, made: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished benchmark folder of one nerf-gt cell (the evaluated run), its dataset, results.json and
    benchmark.json, as ``benchmark`` leaves it; ``report`` rebuilds its page."""
    import dataclasses

    from spikenerf.pipelines.benchmark import BenchmarkConfig
    from spikenerf.pipelines.benchmark.cells import run_dir
    from spikenerf.pipelines.benchmark.settings import write_settings

    out = tmp_path_factory.mktemp("bench") / "bench"
    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray"], out, size=16, frames=40, test_views=2,
                          iters=5, blur_views="frames")  # fmt: skip
    shutil.copytree(evaluated, run_dir(cfg, "analytic-orbs", "gray", "nerf-gt"))
    shutil.copytree(made / "ds", out / "datasets" / "analytic-orbs")
    write_settings(cfg, None)
    config = {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(cfg).items()}
    cell = {"scene": "analytic-orbs", "variant": "nerf-gt", "color": "gray", "psnr": 20.5, "ssim": 0.5,
            "lpips": None, "eval_seconds": 1.5, "seed": 0, "train_seconds": 2.0}  # fmt: skip
    results = {"config": config, "cells": [cell], "trained_on": {"nerf-gt": "2 GT views"}, "environment": {}}
    (out / "results.json").write_text(json.dumps(results))
    assert "error" not in _cli_refusal(["report", out]) and (out / "report.html").is_file()
    return out


def test_report_command(bench_folder: Path, tmp_path: Path) -> None:
    """``spikenerf report`` of a benchmark folder with one file mutated: the page is rebuilt (a figure it
    cannot draw becomes a note), or one error line names the file or folder."""
    out = shutil.copytree(bench_folder, tmp_path / "bench")
    run = out / "runs" / "analytic-orbs" / "gray" / "nerf-gt"
    for path, edit in (
        (out / "results.json", json_edit),
        (out / "benchmark.json", json_edit),
        (run / "metrics.json", json_edit),
        (run / "curves.csv", byte_edit),
        (run / "summary.json", json_edit),
    ):
        _fuzz(path, edit, lambda p=path: _cli_refusal(["report", out], p, out), path, examples=2)


def test_benchmark_dataset_settings(bench_folder: Path, tmp_path: Path) -> None:
    """A benchmark dataset's config.yaml (what a resume compares with its settings) mutated: read, or
    refused in one line naming the dataset."""
    from spikenerf.pipelines.benchmark import BenchmarkConfig
    from spikenerf.pipelines.benchmark.run import dataset_mismatch

    out = shutil.copytree(bench_folder, tmp_path / "bench")
    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray"], out, size=16, frames=40, test_views=2,
                          iters=5, blur_views="frames")  # fmt: skip
    ds = out / "datasets" / "analytic-orbs"
    assert dataset_mismatch(cfg, "analytic-orbs") is None

    def read() -> None:
        if (problem := dataset_mismatch(cfg, "analytic-orbs")) is not None:
            raise problem

    _fuzz(ds / "config.yaml", yaml_edit, read, ds, examples=20)


@pytest.mark.parametrize("old, new", [("filename", "\udce6ilename"), ("colors:\n", "colors: 7\nx:\n")])
def test_benchmark_dataset_config_unreadable(made: Path, tmp_path: Path, old: str, new: str) -> None:
    """A benchmark dataset's config.yaml of bytes that are not UTF-8 was a UnicodeDecodeError out of
    dataset_settings (and of ``info``'s view_counts), its colors an integer a TypeError: what it does not
    say readably is not said (load_dataset refuses such a dataset)."""
    from spikenerf.data.summary import view_counts
    from spikenerf.pipelines.benchmark.run import dataset_settings

    ds = shutil.copytree(made / "ds", tmp_path / "ds")
    text = (ds / "config.yaml").read_text()
    assert old in text
    (ds / "config.yaml").write_bytes(text.replace(old, new, 1).encode("utf-8", "surrogateescape"))
    assert dataset_settings(ds)["colors"] is None
    assert view_counts(ds)["steps"] == 40


def test_sequence_size_beyond_a_float(made: Path) -> None:
    """``simulate --sequence --width 10**400`` was an OverflowError (the height kept the aspect in floats)."""
    from spikenerf.scenes.sequence import SequenceSource

    with pytest.raises(InputError, match=r"width: expected a positive integer below 2\*\*31"):
        SequenceSource(made / "ds" / "transforms_gt.json", width=10**400)


def test_every_summary_field_type_is_checked_when_read_back() -> None:
    """A TrainSummary field of a type the reader does not list would go unchecked (``info`` then formats
    whatever was edited in): each annotated type has its check."""
    from dataclasses import fields

    from spikenerf.train.run import _SUMMARY_TYPES, TrainSummary

    assert {str(f.type) for f in fields(TrainSummary)} <= set(_SUMMARY_TYPES)


# --------------------------------------------------------------------------- checkpoint tensors (review 45)
def _damage(ckpt: dict, change: str) -> None:
    """Apply one named damage to a loaded checkpoint (in place): a tensor of another shape, dtype or with
    NaN/inf values, a missing or extra tensor, an optimizer or random state that does not fit."""
    import torch

    model, state = ckpt["model"], ckpt["optimizer"]["state"]
    planes, grid, rng = model["field.density_planes"], model["field.occupancy.grid"], ckpt["rng"]
    edits = {
        "plane of another size": lambda: model.update({"field.density_planes": planes[:, :, :5].clone()}),
        "int planes": lambda: model.update({"field.density_planes": planes.int()}),
        "float64 planes": lambda: model.update({"field.density_planes": planes.double()}),
        "complex planes": lambda: model.update({"field.density_planes": planes.to(torch.complex64)}),
        "NaN planes": lambda: model.update({"field.density_planes": torch.full_like(planes, float("nan"))}),
        "inf decoder": lambda: model["field.decoder.4.bias"].fill_(float("inf")),
        "NaN occupancy bounds": lambda: model["field.occupancy.bounds"].fill_(float("nan")),
        "occupancy grid not cubic": lambda: model.update({"field.occupancy.grid": grid[:2]}),
        "missing tensor": lambda: model.pop("field.app_lines"),
        "extra tensor": lambda: model.update({"field.bogus": torch.zeros(3)}),
        "NaN Adam moment": lambda: state[0]["exp_avg"].fill_(float("nan")),
        "Adam moment of another shape": lambda: state[0].update({"exp_avg": torch.zeros(3)}),
        "float64 Adam moment": lambda: state[0].update({"exp_avg": state[0]["exp_avg"].double()}),
        "Adam step a list": lambda: state[0].update({"step": [1]}),
        "Adam state a string": lambda: state.update({0: "x"}),
        "no Adam groups": lambda: ckpt["optimizer"].update({"param_groups": []}),
        "Adam rate a string": lambda: ckpt["optimizer"]["param_groups"][0].update({"lr": "x"}),
        "short random state": lambda: ckpt["rng"].update({"torch": torch.zeros(10, dtype=torch.uint8)}),
        "sampler state missing": lambda: [rng.pop(k) for k in list(rng) if k != "torch"],
        "running means a string": lambda: ckpt.update({"interval_means": "x"}),
        "rays missing": lambda: ckpt.pop("rays"),
        "elapsed NaN": lambda: ckpt.update({"elapsed": float("nan")}),
        "poses a string": lambda: ckpt.update({"poses": "x"}),
    }  # fmt: skip
    edits[change]()


LOAD_DAMAGE = [
    ("plane of another size", "grid factor field.density_planes has shape"),
    ("int planes", "'field.density_planes' is torch.int32, expected torch.float32"),
    ("float64 planes", "'field.density_planes' is torch.float64"),
    ("complex planes", "complex values"),
    ("NaN planes", "'field.density_planes' holds NaN or inf"),
    ("inf decoder", "'field.decoder.4.bias' holds NaN or inf"),
    ("NaN occupancy bounds", "'field.occupancy.bounds' holds NaN or inf"),
    ("occupancy grid not cubic", "expected (G, G, G)"),
    ("missing tensor", 'Missing key(s) in state_dict: "field.app_lines"'),
    ("extra tensor", 'Unexpected key(s) in state_dict: "field.bogus"'),
    ("NaN Adam moment", "exp_avg of parameter 0 holds NaN or inf"),
    ("Adam step a list", "the step of parameter 0 is list"),
    ("Adam state a string", "the state of parameter 0 is a str"),
    ("Adam rate a string", "rate is 'x'"),
    ("elapsed NaN", "elapsed time nan"),
    ("poses a string", "entry 'poses'"),
]


@pytest.mark.parametrize("change, words", LOAD_DAMAGE)
def test_checkpoint_tensors_damaged(made: Path, tmp_path: Path, change: str, words: str) -> None:
    """``load_run`` (eval, render) of a checkpoint whose tensors were damaged. Before: a factor of another
    size, a tensor of another dtype (an int grid cast silently) and NaN/inf tensors loaded and rendered
    garbage; a missing or extra tensor said only "Error(s) in loading state_dict for GridModel:"; a
    malformed ``poses`` entry was a TypeError in eval and render."""
    import torch

    from spikenerf.train.run import load_run

    run = shutil.copytree(made / "run", tmp_path / "run")
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)
    _damage(ckpt, change)
    torch.save(ckpt, run / "checkpoint.pt")
    _refused(lambda: load_run(run, train_images=False), run / "checkpoint.pt", words)


@pytest.mark.parametrize("change, words", LOAD_DAMAGE)
def test_info_refuses_a_damaged_checkpoint(made: Path, tmp_path: Path, change: str, words: str) -> None:
    """``info`` of a run whose checkpoint eval would refuse names the same problem. Before: a tensor of
    another dtype or shape, a missing or an extra one passed ``info`` (it loaded the checkpoint but never
    built the model), which then reported the run as trained."""
    import torch

    from spikenerf.train.run import describe_run

    run = shutil.copytree(made / "run", tmp_path / "run")
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)
    _damage(ckpt, change)
    torch.save(ckpt, run / "checkpoint.pt")
    _refused(lambda: describe_run(run), run / "checkpoint.pt", words)


@pytest.mark.parametrize(
    "change, words",
    [("Adam moment of another shape", "exp_avg of parameter 0 is (3,) torch.float32, its parameter (3, 16"),
     ("float64 Adam moment", "exp_avg of parameter 0 is"),
     ("no Adam groups", "0 parameter groups where the model has 2"),
     ("short random state", "its training state does not load (RuntimeError"),
     ("sampler state missing", "its training state does not load (KeyError"),
     ("running means a string", "its training state does not load (TypeError"),
     ("rays missing", "its training state does not load (KeyError: 'rays')")],
)  # fmt: skip
def test_checkpoint_resume_state_damaged(
    made: Path, tmp_path: Path, capsys: pytest.CaptureFixture, change: str, words: str
) -> None:
    """``train --resume`` of a checkpoint whose training state was damaged. Before: an Adam moment of
    another shape crashed the process (a segmentation fault in the fused step), the others were tracebacks
    (ValueError, RuntimeError, KeyError, TypeError) from ``load_state_dict`` and ``restore_rng``."""
    import torch

    from spikenerf.cli import main

    run = shutil.copytree(made / "run", tmp_path / "run")
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)
    _damage(ckpt, change)
    torch.save(ckpt, run / "checkpoint.pt")
    before = (run / "checkpoint.pt").read_bytes()
    argv = ["--threads", "1", "train", str(made / "ds"), "--out", str(run), "--resume", "--iters", "7"]
    with pytest.raises(SystemExit) as done:
        main([*argv, "--device", "cpu", "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert done.value.code == 2 and len(err.splitlines()) == 1, err
    assert str(run / "checkpoint.pt") in err and words in err, err
    assert (run / "checkpoint.pt").read_bytes() == before


def _binary_model(work: Path, tmp_path: Path) -> Path:
    """The fixture's COLMAP text model written as a binary one by pycolmap (skipped without it)."""
    pycolmap = pytest.importorskip("pycolmap")
    text, folder = tmp_path / "text", tmp_path / "sparse"
    text.mkdir()
    folder.mkdir()
    shutil.copy(work / "colmap" / "cameras.txt", text)
    poses = (work / "colmap" / "images.txt").read_text().splitlines()[1::2]  # without their 2-D points
    (text / "images.txt").write_text("".join(f"{line}\n\n" for line in poses))
    (text / "points3D.txt").write_text("1 0.1 0.2 0.3 255 0 0 0.5\n2 -0.1 0.0 0.3 0 255 0 0.5\n")
    pycolmap.Reconstruction(str(text)).write_binary(str(folder))
    assert len(read_pose_source(folder).poses) == 5
    return folder


def _read_in_child(folder: Path) -> str:
    """``read_pose_source(folder)`` in a child process limited to 30 s and 2 GiB: what it printed (a
    pycolmap that reads on past the end of a cut file allocates without end)."""
    import resource
    import subprocess
    import sys

    code = (
        "import sys\nfrom spikenerf.importing.poses import read_pose_source\n"
        "from spikenerf.core.errors import InputError\n"
        f"try:\n    print('read', len(read_pose_source({str(folder)!r}).poses))\n"
        "except InputError as err:\n    print('refused', err)\n"
    )

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))

    try:
        done = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=30, preexec_fn=limit
        )
    except subprocess.TimeoutExpired:
        return "timed out"
    return done.stdout.strip() or done.stderr.strip().splitlines()[-1]


@pytest.mark.parametrize(
    "name, cut, words",
    [("points3D.bin", 0, "the record count ends past its 0 bytes"),
     ("points3D.bin", 36, "point record 1 ends past its 36 bytes"),
     ("frames.bin", -10, "truncated COLMAP binary file: frame record"),
     ("images.bin", -5, "truncated COLMAP binary file: image record"),
     ("cameras.bin", "COUNT", "it declares 4294967296 records, holds 1")],
)  # fmt: skip
def test_colmap_binary_model_cut(work: Path, tmp_path: Path, name: str, cut: object, words: str) -> None:
    """A binary COLMAP model with a file cut short or an absurd record count. Before: pycolmap read a
    zero-byte or cut ``points3D.bin`` (or a cut ``frames.bin``) on without end, allocating gigabytes in
    seconds (the import hung until the machine ran out of memory)."""
    import struct

    folder = _binary_model(work, tmp_path)
    data = (folder / name).read_bytes()
    (folder / name).write_bytes(struct.pack("<Q", 2**32) + data[8:] if cut == "COUNT" else data[:cut])
    found = _read_in_child(folder)
    assert found.startswith("refused") and str(folder / name) in found and words in found, found


def test_colmap_binary_model_values(work: Path, tmp_path: Path) -> None:
    """A binary model whose camera has a NaN focal length was refused naming the deleted text file that
    pycolmap converted it to (``/tmp/tmpXXXX/cameras.txt``), not the user's ``cameras.bin``."""
    import struct

    folder = _binary_model(work, tmp_path)
    data = (folder / "cameras.bin").read_bytes()  # count, id, model, width, height, then the focal length
    (folder / "cameras.bin").write_bytes(data[:32] + struct.pack("<d", float("nan")) + data[40:])
    _refused(lambda: read_pose_source(folder), folder / "cameras.bin", "focal length must be > 0")
    check_refusal(lambda: read_pose_source(folder), folder / "cameras.bin")


def test_colmap_cameras_of_every_model_pass_the_layout_check(tmp_path: Path) -> None:
    """The layout check knew camera models 0-11 and refused a valid model holding a FISHEYE (15) or
    SIMPLE_DIVISION (12) camera that pycolmap 4.2 writes; a model id newer than its table ends the check of
    cameras.bin (pycolmap reads it) instead of refusing it. A camera cut short is still refused."""
    import struct

    from spikenerf.importing.colmap_model import check_binary_layout

    def camera(cid: int, model: int, params: int) -> bytes:
        return struct.pack(f"<IiQQ{params}d", cid, model, 64, 48, *([1.0] * params))

    path = tmp_path / "cameras.bin"
    for model, params in [(1, 4), (12, 4), (15, 4), (16, 6), (17, 2), (99, 0)]:
        path.write_bytes(struct.pack("<Q", 2) + camera(1, 1, 4) + camera(2, model, params))
        check_binary_layout(path)
    path.write_bytes(struct.pack("<Q", 2) + camera(1, 1, 4) + camera(2, 15, 4)[:-8])
    with pytest.raises(InputError, match="camera record 2 ends past"):
        check_binary_layout(path)


def test_running_out_of_memory_while_resuming_is_not_called_damage(
    made: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``torch.cuda.OutOfMemoryError`` is a RuntimeError: restoring the training state on a full GPU was
    reported as "damaged checkpoint: its training state does not load"."""
    import torch

    from spikenerf.train.config_file import load_run_config
    from spikenerf.train.trainer import Trainer

    def full(*args: object) -> None:
        raise torch.cuda.OutOfMemoryError("CUDA out of memory")

    run = shutil.copytree(made / "run", tmp_path / "run")
    monkeypatch.setattr(Trainer, "_restore", full)
    config = load_run_config(run / "config.yaml")
    config.dataset, config.iters = str(made / "ds"), 7
    with pytest.raises(torch.cuda.OutOfMemoryError):
        Trainer(config, run, resume=True, progress=False)

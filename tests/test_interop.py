"""Other tools read our dataset folder: nerfstudio's ``nerfstudio-data`` parser and SpikeCV's loader keys.

The checks below are our own code, written from the tools' documented formats (the packages are not installed
here): nerfstudio's dataparser (``nerfstudio/data/dataparsers/nerfstudio_dataparser.py``) and SpikeCV's
``spkData/load_dat.py`` (``data_parameter_dict``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from spikenerf.camera.io import read_dat
from spikenerf.camera.reconstruct import tfp
from spikenerf.cli import main
from spikenerf.data.dataset import load_dataset, load_image

VIEWS = ("transforms_gt.json", "transforms_tfp.json", "transforms_blur.json")
#: nerfstudio's camera models (cameras.CAMERA_MODEL_TO_TYPE keys); frames default to PERSPECTIVE
NS_CAMERA_MODELS = {"SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE"}
#: SpikeCV's task ids (LABEL_DATA_TYPE); the raw stream is task 0
SPIKECV_RAW = 0


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("interop") / "ds"
    args = ["--width", "12", "--height", "10", "--frames", "40", "--blur-fps", "4000", "--test-views", "2"]
    main(["simulate", "--scene", "analytic-orbs", "--out", str(out), *args, "--color", "all",
          "--no-progress"])  # fmt: skip
    return out


def nerfstudio_parse(json_path: Path, split: str) -> dict:
    """nerfstudio's parsing rules for one split of a ``transforms*.json``: image paths, poses, intrinsics."""
    meta = json.loads(json_path.read_text(encoding="utf-8"))
    data_dir = json_path.parent
    intrinsics = {}
    for key in ("fl_x", "fl_y", "cx", "cy", "h", "w"):
        # a camera value is global (top level) or given by every frame, else the parser fails
        intrinsics[key] = meta[key] if key in meta else [frame[key] for frame in meta["frames"]]
    camera_model = meta.get("camera_model", "OPENCV")
    assert camera_model in NS_CAMERA_MODELS
    # frames sorted by image path; a frame without file_path is a KeyError
    frames = sorted(meta["frames"], key=lambda f: str(data_dir / f["file_path"]))
    names = [data_dir / f["file_path"] for f in frames]
    poses = np.array([f["transform_matrix"] for f in frames], dtype=np.float32)
    assert poses.shape == (len(frames), 4, 4)
    has_lists = any(f"{s}_filenames" in meta for s in ("train", "val", "test"))
    if f"{split}_filenames" in meta:
        wanted = {data_dir / p for p in meta[f"{split}_filenames"]}
        if wanted - set(names):
            raise RuntimeError(f"Some filenames for split {split} were not found: {wanted - set(names)}")
        indices = [i for i, n in enumerate(names) if n in wanted]
    elif has_lists:
        raise RuntimeError(f"The dataset's list of filenames for split {split} is missing.")
    else:
        indices = list(range(len(names)))
    for i in indices:  # the image loader opens each file with PIL: 8-bit view, stated size
        with Image.open(names[i]) as img:
            assert img.size == (meta["w"], meta["h"]) and img.mode == "RGB", (names[i], img.size, img.mode)
    return {"images": [names[i] for i in indices], "poses": poses[indices], **intrinsics}


@pytest.mark.parametrize("view", VIEWS)
def test_every_view_parses_by_our_reading_of_nerfstudios_format(dataset: Path, view: str) -> None:
    splits = {s: nerfstudio_parse(dataset / view, s) for s in ("train", "val", "test")}
    train, test = splits["train"]["images"], splits["test"]["images"]
    assert train and len(test) == 2 and not set(train) & set(test)
    assert splits["val"]["images"] == test and all(p.parent.name == "test" for p in test)
    folder = {"transforms_gt.json": "gt", "transforms_tfp.json": "tfp", "transforms_blur.json": "blur"}[view]
    assert {p.parent.name for p in train} == {folder}
    ours = json.loads((dataset / "transforms.json").read_text())
    assert splits["train"]["w"] == ours["w"] == 12 and splits["train"]["fl_x"] == ours["fl_x"]


def test_our_transforms_json_alone_lacks_the_keys_of_nerfstudios_format(dataset: Path) -> None:
    """Why the views exist: most spike steps have no image, and nerfstudio's parser needs one per frame."""
    with pytest.raises(KeyError, match="file_path"):
        nerfstudio_parse(dataset / "transforms.json", "train")


def test_tfp_keyframes_are_tfp_of_the_recorded_stream(dataset: Path) -> None:
    meta = json.loads((dataset / "transforms_tfp.json").read_text())
    ours = {f["step"]: f for f in json.loads((dataset / "transforms.json").read_text())["frames"]}
    rgb = np.stack([read_dat(dataset / f"spikes_rgb_{c}.dat", 10, 12) for c in "rgb"], axis=1)
    keyframes = [f for f in meta["frames"] if f["file_path"].startswith("tfp/")]
    assert [f["step"] for f in keyframes] == [0, 10, 20, 30]
    for f in keyframes:
        want = tfp(rgb, 41, 1.0, frames=f["step"])[0].transpose(1, 2, 0)
        got = load_image(dataset / f["file_path"])
        np.testing.assert_allclose(got, np.clip(want, 0, 1), atol=2e-4)
        assert f["transform_matrix"] == ours[f["step"]]["transform_matrix"]


def test_our_loader_ignores_the_held_out_frames_of_the_blur_view(dataset: Path) -> None:
    ds = load_dataset(dataset)
    assert ds.blur is not None and len(ds.blur) == 4 and len(ds.test) == 2 and len(ds.gt) == 4


def test_spikecv_loader_keys_by_its_documented_format(dataset: Path) -> None:
    """SpikeCV's ``data_parameter_dict``: the task must be listed, then spike_h/spike_w size the stream."""
    cfg = yaml.safe_load((dataset / "config.yaml").read_text())
    for key in ("filename", "spike_h", "spike_w", "is_labeled", "labeled_data_type", "labeled_data_suffix"):
        assert key in cfg, key
    assert SPIKECV_RAW in cfg["labeled_data_type"] and cfg["is_labeled"] is False
    h, w = cfg["spike_h"], cfg["spike_w"]
    assert (h, w) == (10, 12) and isinstance(h, int) and isinstance(w, int)
    frame_bytes = h * w // 8  # SpikeCV: img_num = len(file) // (h·w/8)
    assert (dataset / "spikes_gray.dat").stat().st_size // frame_bytes == 40

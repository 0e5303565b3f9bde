"""Writing a dataset folder: ``simulate`` streams into :class:`DatasetWriter` (docs/formats.md).

Beside ``transforms.json`` (one frame per spike step, our own format) it writes three views in nerfstudio's
``nerfstudio-data`` format, each loadable with ``ns-train ... --data DIR/transforms_<view>.json``: every frame
has a ``file_path``, the held-out ``test/`` views are in the frame list, and ``train_filenames``,
``val_filenames`` and ``test_filenames`` say which frames train and which evaluate.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from spikenerf.camera.dat_codec import encode_frames
from spikenerf.camera.io import read_dat
from spikenerf.camera.reconstruct import DEFAULT_WINDOW
from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError
from spikenerf.core.marker import folder_kind, mark
from spikenerf.core.replacement import recover_retired
from spikenerf.data.dataset import (
    BLUR_ARRAY,
    CONFIG,
    TRANSFORMS,
    TRANSFORMS_BLUR,
    TRANSFORMS_GT,
    TRANSFORMS_TEST,
    TRANSFORMS_TFP,
    spike_files,
    write_image,
)
from spikenerf.data.reconstruction import frame_at
from spikenerf.scenes.trajectory import Intrinsics, Trajectory


def _matrix(pose: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(pose, dtype=np.float64)]


#: TFP window (frames) of the keyframes in ``tfp/`` (the paper's and ``reconstruct``'s default)
TFP_WINDOW = DEFAULT_WINDOW


def split_fields(train: list[dict], test: list[dict]) -> dict:
    """nerfstudio's split lists: ``train`` frames train; the held-out ``test`` frames are val and test."""
    held_out = [f["file_path"] for f in test]
    return {
        "camera_model": "PINHOLE",
        "train_filenames": [f["file_path"] for f in train],
        "val_filenames": held_out,
        "test_filenames": held_out,
    }


def _dump(header: dict, frames: list[dict]) -> str:
    """JSON with the header indented and one line per frame (1000-step files stay readable)."""
    head = "".join(f"  {json.dumps(key)}: {json.dumps(value)},\n" for key, value in header.items())
    body = ",\n".join("    " + json.dumps(f) for f in frames)
    return f'{{\n{head}  "frames": [\n{body}\n  ]\n}}\n'


class DatasetWriter:
    """Writes a dataset folder (the ``simulate`` pipeline streams into it).

    Args:
        root: the folder (created). intrinsics: the camera. fps: spike readout rate (Hz).
        scene_box: (2, 3) bounds. near, far: ray bounds in scene units.
    """

    def __init__(
        self, root: Path, intrinsics: Intrinsics, fps: float, scene_box: np.ndarray, near: float, far: float
    ) -> None:
        self.root, self.intrinsics, self.fps = Path(root), intrinsics, float(fps)
        self.scene_box, self.near, self.far = np.asarray(scene_box, dtype=np.float64), float(near), float(far)
        self.root.mkdir(parents=True, exist_ok=True)
        self.gt_paths: dict[int, str] = {}
        self.blur_frames: list[dict] = []
        self.blur_array: np.ndarray | None = None
        self.test_frames: list[dict] = []

    def header(self, **extra: Any) -> dict:
        """Camera and scene fields shared by the three transforms files; a lens adds nerfstudio's
        ``camera_model`` (over the views' ``PINHOLE``) and its non-zero terms (``k1``, …)."""
        k = self.intrinsics
        camera = {
            "camera_angle_x": k.camera_angle_x,
            "w": k.width,
            "h": k.height,
            "fl_x": k.fl_x,
            "fl_y": k.fl_y,
        }
        scene = {"fps": self.fps, "scene_box": self.scene_box.tolist(), "near": self.near, "far": self.far}
        lens = {} if k.distortion is None else k.distortion.as_json()
        return {**camera, "cx": k.cx, "cy": k.cy, **scene, **extra, **lens}

    def start_spikes(self, modes: list[str]) -> None:
        """Create (truncate) the spike files of ``modes``."""
        for mode in modes:
            for name in spike_files(mode):
                (self.root / name).write_bytes(b"")

    def append_spikes(self, mode: str, spikes: np.ndarray) -> None:
        """Append steps to a mode's files: bool (n, H, W) gray/bayer or (n, 3, H, W) rgb."""
        channels = [spikes[:, c] for c in range(3)] if mode == "rgb" else [spikes]
        for name, stream in zip(spike_files(mode), channels, strict=True):
            with open(self.root / name, "ab") as fh:
                fh.write(encode_frames(np.asarray(stream)).tobytes())

    def add_gt(self, step: int, image: np.ndarray) -> None:
        """Store the sharp render (H, W, 3) linear of ``step`` as ``gt/NNNNN.png``."""
        rel = f"gt/{step:05d}.png"
        write_image(self.root / rel, image)
        self.gt_paths[int(step)] = rel

    def start_blur_array(self, count: int) -> None:
        """Store the next ``count`` blur views in one float16 array ``blur/views.npy`` (N, H, W, 3) instead of
        one PNG each (for the paper's 1000 overlapping views; written in place, memory-mapped)."""
        (self.root / "blur").mkdir(exist_ok=True)
        k = self.intrinsics
        shape = (count, k.height, k.width, 3)
        self.blur_array = np.lib.format.open_memmap(self.root / BLUR_ARRAY, "w+", np.float16, shape)

    def add_blur(self, image: np.ndarray, pose: np.ndarray, step_start: int, step_end: int) -> None:
        """Store a conventional frame (H, W, 3) linear exposed over steps ``[step_start, step_end)``; pose at
        mid-exposure. It goes to ``blur/NNNNN.png``, or into the array after :meth:`start_blur_array`."""
        index = len(self.blur_frames)
        frame: dict[str, Any]
        if self.blur_array is None:
            rel = f"blur/{index:05d}.png"
            write_image(self.root / rel, image)
            frame = {"file_path": rel}
        else:
            self.blur_array[index] = np.clip(image, 0.0, 1.0)  # the range the PNGs hold
            frame = {"index": index}
        frame |= {"transform_matrix": _matrix(pose), "step_start": int(step_start)}
        mid = (step_start + step_end - 1) / 2  # the mean time of the renders in the exposure
        self.blur_frames.append({**frame, "step_end": int(step_end), "time": mid / self.fps})

    def add_test(self, image: np.ndarray, pose: np.ndarray) -> None:
        """Store a held-out view (H, W, 3) linear with its pose (4, 4)."""
        rel = f"test/{len(self.test_frames):05d}.png"
        write_image(self.root / rel, image)
        self.test_frames.append({"file_path": rel, "transform_matrix": _matrix(pose)})

    def finish(self, trajectory: Trajectory, config: dict, blur_fps: float | None) -> None:
        """Write the side files, ``config.yaml`` and, last, ``transforms.json``."""
        test = self.test_frames
        if blur_fps:
            if self.blur_array is None:
                header = self.header(fps=float(blur_fps), **split_fields(self.blur_frames, test))
                write_text_atomic(self.root / TRANSFORMS_BLUR, _dump(header, self.blur_frames + test))
            else:  # views in blur/views.npy: no nerfstudio split (nerfstudio cannot read the array)
                if len(self.blur_frames) != len(self.blur_array):
                    raise ValueError(
                        f"{len(self.blur_frames)} blur views added, {len(self.blur_array)} expected"
                    )
                self.blur_array.flush()
                self.blur_array = None
                header = self.header(fps=float(blur_fps), images_npy=BLUR_ARRAY)
                write_text_atomic(self.root / TRANSFORMS_BLUR, _dump(header, self.blur_frames))
        write_text_atomic(self.root / TRANSFORMS_TEST, _dump(self.header(), test))
        write_text_atomic(self.root / CONFIG, yaml.safe_dump(config, sort_keys=False))
        frames, keyframes = [], []
        for pose, time, step in zip(trajectory.poses, trajectory.times, trajectory.steps, strict=True):
            frame = {"step": int(step), "time": float(time), "transform_matrix": _matrix(pose)}
            if int(step) in self.gt_paths:
                frame["file_path"] = self.gt_paths[int(step)]
                keyframes.append(frame)
            frames.append(frame)
        for name, views in (
            (TRANSFORMS_GT, keyframes),
            (TRANSFORMS_TFP, self._tfp_keyframes(trajectory, keyframes, config)),
        ):
            if not views:  # no GT renders (an imported recording): no training images, no nerfstudio view
                continue
            write_text_atomic(self.root / name, _dump(self.header(**split_fields(views, test)), views + test))
        write_text_atomic(self.root / TRANSFORMS, _dump(self.header(), frames))

    def _tfp_keyframes(self, trajectory: Trajectory, keyframes: list[dict], config: dict) -> list[dict]:
        """TFP reconstructions (window 41) at the GT keyframes as ``tfp/NNNNN.png``, from the rgb stream if
        recorded, else the gray one (a Bayer-only dataset gives its raw mosaic, not demosaiced); each keyframe
        reads only its own window of the stream."""
        modes = list(config.get("colors", ["gray"]))
        mode = "rgb" if "rgb" in modes else modes[0]
        k, total, threshold = self.intrinsics, len(trajectory.steps), float(config["threshold"])
        index = {int(s): i for i, s in enumerate(trajectory.steps)}
        readers = [  # read only each keyframe's window: the stream may be long
            lambda a, b, path=self.root / name: read_dat(path, k.height, k.width, slice(a, b))
            for name in spike_files(mode)
        ]
        out = []
        for frame in keyframes:
            i, rel = index[frame["step"]], f"tfp/{frame['step']:05d}.png"
            image = np.stack(
                [frame_at(read, i, "tfp", TFP_WINDOW, threshold, total) for read in readers], axis=-1
            )
            write_image(self.root / rel, np.broadcast_to(image, (*image.shape[:2], 3)))
            out.append({**frame, "file_path": rel})
        return out


def work_dir(out: Path) -> Path:
    """The work folder of an output folder: ``<out>.partial``."""
    return out.with_name(out.name + ".partial")


def open_work(out: Path) -> tuple[Path, bool]:
    """Create (or reopen) the work folder ``<out>.partial`` marked as ours; returns it and whether it is new.

    A non-empty ``.partial`` folder without our dataset marker is someone else's: InputError, untouched.
    """
    work = work_dir(out)
    fresh = not work.exists()
    if not fresh and (not work.is_dir() or any(work.iterdir())) and folder_kind(work) != "dataset":
        raise InputError(
            "is in the way of the work folder and spikenerf did not write it; move it away", work
        )
    work.mkdir(parents=True, exist_ok=True)
    mark(work, "dataset")  # written first: a later run knows the folder is its own to resume or clean
    return work, fresh


def recover_replaced(out: Path) -> None:
    """Finish a :func:`~spikenerf.core.replacement.replace_dir` that was killed between its renames (call it
    holding the lock): the swapped-out ``.<out>.old`` is restored when ``out`` is missing, else deleted;
    only one spikenerf retired (``core/replacement.py``), never the user's own ``.<out>.old``."""
    recover_retired(out)

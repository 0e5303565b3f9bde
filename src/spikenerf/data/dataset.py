"""The dataset folder written by ``spikenerf simulate`` and read by ``spikenerf train`` (docs/formats.md).

``DIR/transforms.json`` (one frame per spike step), ``config.yaml``, ``spikes_<mode>.dat`` files, ``gt/``,
``blur/`` + ``transforms_blur.json`` and ``test/`` + ``transforms_test.json``. Images are 16-bit PNGs of
sRGB-encoded linear radiance clipped to [0, 1]; every array handed out is linear.
"""

from __future__ import annotations

import struct
import tokenize
from dataclasses import dataclass
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import yaml
from PIL import Image

from spikenerf.camera.io import count_frames, read_dat, rgb_paths
from spikenerf.camera.modes import COLORS
from spikenerf.core.atomic import write_bytes_atomic
from spikenerf.core.color import srgb_decode, srgb_encode
from spikenerf.core.errors import InputError, as_path, check_choice
from spikenerf.core.marker import folder_kind
from spikenerf.core.png16 import decode_png16, encode_png16, is_png16
from spikenerf.core.yamlio import load_yaml
from spikenerf.scenes.trajectory import Intrinsics, Trajectory
from spikenerf.scenes.transforms import (
    frames_of,
    intrinsics,
    number,
    pose,
    poses_at_once,
    read_transforms,
    scene_box,
)

TRANSFORMS, TRANSFORMS_BLUR, TRANSFORMS_TEST, CONFIG = (
    "transforms.json",
    "transforms_blur.json",
    "transforms_test.json",
    "config.yaml",
)
#: nerfstudio views of the folder (written by the writer; never read by spikenerf)
TRANSFORMS_GT, TRANSFORMS_TFP = "transforms_gt.json", "transforms_tfp.json"
MODES = COLORS  # the colour modes a dataset may hold (camera.model.ColorMode)
#: blur views stored as one array (named by ``images_npy`` in transforms_blur.json; frames carry ``index``)
BLUR_ARRAY = "blur/views.npy"
_MISSING = "missing file (not a dataset folder written by `spikenerf simulate`?)"
#: a ``simulate`` work folder (``OUT.partial``) given as a dataset
UNFINISHED = "an unfinished `spikenerf simulate` or `import` work folder: run the same command to resume"


def spike_files(mode: str) -> list[str]:
    """File names of one colour mode's stream: one file, or ``spikes_rgb_{r,g,b}.dat`` for ``rgb``."""
    check_choice(mode, MODES, "mode", "colour mode")
    return [p.name for p in rgb_paths("spikes_rgb")] if mode == "rgb" else [f"spikes_{mode}.dat"]


def write_image(path: str | Path, linear: np.ndarray) -> None:
    """Write linear radiance (H, W, 3) atomically as a 16-bit PNG of its sRGB encoding (clipped to [0, 1])."""
    write_bytes_atomic(path, encode_png16(srgb_encode(np.asarray(linear, dtype=np.float64))))


def read_display(path: Path) -> np.ndarray:
    """An image file's display values in [0, 1]: float64 (H, W, 3) (16-bit exactly, 8-bit via imageio)."""
    try:
        data = path.read_bytes()
        arr = decode_png16(data, path) if is_png16(data) else np.asarray(iio.imread(data))
    except (OSError, ValueError, SyntaxError, struct.error, Image.DecompressionBombError) as err:
        # (Pillow raises SyntaxError, struct.error or DecompressionBombError for a broken or huge PNG)
        if isinstance(err, InputError):
            raise
        raise InputError(f"cannot read image ({err})", path=path) from err
    arr = arr[..., None] if arr.ndim == 2 else arr
    if arr.ndim != 3 or arr.dtype not in (np.uint8, np.uint16):
        raise InputError(
            f"expected an 8/16-bit gray or RGB(A) image, found {arr.dtype} {arr.shape}", path=path
        )
    x = arr.astype(np.float64) / np.iinfo(arr.dtype).max
    return np.repeat(x[..., :1], 3, -1) if x.shape[-1] <= 2 else x[..., :3]  # alpha is dropped


def load_image(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """Read an image as linear RGB (H, W, 3) float32; ``size = (H, W)`` is checked when given."""
    image = read_display(path)
    if size is not None and image.shape[:2] != size:
        raise InputError(
            f"image is {image.shape[0]}×{image.shape[1]} (H×W), expected {size[0]}×{size[1]}", path
        )
    return srgb_decode(image).astype(np.float32)


# ------------------------------------------------------------------------------------------ containers
@dataclass(frozen=True)
class PosedImages:
    """Images with poses: poses (N, 4, 4) float32 c2w, images (N, H, W, 3) linear (float32; blur views kept
    in ``blur/views.npy`` are a read-only float16 memory map), steps (N,) int64 spike steps or None,
    step_ranges (N, 2) int64 exposure ``[start, end)`` or None."""

    poses: np.ndarray
    images: np.ndarray
    steps: np.ndarray | None = None
    step_ranges: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.poses)


@dataclass(frozen=True)
class SpikeDataset:
    """A loaded dataset folder (see :func:`load_dataset`); spike streams are read on demand."""

    root: Path
    intrinsics: Intrinsics
    trajectory: Trajectory
    threshold: float
    scene_box: np.ndarray
    near: float
    far: float
    config: dict
    modes: list[str]
    gt: PosedImages
    blur: PosedImages | None
    test: PosedImages

    def spikes(self, mode: str | None = None, frames: slice | int | None = None) -> np.ndarray:
        """uint8 0/1 spikes of ``mode`` (default: the first): (T, H, W) gray/bayer, (T, 3, H, W) rgb.

        ``frames`` selects a range of steps; only those are read from the memory-mapped file.
        """
        mode = self.modes[0] if mode is None else mode
        if mode not in self.modes:
            raise InputError(
                f"mode: colour mode {mode!r} is not in this dataset (has {', '.join(self.modes)})",
                self.root,
                param="mode",
            )
        h, w = self.intrinsics.height, self.intrinsics.width
        streams = [read_dat(self.root / name, h, w, frames) for name in spike_files(mode)]
        return np.stack(streams, axis=1) if mode == "rgb" else streams[0]


def near_far(poses: np.ndarray, scene_box: np.ndarray) -> tuple[float, float]:
    """Ray bounds that enclose the box's bounding sphere from every camera centre of ``poses`` (N, 4, 4)."""
    center, radius = scene_box.mean(0), float(np.linalg.norm(scene_box[1] - scene_box[0]) / 2)
    dist = np.linalg.norm(np.asarray(poses)[:, :3, 3] - center, axis=-1)
    return max(float(dist.min()) - radius, 0.05), float(dist.max()) + radius


def recording_in(path: Path) -> str | None:
    """What to say where a camera's recording was given for a dataset: ``path`` is a ``.dat`` file, or a
    folder without ``transforms.json`` that holds one (not a dataset's own ``spikes_*.dat``); else None."""
    if path.is_file():
        found = [path] if path.suffix.lower() == ".dat" else []
    elif path.is_dir():
        found = sorted(p for p in path.glob("*.dat") if not p.name.startswith("spikes_"))
    else:
        found = []
    if not found:
        return None
    what = "is a spike recording" if path.is_file() else f"holds a spike recording ({found[0].name})"
    return f"{what}, not a dataset folder: make one with `spikenerf import {found[0]}`"


def read_mapping(path: Path, fmt: str = "JSON") -> dict:
    """The top-level mapping of a dataset folder's JSON (read by ``scenes.transforms.read_transforms``) or
    YAML (``fmt``) file; InputError when the file is missing, malformed or not a mapping."""
    if fmt == "JSON":
        return read_transforms(path, missing=_MISSING)
    if not path.is_file():
        raise InputError(_MISSING, path=path)
    try:
        data = load_yaml(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        raise InputError(f"malformed YAML ({err})", path=path) from err
    if not isinstance(data, dict):
        raise InputError(f"expected a mapping at the top level, found {type(data).__name__}", path=path)
    return data


def _pose(obj: dict, path: Path, where: str) -> np.ndarray:
    """``obj["transform_matrix"]`` of the frame ``where`` (``"frames[3]."``), checked by the one reader."""
    if "transform_matrix" not in obj:
        raise InputError(f"missing field {where}'transform_matrix'", path=path)
    return pose(obj["transform_matrix"], f"{where}transform_matrix", path)


def _file(root: Path, obj: dict, path: Path, where: str) -> Path:
    rel = obj.get("file_path")
    if not isinstance(rel, str) or not rel:
        raise InputError(
            f"field {where}'file_path': expected a relative path string, found {rel!r}", path=path
        )
    target = (root / rel).resolve()
    if Path(rel).is_absolute() or not target.is_relative_to(root.resolve()):
        raise InputError(f"field {where}'file_path' {rel!r} escapes the dataset folder {root}", path=path)
    if not target.is_file():
        raise InputError(f"field {where}'file_path': image {rel!r} not found", path=path)
    return target


def _frames(data: dict, path: Path) -> list[dict]:
    return frames_of(data, path, empty=True)


def _check_camera(data: dict, path: Path, k: Intrinsics | None) -> Intrinsics:
    found = intrinsics(data, path)
    if k is not None and (found.width, found.height) != (k.width, k.height):
        raise InputError(
            f"image size {found.width}×{found.height} differs from transforms.json's "
            f"{k.width}×{k.height} (W×H)",
            path=path,
        )
    if k is not None and found.distortion != k.distortion:  # (one camera: its lens too)
        lenses = [lens.describe() if lens else "none" for lens in (found.distortion, k.distortion)]
        raise InputError("lens distortion {} differs from transforms.json's {}".format(*lenses), path=path)
    return found


def _posed(root: Path, name: str, k: Intrinsics, blur: bool) -> PosedImages | None:
    path = root / name
    if not path.exists():
        return None
    data = read_mapping(path)
    _check_camera(data, path, k)
    frames = _frames(data, path)
    array = (
        _image_array(root, data, path, (len(frames), k.height, k.width, 3)) if "images_npy" in data else None
    )
    poses, images, ranges, kept = [], [], [], []
    train = data.get("train_filenames")  # a nerfstudio view lists its held-out frames too: skip them
    for i, f in enumerate(frames):
        if isinstance(train, list) and f.get("file_path") not in train:
            continue
        kept.append(i)
        where = f"frames[{i}]."
        poses.append(_pose(f, path, where))
        if array is None:
            images.append(load_image(_file(root, f, path, where), (k.height, k.width)))
        elif f.get("index") != i:
            raise InputError(f"field {where}'index': expected {i}, found {f.get('index')!r}", path=path)
        if blur:
            s0, s1 = (number(f, key, path, where) for key in ("step_start", "step_end"))
            if not (s0 == int(s0) and s1 == int(s1) and 0 <= s0 < s1 < 2**63):  # (int64 steps)
                raise InputError(
                    f"fields {where}step_start/step_end: expected integers 0 ≤ a < b < 2⁶³, found {s0}, {s1}",
                    path=path,
                )
            ranges.append((int(s0), int(s1)))
    if array is None:
        return _stack(k, poses, images, None, ranges if blur else None)
    n = len(poses)
    step_ranges = np.asarray(ranges, np.int64).reshape(n, 2) if blur else None
    array = array if n == len(frames) else array[kept]  # the images of the frames kept, as their poses
    return PosedImages(np.asarray(poses, np.float32).reshape(n, 4, 4), array, None, step_ranges)


def _image_array(root: Path, data: dict, path: Path, shape: tuple[int, ...]) -> np.ndarray:
    """The memory-mapped image array named by ``images_npy``: float16/float32 of ``shape`` (N, H, W, 3)."""
    target = _file(root, {"file_path": data["images_npy"]}, path, "")
    try:
        array = np.load(target, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError, tokenize.TokenError) as err:  # (EOF, TokenError: a cut header)
        raise InputError(f"cannot read the image array ({err})", path=target) from err
    if array.shape != shape or array.dtype not in (np.float16, np.float32):
        raise InputError(
            f"expected a float16/float32 array of shape {shape}, found {array.dtype} {array.shape}", target
        )
    return array


def _stack(
    k: Intrinsics, poses: list, images: list, steps: list | None = None, ranges: list | None = None
) -> PosedImages:
    """PosedImages from lists (float32 poses and images, int64 steps and ranges)."""
    n = len(poses)
    return PosedImages(
        np.asarray(poses, np.float32).reshape(n, 4, 4),
        np.asarray(images, np.float32).reshape(n, k.height, k.width, 3),
        None if steps is None else np.asarray(steps, np.int64).reshape(n),
        None if ranges is None else np.asarray(ranges, np.int64).reshape(n, 2),
    )


def load_dataset(root: str | Path, train_images: bool = True) -> SpikeDataset:
    """Load and validate a dataset folder (every problem is an InputError naming the file and field).

    Args:
        root: the dataset folder.
        train_images: decode the training images, the sharp GT renders and the blur frames; False leaves
            ``gt`` empty (its paths still checked) and ``blur`` None, for ``eval`` and ``render``, which use
            the test views only (a 400×400 dataset's 100 GT PNGs take seconds to decode).
    Returns:
        A :class:`SpikeDataset`: per-step trajectory, intrinsics, threshold, scene box, near/far, the config,
        the colour modes present, GT renders (with their steps), blur frames (or None) and test views.
    """
    root = as_path(root, "root")
    if not root.is_dir():
        if recording := recording_in(root):
            raise InputError(recording, path=root)
        raise InputError(
            "is a file, not a dataset folder" if root.exists() else "dataset folder not found", path=root
        )
    tpath = root / TRANSFORMS
    if not tpath.exists() and root.name.endswith(".partial"):
        raise InputError(UNFINISHED, path=root)
    if not tpath.exists() and (recording := recording_in(root)):
        raise InputError(recording, path=root)
    if not tpath.exists() and (kind := folder_kind(root)) not in (None, "dataset"):  # another of ours
        raise InputError(f"is a {kind} folder, not a dataset folder", path=root)
    data = read_mapping(tpath)
    k = _check_camera(data, tpath, None)
    fps = number(data, "fps", tpath, positive=True)
    near, far = number(data, "near", tpath, positive=True), number(data, "far", tpath, positive=True)
    if near >= far:
        raise InputError(f"fields 'near', 'far': expected near < far, found {near}, {far}", path=tpath)
    box = scene_box(data, tpath, required=True)
    frames = _frames(data, tpath)
    if not frames:
        raise InputError("field 'frames' is empty: expected one frame per spike step", path=tpath)
    poses, times, steps, gt_poses, gt_images, gt_steps = [], [], [], [], [], []
    at_once = poses_at_once([f.get("transform_matrix") for f in frames])  # else one by one, naming a bad one
    for i, f in enumerate(frames):
        where = f"frames[{i}]."
        poses.append(_pose(f, tpath, where) if at_once is None else at_once[i])
        times.append(number(f, "time", tpath, where))
        if len(times) > 1 and not times[-1] > times[-2]:
            raise InputError(f"field {where}'time': expected increasing times, found {times[-1]}", tpath)
        step = number(f, "step", tpath, where)
        if step != int(step) or not abs(step) < 2**63 or (steps and step <= steps[-1]):  # (int64 steps)
            raise InputError(f"field {where}'step': expected increasing integers, found {step}", path=tpath)
        steps.append(int(step))
        if "file_path" in f:
            image = _file(root, f, tpath, where)
            if train_images:
                gt_images.append(load_image(image, (k.height, k.width)))
                gt_poses.append(poses[-1])
                gt_steps.append(int(step))
    traj = Trajectory(np.stack(poses), np.asarray(times), np.asarray(steps, np.int64), fps)
    config = _load_config(root, k, fps)
    modes = list(config["colors"])
    for mode in modes:
        for name in spike_files(mode):
            n = count_frames(root / name, k.height, k.width)
            if n != len(frames):
                raise InputError(f"holds {n} steps but transforms.json has {len(frames)} frames", root / name)
    return SpikeDataset(
        root=root,
        intrinsics=k,
        trajectory=traj,
        threshold=float(config["threshold"]),
        scene_box=box,
        near=near,
        far=far,
        config=config,
        modes=modes,
        gt=_stack(k, gt_poses, gt_images, gt_steps),
        blur=_posed(root, TRANSFORMS_BLUR, k, blur=True) if train_images else None,
        test=_posed(root, TRANSFORMS_TEST, k, blur=False) or _stack(k, [], []),
    )


def _load_config(root: Path, k: Intrinsics, fps: float) -> dict:
    path = root / CONFIG
    config = read_mapping(path, "YAML")
    for key, want in (("spike_h", k.height), ("spike_w", k.width), ("fps", fps)):
        if number(config, key, path, positive=True) != want:
            raise InputError(f"field {key!r} is {config[key]}, but transforms.json says {want}", path=path)
    number(config, "threshold", path, positive=True)
    colors = config.get("colors")
    if not isinstance(colors, list) or not colors or any(c not in MODES for c in colors):
        raise InputError(
            f"field 'colors': expected a non-empty list of {'/'.join(MODES)}, found {colors!r}", path
        )
    if config.get("layout", "spikecv") != "spikecv":  # (reconstruct and info of a .dat would read it so)
        raise InputError(
            f"field 'layout': a dataset's spike files are stored in the spikecv layout (rows bottom-up), "
            f"found {config['layout']!r}",
            path,
        )
    return config

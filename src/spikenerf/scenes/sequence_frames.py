"""The frames of an image sequence's transforms.json: the listed frames selected (``frame_range``), their
images found and checked (one size), their poses, the camera and any scene box, validated before any
simulation runs (:class:`~spikenerf.scenes.sequence.SequenceSource` reads them; ``docs/sequence.md``)."""

from __future__ import annotations

import contextlib
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError, is_integer, parse_range
from spikenerf.scenes import transforms
from spikenerf.scenes.image_io import find_image, image_size
from spikenerf.scenes.trajectory import Intrinsics

#: the stop of an open range ``(A, OPEN_END)`` (Python slices clamp it to the number of frames).
OPEN_END = sys.maxsize
#: a selection of the listed frames: a slice, or ``(start, stop)`` as a Python slice's bounds
FrameRange = slice | tuple[int, int] | str


def select_range(count: int, frame_range: FrameRange | None, path: Path | None = None) -> range:
    """The listed-frame indices ``range(count)[A:B]``; an empty selection, or an A or B past either end of the
    ``count`` frames (which a Python slice would clip without a word), is an :class:`InputError`.

    ``frame_range`` is a slice, ``(A, B)`` or the text ``"A:B"`` (``core.errors.parse_range``); InputErrors
    name ``frame_range``."""
    if frame_range is None:
        return range(count)
    if isinstance(frame_range, str):
        frame_range = parse_range(frame_range, "frame_range")
    pair = isinstance(frame_range, (tuple, list)) and len(frame_range) == 2
    if not (isinstance(frame_range, slice) or pair) or not all(
        v is None or is_integer(v) for v in _bounds(frame_range)
    ):
        raise InputError(
            f"frame_range must be a slice, (start, stop) integers or 'A:B', found {frame_range!r}",
            path=path,
            param="frame_range",
        )
    if isinstance(frame_range, slice) and frame_range.step not in (None, 1):
        raise InputError(
            f"frame_range: a step is not supported, found {frame_range!r}", path=path, param="frame_range"
        )
    start, stop = _bounds(frame_range)
    shown = repr(f"{'' if start is None else start}:{'' if stop in (None, OPEN_END) else stop}")
    outside = [v for v in (start, stop) if v not in (None, OPEN_END) and not -count <= v <= count]
    if outside:
        raise InputError(
            f"frame_range {shown}: {outside[0]} is outside the {count} listed frames (-{count} to {count})",
            path=path,
            param="frame_range",
        )
    selected = range(count)[slice(start, stop)]
    if len(selected) == 0:
        raise InputError(
            f"frame_range {shown} selects no frames out of {count} listed",
            path=path,
            param="frame_range",
        )
    return selected


def _bounds(frame_range: slice | tuple | list) -> tuple:
    """(start, stop) of a slice, or of a pair as it is (its length checked by the caller)."""
    if isinstance(frame_range, slice):
        return frame_range.start, frame_range.stop
    return tuple(frame_range) if len(frame_range) == 2 else (None, None)


@dataclass(frozen=True)
class SequenceFrames:
    """Listed frames of a transforms.json, validated.

    Attributes:
        path: the JSON file. indices: (N,) positions of the selected frames in the file's ``frames``.
        images: N image paths. poses: (N, 4, 4) float64 c2w of the selected frames.
        all_poses: (M, 4, 4) poses of every frame of the path (``train_filenames``'s where the file has one
        and the path is asked for). intrinsics: the camera at the images' size.
        scene_box: (2, 3) from a ``scene_box``/``aabb`` key, or None.
    """

    path: Path
    indices: np.ndarray
    images: list[Path]
    poses: np.ndarray
    all_poses: np.ndarray
    intrinsics: Intrinsics
    scene_box: np.ndarray | None


def load_sequence(
    transforms_json: str | Path, frame_range: FrameRange | None = None, path_only: bool = True
) -> SequenceFrames:
    """Read and validate a transforms.json: every listed pose, and the images of the selected frames. With
    ``path_only`` a file with ``train_filenames`` gives only the frames that list names (its path):
    ``frame_range`` counts those, while ``indices`` and every error name a frame by its place in the
    file's ``frames``."""
    path = Path(transforms_json)
    meta = transforms.read_transforms(path)
    try:
        frames = transforms.frames_of(meta, path, ("file_path", "transform_matrix"))
    except InputError as err:
        raise _dataset_hint(err, meta, path) from None
    every_pose = transforms.frame_poses(meta, path)
    path_frames = _training_frames(meta, path) if path_only else np.arange(len(frames))
    indices = path_frames[np.asarray(select_range(len(path_frames), frame_range, path), dtype=np.int64)]
    root = path.parent
    images = [find_image(root, frames[i]["file_path"], f"frames[{i}].file_path", path) for i in indices]
    size = image_size(images[0])
    for i, image in zip(indices[1:], images[1:], strict=True):
        found = image_size(image)
        if found != size:
            raise InputError(
                f"frames[{i}].file_path: image is {found[0]}×{found[1]} but frames[{indices[0]}] is "
                f"{size[0]}×{size[1]}: all images must have the same size",
                path=path,
            )
    intrinsics = transforms.intrinsics(meta, path, size)
    return SequenceFrames(
        path,
        indices,
        images,
        every_pose[indices],
        every_pose[path_frames],
        intrinsics,
        transforms.scene_box(meta, path),
    )


def _training_frames(meta: dict, path: Path) -> np.ndarray:
    """(N,) int64 places in ``meta["frames"]`` (checked already: a list of objects) of the frames its
    ``train_filenames`` lists, where it has that list (a nerfstudio view, such as a spikenerf dataset's
    ``transforms_gt.json``, lists its held-out test views among the frames too: as part of the path they
    would make the camera jump); else of every frame."""
    train, frames = meta.get("train_filenames"), meta["frames"]
    if not isinstance(train, list):
        return np.arange(len(frames), dtype=np.int64)
    listed = set(map(str, train))
    kept = [i for i, f in enumerate(frames) if str(f.get("file_path")) in listed]
    if not kept:
        raise InputError(
            f"field 'train_filenames' lists none of the {len(frames)} frames' file_path: no frame is left "
            "for the path (remove the list to use every frame)",
            path=path,
        )
    return np.asarray(kept, dtype=np.int64)


def _dataset_hint(err: InputError, meta: dict, path: Path) -> InputError:
    """``err`` with a hint added where a frame without ``file_path`` is one of a spikenerf dataset (frames
    with a ``step``, or a ``config.yaml`` of spikenerf beside the file): it has an image every gt_every
    steps only (``simulate``'s option)."""
    if not err.message.endswith("missing field 'file_path'"):
        return err
    frames = meta["frames"]
    missing = next(f for f in frames if "file_path" not in f)
    config = path.parent / "config.yaml"
    ours, text = "step" in missing, ""
    with contextlib.suppress(OSError, UnicodeDecodeError):
        text = config.read_text(encoding="utf-8") if config.is_file() else ""
    if "\nimported:" in f"\n{text}" or "noise: recorded" in text:  # an imported recording: spikes only
        return InputError(
            f"{err.message}: this is an imported recording's dataset, spikes without images; it cannot be "
            "read as an image sequence (train on it instead)",
            path=path,
        )
    if not (ours or "spikenerf_version:" in text):
        return err
    return InputError(
        f"{err.message}: a spikenerf dataset stores an image only every few steps; read its "
        "transforms_gt.json, which lists them as a sequence, or simulate it with gt_every 1",
        path=path,
        param="gt_every",
    )

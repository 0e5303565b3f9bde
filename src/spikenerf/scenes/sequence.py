"""Import an image sequence with poses (NeRF "Blender" ``transforms.json``) as a spike-simulation source.

The frames are taken in the order they are listed (the trajectory order). Source frame ``i`` covers spike
steps ``i·s … i·s + s − 1`` (``s = steps_per_frame``): held by default, or blended linearly towards frame
``i + 1`` in intensity with a slerp/lerp pose when ``interpolate=True``. Colour handling is described in
:mod:`spikenerf.scenes.image_io`; the user guide is ``docs/sequence.md``.
"""

from __future__ import annotations

import contextlib
import sys
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError, is_finite, is_integer, parse_range
from spikenerf.core.limits import check_memory
from spikenerf.scenes import transforms
from spikenerf.scenes.image_io import find_image, image_size, load_frame
from spikenerf.scenes.poses import interpolate_poses
from spikenerf.scenes.trajectory import Intrinsics, Trajectory

#: the stop of an open range ``(A, OPEN_END)`` (Python slices clamp it to the number of frames).
OPEN_END = sys.maxsize
#: a selection of the listed frames: a slice, or ``(start, stop)`` as a Python slice's bounds
FrameRange = slice | tuple[int, int] | str
#: half-size of an estimated scene box, as a fraction of the nearest camera's distance to the box centre.
SCENE_BOX_FACTOR = 0.5
#: cameras whose positions all lie within this fraction of their distance to the estimated centre do not
#: move (no parallax): the estimated scene box is then a guess, which is warned of
STILL_FRACTION = 1e-3
#: a camera this many times further from the cameras' median position than their median distance to it is
#: named in a warning (a wrong translation, e.g. other units)
FAR_FACTOR = 1000.0
#: peak bytes per spike step while a source builds its step schedule and poses (measured about 740)
SCHEDULE_BYTES = 1024


# ----------------------------------------------------------------------------------------------- ranges
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


def step_schedule(
    n_frames: int, steps_per_frame: int, interpolate: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which source frames each spike step shows.

    Returns:
        frame (T,) int64 = k // steps_per_frame, next (T,) int64 = min(frame + 1, n − 1), and the blend
        weight alpha (T,) float64 of ``next`` (0 when holding; the last frame is held); T = n · steps.
    """
    k = np.arange(n_frames * steps_per_frame, dtype=np.int64)
    frame = k // steps_per_frame
    nxt = np.minimum(frame + 1, n_frames - 1)
    alpha = (k % steps_per_frame) / steps_per_frame if interpolate else np.zeros(len(k))
    return frame, nxt, np.where(frame == nxt, 0.0, alpha)


def blend_frames(a: np.ndarray, b: np.ndarray, alpha: float) -> np.ndarray:
    """Linear blend ``(1 − alpha)·a + alpha·b`` of two (H, W, 3) linear frames, float32."""
    return ((1.0 - alpha) * a + alpha * b).astype(np.float32)


# ------------------------------------------------------------------------------------------ scene box
def estimate_scene_box(
    poses: np.ndarray, factor: float = SCENE_BOX_FACTOR, path: Path | None = None
) -> np.ndarray:
    """Axis-aligned box around the region the cameras look at.

    The centre is the least-squares point closest to all optical axes (camera centre, −Z direction); the
    half-size is ``factor`` × the nearest camera's distance to it. When the axes are (nearly) parallel or
    the point lies behind the cameras, the centre is put ahead of the mean camera by the cameras' spread
    (at least 1 unit) — a rough guess; give a ``scene_box`` key then.

    A warning (naming ``path``) says when the cameras do not move (no parallax: the box is a guess) or one
    lies orders of magnitude further than the others (``FAR_FACTOR``: a wrong pose, naming its frame); an
    InputError when no finite box comes out.

    Args:
        poses: (N, 4, 4) camera-to-world of ``frames[0…N−1]``. Returns: (2, 3) float64 (min, max).
    """
    box, converged = _estimate(poses, factor)
    _check_cameras(poses, box, path, converged)
    return box


def _estimate(poses: np.ndarray, factor: float) -> tuple[np.ndarray, bool]:
    """:func:`estimate_scene_box`'s box (2, 3) of ``poses`` (N, 4, 4), and whether the optical axes meet
    ahead of the cameras (else the centre is a guess)."""
    origins = poses[:, :3, 3]
    dirs = -poses[:, :3, 2] / np.linalg.norm(poses[:, :3, 2], axis=-1, keepdims=True)
    proj = np.eye(3) - dirs[:, :, None] * dirs[:, None, :]  # (N, 3, 3) projections orthogonal to each axis
    with np.errstate(over="ignore", invalid="ignore"):  # (positions near the float limit: refused later)
        a, b = proj.sum(0), np.einsum("nij,nj->i", proj, origins)
        centre, converged = None, False
        if np.linalg.eigvalsh(a / len(poses)).min() > 1e-3:
            centre = np.linalg.solve(a, b)
            converged = bool(np.mean(np.sum((centre - origins) * dirs, axis=-1)) > 0)
            centre = centre if converged else None
        if centre is None:
            mean_dir = dirs.mean(0)
            mean_dir /= max(np.linalg.norm(mean_dir), 1e-12)
            spread = float(np.linalg.norm(origins - origins.mean(0), axis=-1).max())
            centre = origins.mean(0) + mean_dir * max(2.0 * spread, 1.0)
        half = factor * float(np.linalg.norm(origins - centre, axis=-1).min())
        half = half if half > 0 else 1.0
        return np.stack([centre - half, centre + half]), converged


def _check_cameras(poses: np.ndarray, box: np.ndarray, path: Path | None, converged: bool) -> None:
    """Warn of a few cameras far off the others (beyond :data:`FAR_FACTOR` × the others' typical offset
    and their typical distance to the centre of the others' box: cameras at rest with a little pose noise
    do not make a moving one "far") or of cameras that stand still: within :data:`STILL_FRACTION` of their
    distance to what they face where the axes meet (``converged``), else (that distance is a guess) at one
    point; refuse a box that is not finite."""
    origins = poses[:, :3, 3]
    if not np.isfinite(box).all():
        frame = int(np.argmax(np.abs(origins).max(axis=1)))
        raise InputError(
            f"cannot estimate a scene box: the camera positions overflow (frames[{frame}] lies at "
            f"{np.abs(origins[frame]).max():.3g}); fix its transform_matrix or give a 'scene_box' key",
            path=path,
        )
    where = "" if path is None else f"{path}: "
    shown = f"[{', '.join(f'{v:.3g}' for v in box[0])}] to [{', '.join(f'{v:.3g}' for v in box[1])}]"
    with np.errstate(over="ignore", invalid="ignore"):
        offset = np.linalg.norm(origins - np.median(origins, axis=0), axis=-1)
        spread = float(np.linalg.norm(origins - origins.mean(0), axis=-1).max())
        distance = float(np.linalg.norm(origins.mean(0) - box.mean(0)))
    moved = offset[offset > 0]
    typical = float(np.median(moved)) if len(moved) else 0.0
    far = np.flatnonzero(~(offset <= FAR_FACTOR * typical)) if typical > 0 else np.zeros(0, dtype=np.int64)
    if 0 < len(far) < len(origins) / 2:  # against the scene the others see, too
        rest = np.setdiff1d(np.arange(len(origins)), far)
        others, _ = _estimate(poses[rest], SCENE_BOX_FACTOR)
        with np.errstate(over="ignore", invalid="ignore"):
            typical = max(typical, float(np.median(np.linalg.norm(origins[rest] - others.mean(0), axis=-1))))
        far = far[~(offset[far] <= FAR_FACTOR * typical)]
    if 0 < len(far) < len(origins) / 2:
        first = int(far[np.argmax(offset[far])])
        more = f" (and {len(far) - 1} more)" if len(far) > 1 else ""
        warnings.warn(
            f"{where}the camera of frames[{first}]{more} lies {offset[first]:.3g} from the cameras' median "
            f"position, over {FAR_FACTOR:g}× their typical {typical:.3g}: a wrong transform_matrix? The "
            f"estimated scene box is {shown}; fix the pose or give a 'scene_box' key",
            stacklevel=3,
        )
    elif len(origins) > 1 and not spread > (  # (one frame: a still on purpose)
        STILL_FRACTION * distance if converged else 1e-9 * max(1.0, float(np.abs(origins).max()))
    ):  # (axes that do not meet: the distance is a guess, so only cameras at one point are said)
        warnings.warn(
            f"{where}the {len(origins)} cameras do not move (all within {spread:.3g} of their mean position, "
            f"{distance:.3g} from what they face): no parallax, so the estimated scene box {shown} is a "
            "guess; give a 'scene_box' key",
            stacklevel=3,
        )


# --------------------------------------------------------------------------------- transforms.json
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


# --------------------------------------------------------------------------------------- the source
def _output_size(native: tuple[int, int], width: int | None, height: int | None) -> tuple[int, int]:
    for name, value in (("width", width), ("height", height)):
        if value is not None and not (is_integer(value) and 0 < value < 2**31):  # (10**400: OverflowError)
            raise InputError(
                f"{name}: expected a positive integer below 2**31, found {value!r:.60}", param=name
            )
    w0, h0 = native
    if width is None and height is None:
        return native
    if width is None:
        width = max(1, round(w0 * height / h0))
    if height is None:
        height = max(1, round(h0 * width / w0))
    return width, height


class SequenceSource:
    """A :class:`~spikenerf.scenes.base.FrameSource` over an image sequence with poses.

    Args:
        transforms_json: NeRF-Blender JSON; images are resolved relative to its folder.
        width, height: output size (one alone keeps the aspect ratio); None = the images' size.
        frame_range: a slice, (start, stop) or "A:B" of the listed frames (``core.errors.parse_range``).
        steps_per_frame: spike steps per source frame, T = frames × steps_per_frame.
        interpolate: blend intensity and interpolate poses between neighbouring frames instead of holding.
        eval_views: a second transforms.json of held-out views with ground truth (the test split).
        fps: spike readout rate, step k is at time k / fps. name: scene name (default: the JSON's folder).

    Attributes:
        frame_images: source image paths; frame_poses (F, 4, 4): their poses; frame_indices (F,): their
        positions in ``frames``; native_size: (width, height) of the images; plus the protocol attributes.
    """

    _CACHE = 4

    def __init__(
        self,
        transforms_json: Path,
        width: int | None = None,
        height: int | None = None,
        frame_range: FrameRange | None = None,
        steps_per_frame: int = 1,
        interpolate: bool = False,
        eval_views: Path | None = None,
        fps: float = 40000.0,
        name: str | None = None,
    ) -> None:
        if isinstance(steps_per_frame, bool) or not isinstance(steps_per_frame, int) or steps_per_frame < 1:
            found = f"found {steps_per_frame!r}"
            raise InputError(f"steps_per_frame: expected an integer ≥ 1, {found}", param="steps_per_frame")
        if not is_finite(fps) or fps <= 0:  # (10**400 is no float: math.isfinite raises on it)
            raise InputError(f"fps: expected a positive number, found {fps!r}", param="fps")
        path = Path(transforms_json)
        seq = load_sequence(path, frame_range)
        # the schedule and its poses are built here, before any simulate-wide estimate: bound them first
        check_memory(len(seq.images) * steps_per_frame * SCHEDULE_BYTES, "steps_per_frame")
        self.native_size = (seq.intrinsics.width, seq.intrinsics.height)
        size = _output_size(self.native_size, width, height)
        self.name = name or path.resolve().parent.name or "sequence"
        self.intrinsics = seq.intrinsics if size == self.native_size else seq.intrinsics.scaled(*size)
        self.frame_images, self.frame_poses, self.frame_indices = seq.images, seq.poses, seq.indices
        self.steps_per_frame, self.interpolate = steps_per_frame, bool(interpolate)
        self._frame, self._next, self._alpha = step_schedule(len(seq.images), steps_per_frame, interpolate)
        poses = interpolate_poses(seq.poses[self._frame], seq.poses[self._next], self._alpha)
        steps = np.arange(len(self._frame), dtype=np.int64)
        self.trajectory = Trajectory(poses, steps / float(fps), steps, float(fps))
        self.scene_box = (
            seq.scene_box if seq.scene_box is not None else estimate_scene_box(seq.all_poses, path=path)
        )
        self._eval = None if eval_views is None else self._check_eval(Path(eval_views))
        self._cache: dict[int, np.ndarray] = {}
        self._test: tuple[np.ndarray, np.ndarray] | None = None

    def _check_eval(self, path: Path) -> SequenceFrames:
        """Validate the held-out views now (before any simulation runs): same camera as the sequence."""
        seq = load_sequence(path, path_only=False)  # held-out views: every frame the file lists
        cam, ours = seq.intrinsics.scaled(self.intrinsics.width, self.intrinsics.height), self.intrinsics
        found, want = (cam.fl_x, cam.fl_y, cam.cx, cam.cy), (ours.fl_x, ours.fl_y, ours.cx, ours.cy)
        if cam.distortion != ours.distortion:
            lenses = [k.distortion.describe() if k.distortion else "none" for k in (cam, ours)]
            raise InputError("eval views use another lens: {}, the sequence's is {}".format(*lenses), path)
        if not np.allclose(found, want, rtol=1e-3, atol=1e-3):
            raise InputError(
                f"eval views use another camera: at {ours.width}×{ours.height} their (fl_x, fl_y, cx, cy) is "
                f"{tuple(round(v, 3) for v in found)}, the sequence's is {tuple(round(v, 3) for v in want)}",
                path=path,
            )
        return seq

    def _image(self, index: int) -> np.ndarray:
        if index not in self._cache:
            if len(self._cache) >= self._CACHE:
                self._cache.pop(next(iter(self._cache)))
            size = (self.intrinsics.width, self.intrinsics.height)
            self._cache[index] = load_frame(self.frame_images[index], size)
        return self._cache[index]

    def frames(self, steps: Sequence[int]) -> Iterator[np.ndarray]:
        """Yield the linear frame (H, W, 3) float32 of each trajectory step, in order (white background)."""
        for step in steps:
            k = int(step)
            if not 0 <= k < len(self._frame):
                raise IndexError(f"step {k} outside the trajectory's {len(self._frame)} steps")
            frame = self._image(int(self._frame[k]))
            alpha = float(self._alpha[k])
            yield frame.copy() if alpha == 0 else blend_frames(frame, self._image(int(self._next[k])), alpha)

    @property
    def test_view_count(self) -> int:
        """How many held-out views ``eval_views`` gives (0 without them)."""
        return 0 if self._eval is None else len(self._eval.images)

    def test_views(self) -> tuple[np.ndarray, np.ndarray]:
        """Held-out poses (N, 4, 4) and linear frames (N, H, W, 3) float32 of ``eval_views`` (else N = 0)."""
        if self._test is None:
            h, w = self.intrinsics.height, self.intrinsics.width
            if self._eval is None:
                self._test = (np.zeros((0, 4, 4)), np.zeros((0, h, w, 3), dtype=np.float32))
            else:
                images = [load_frame(p, (w, h)) for p in self._eval.images]
                self._test = (self._eval.poses.copy(), np.stack(images).astype(np.float32))
        return self._test[0].copy(), self._test[1].copy()

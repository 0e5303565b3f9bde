"""Import an image sequence with poses (NeRF "Blender" ``transforms.json``) as a spike-simulation source.

The frames are taken in the order they are listed (the trajectory order). Source frame ``i`` covers spike
steps ``i·s … i·s + s − 1`` (``s = steps_per_frame``): held by default, or blended linearly towards frame
``i + 1`` in intensity with a slerp/lerp pose when ``interpolate=True``. Colour handling is described in
:mod:`spikenerf.scenes.image_io`, the frames' reading and checks in :mod:`spikenerf.scenes.sequence_frames`,
the scene box estimated where the file gives none in :mod:`spikenerf.scenes.scene_box`; the user guide is
``docs/sequence.md``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError, is_finite, is_integer
from spikenerf.core.limits import check_memory
from spikenerf.scenes.image_io import load_frame
from spikenerf.scenes.poses import interpolate_poses
from spikenerf.scenes.scene_box import estimate_scene_box
from spikenerf.scenes.sequence_frames import FrameRange, SequenceFrames, load_sequence
from spikenerf.scenes.trajectory import Trajectory

#: peak bytes per spike step while a source builds its step schedule and poses (measured about 740)
SCHEDULE_BYTES = 1024


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

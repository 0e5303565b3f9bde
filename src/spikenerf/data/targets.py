"""Training targets, as compact tensors: posed target images and the recorded spike stream.

Every target is *linear* intensity per readout step (1.0 = white, φ = the dataset threshold), channels last.
Which method uses which targets is decided by its class in :mod:`spikenerf.train.methods`:

* ``spike-nerf`` (:func:`stream_targets`): ``M_k ⊙ Î_k`` at every step k — TFP (window 41) or TFI of the
  recorded stream, times the spike mask ``M_k = s_{k-n} ∨ … ∨ s_{k+n}`` (n = 5: exactly 11 frames);
  unmasked (``mask=False``) = ``Î_k``.
* ``nerf-recon`` (:func:`stream_targets`, ``mask=False``): ``Î_k`` at every step (no mask).
* Either of the two with ``window_poses`` S > 1 (window-aware targets, not in the paper): a TFP image is the
  mean light over its window, so each target carries S poses spread over its window (:func:`window_steps`)
  and the method compares it with the mean of the renders there, as ``nerf-blur-aware`` does with a blur
  view's exposure.
* ``nerf-gt`` (:func:`gt_targets`): the sharp ground-truth renders at their poses.
* ``nerf-blur`` (:func:`blur_targets`): the conventional-camera (400 fps) blur views the dataset holds
  (``simulate --blur-views``: 10 consecutive frames, or the paper's 1000 overlapping exposures) at their
  mid-exposure poses.
* ``nerf-blur-aware`` (a deblurring NeRF given the true trajectory; it does not optimise the trajectory as
  BAD-NeRF does; :func:`blur_targets` with ``samples``): the blur views, each with ``blur_samples`` poses
  spread over its exposure; the method renders all of them and averages before the loss.
* ``nerf-bad`` (BAD-NeRF-like; :func:`blur_targets` at the given poses): the blur views at their stored
  (mid-exposure) poses only; the method learns each view's exposure start and end pose itself
  (``spikenerf.train.exposure_poses``) and reads no trajectory.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import torch
from torch import Tensor

from spikenerf.camera.layout import to_channels_last
from spikenerf.camera.masks import spike_masks
from spikenerf.camera.reconstruct import DEFAULT_WINDOW
from spikenerf.core.color import rgb_to_gray
from spikenerf.core.errors import InputError, check_choice
from spikenerf.data.choices import COLORS
from spikenerf.data.choices import METHODS as METHODS  # (defined there, without torch)
from spikenerf.data.choices import Method as Method
from spikenerf.data.choices import TrainColor as TrainColor
from spikenerf.data.reconstruction import RECONS as RECONS
from spikenerf.data.reconstruction import TargetRecon as TargetRecon
from spikenerf.data.reconstruction import reconstruct_cut, reconstruct_stream

if TYPE_CHECKING:
    from spikenerf.data.dataset import PosedImages, SpikeDataset


@dataclass
class ImageTargets:
    """Posed linear target images for the reconstruction loss.

    Attributes:
        poses: (K, S, 4, 4) float32 camera-to-world; the rendering of an image is the mean over its S poses
            (S = 1 except for the exposure-aware blur baseline).
        images: (K, H, W, C) float16 linear targets (C = 1 gray, 3 rgb).
        steps: (K,) int64 spike step of each image (−1 if unknown).
        pose_steps: (K, S) int64 spike step of each pose (None: ``steps`` for every pose).
    """

    poses: Tensor
    images: Tensor
    steps: Tensor
    pose_steps: Tensor | None = None

    #: read on the host only (the pose refiners, the holdout), never by the device part of a training step
    HOST_FIELDS: ClassVar[tuple[str, ...]] = ("steps", "pose_steps")

    def __len__(self) -> int:
        return int(self.images.shape[0])

    def gather(self, index: Tensor, pixels: Tensor) -> Tensor:
        """Target values (B, C) float32 of images ``index`` (B,) at pixels (B, 2) int ``(x, y)``, gathered
        on the images' device (the indices are copied there)."""
        dev = self.images.device
        index, pixels = index.to(dev), pixels.to(dev)
        return self.images[index, pixels[:, 1], pixels[:, 0]].float()

    def images_on(self, device: torch.device | str) -> ImageTargets:
        """The same targets with ``images`` and ``poses`` on ``device`` (a training GPU gathers both there,
        so a step copies nothing from the host but its draws); ``steps`` and ``pose_steps`` stay where they
        are (:data:`HOST_FIELDS`: the pose refiners read them on the host, with host indices)."""
        return dataclasses.replace(self, images=self.images.to(device), poses=self.poses.to(device))


@dataclass
class SpikeTargets:
    """The recorded stream and per-step poses for the spike loss.

    Attributes:
        spikes: (T, H, W, C) uint8 0/1 recorded spikes, channels last (``camera.layout.to_channels_last``).
        poses: (T, 4, 4) float32 camera-to-world of each step.
        threshold: φ of the camera.
    """

    spikes: Tensor
    poses: Tensor
    threshold: float

    def window(self, steps: Tensor, pixels: Tensor) -> Tensor:
        """Recorded spikes (L, P, C) float32 of ``steps`` (L,) int64 at pixels (P, 2) int ``(x, y)``,
        gathered on the spikes' device (the indices are copied there; no value is read back)."""
        steps, pixels = steps.to(self.spikes.device), pixels.to(self.spikes.device)
        return self.spikes[steps[:, None], pixels[:, 1], pixels[:, 0]].float()

    def spikes_on(self, device: torch.device | str) -> SpikeTargets:
        """The same targets with ``spikes`` and ``poses`` on ``device``."""
        return dataclasses.replace(self, spikes=self.spikes.to(device), poses=self.poses.to(device))


def masked_reconstruction(
    spikes: np.ndarray,
    recon: str = "tfp",
    window: int = DEFAULT_WINDOW,
    threshold: float = 1.0,
    mask: bool = True,
    mask_n: int = 5,
    cuts: np.ndarray | None = None,
) -> np.ndarray:
    """``M_k ⊙ Î_k`` (or ``Î_k`` when ``mask`` is False) for every step of a (T, ...) stream; ``cuts``
    (M,): ``Î`` of the stream cut there (:func:`~spikenerf.data.reconstruction.reconstruct_cut`; the mask
    of the whole stream).

    Returns:
        float32 (T, ...) linear intensity; 0 where no spike fell in frames ``k-n..k+n``.
    """
    if cuts is None:
        images = reconstruct_stream(spikes, recon, window, threshold)
    else:
        images = reconstruct_cut(spikes, recon, window, threshold, cuts)
    if mask:
        images = images * spike_masks(spikes, n=mask_n)
    return images.astype(np.float32)


def stream_mode(color: str) -> str:
    """Dataset spike mode used for ``--color``: gray → ``gray`` stream, rgb → per-channel ``rgb`` streams."""
    check_choice(color, COLORS, "color")
    return color


def load_stream(dataset: SpikeDataset, color: str) -> np.ndarray:
    """The recorded stream of ``--color``: uint8 (T, H, W) gray or (T, 3, H, W) rgb; checked against poses."""
    mode = stream_mode(color)
    if mode not in dataset.modes:
        raise InputError(
            f"color {color} needs the {mode!r} spike stream, but the dataset has {sorted(dataset.modes)}",
            path=getattr(dataset, "root", None),
            param="color",
        )
    spikes = np.asarray(dataset.spikes(mode))
    if len(dataset.trajectory) != spikes.shape[0]:
        raise InputError(
            f"the {mode} stream has {spikes.shape[0]} steps but the trajectory has {len(dataset.trajectory)}",
            path=getattr(dataset, "root", None),
        )
    return spikes


def given_stream(dataset: SpikeDataset, color: str, spikes: np.ndarray | None) -> np.ndarray:
    """The stream of ``color``: ``spikes`` when given (checked: (T, H, W) gray or (T, 3, H, W) rgb with the
    dataset's T steps and H×W pixels, else InputError naming ``spikes``), else :func:`load_stream`."""
    if spikes is None:
        return load_stream(dataset, color)
    k, steps = dataset.intrinsics, len(dataset.trajectory)
    want = (steps, k.height, k.width) if stream_mode(color) == "gray" else (steps, 3, k.height, k.width)
    found = tuple(getattr(spikes, "shape", np.shape(spikes)))
    if found != want:
        layout = "(T, H, W)" if len(want) == 3 else "(T, 3, H, W)"
        raise InputError(
            f"spikes must be the {color} stream {layout} = {want} of the dataset's {steps} steps at "
            f"{k.height}×{k.width}, found shape {found}",
            path=getattr(dataset, "root", None),
            param="spikes",
        )
    return spikes


def image_channels(images: np.ndarray | Tensor, color: str) -> Tensor:
    """Linear RGB images (N, H, W, 3) → (N, H, W, 1) gray (``rgb_to_gray``) or unchanged for rgb, float32."""
    x = torch.as_tensor(np.asarray(images, dtype=np.float32))
    return rgb_to_gray(x, channel_axis=-1)[..., None] if stream_mode(color) == "gray" else x


def half_channels(images: np.ndarray, color: str, chunk: int = 64) -> Tensor:
    """:func:`image_channels` as float16 (N, H, W, C), converted ``chunk`` images at a time (memory maps of
    1000 blur views never exist in float32 at once)."""
    parts = [image_channels(images[i : i + chunk], color).half() for i in range(0, len(images), chunk)]
    return torch.cat(parts) if parts else image_channels(images, color).half()


def step_poses(dataset: SpikeDataset, steps: np.ndarray) -> np.ndarray:
    """Trajectory poses (N, 4, 4) at spike ``steps`` (N,) (indices into ``trajectory.steps``)."""
    traj = dataset.trajectory
    idx = np.searchsorted(traj.steps, steps)
    idx = np.clip(idx, 0, len(traj) - 1)
    if not np.array_equal(traj.steps[idx], steps):
        raise InputError(
            "frame steps are not on the training trajectory", path=getattr(dataset, "root", None)
        )
    return traj.poses[idx]


def exposure_steps(step_range: np.ndarray, samples: int) -> np.ndarray:
    """``samples`` steps (samples,) int64 spread evenly over an exposure ``step_range`` (2,) = ``[start,
    end)``: centres of equal sub-intervals."""
    start, end = int(step_range[0]), int(step_range[1])
    frac = (np.arange(samples) + 0.5) / samples
    return np.minimum(start + np.floor(frac * (end - start)).astype(np.int64), end - 1)


def window_steps(n_steps: int, window: int, samples: int) -> np.ndarray:
    """Trajectory indices (T, S) of ``samples`` poses spread over each step's TFP window.

    Step k's window is ``k − h … k + h`` (h = (window − 1) // 2) clipped to ``0 … n_steps − 1``, as
    :func:`spikenerf.camera.reconstruct.tfp` clips it; the S indices are the centres of S equal parts of it
    (:func:`exposure_steps`), so S = 1 is k itself where the whole window fits.
    """
    h = (window - 1) // 2
    k = np.arange(n_steps)
    lo, hi = np.maximum(k - h, 0), np.minimum(k + h, n_steps - 1) + 1
    return np.stack([exposure_steps(np.array([a, b]), samples) for a, b in zip(lo, hi, strict=True)])


def _posed(posed: PosedImages | None, what: str, method: str, dataset: SpikeDataset) -> PosedImages:
    if posed is None or len(posed.images) == 0:
        raise InputError(
            f"method {method} needs the {what} frames, but the dataset has none",
            path=getattr(dataset, "root", None),
            param="method",
        )
    return posed


def stream_targets(
    dataset: SpikeDataset,
    color: str = "gray",
    recon: str = "tfp",
    window: int = DEFAULT_WINDOW,
    mask: bool = True,
    mask_n: int = 5,
    spikes: np.ndarray | None = None,
    window_poses: int = 1,
    cuts: np.ndarray | None = None,
) -> ImageTargets:
    """``M_k ⊙ Î_k`` (``mask``) or ``Î_k`` at every step's pose: poses (T, 1, 4, 4), images (T, H, W, C);
    with ``window_poses`` S > 1 (``recon`` tfp only), poses (T, S, 4, 4) spread over each step's TFP
    window (:func:`window_steps`) and ``pose_steps`` (T, S).

    Args:
        dataset: a loaded dataset folder. color: gray | rgb. recon: tfp | tfi | tfstp | learned. window: TFP
        window (odd). mask: apply spike masks. mask_n: mask half window n (2n+1 frames). spikes: the stream if
        already loaded ((T, H, W) gray or (T, 3, H, W) rgb, T the trajectory's steps, H×W the dataset's;
        checked, InputError naming ``spikes``). window_poses: poses per target (≥ 1). cuts: (M,) steps
        where the stream is cut before it is reconstructed (None: not cut; a hold-out's bands'
        edges, ``data.holdout.Holdout.cuts``).
    """
    if window_poses < 1:
        raise InputError(f"window_poses must be ≥ 1, found {window_poses}", param="window_poses")
    if window_poses > 1 and recon != "tfp":
        raise InputError(
            f"window_poses > 1 models the TFP window; recon {recon!r} has none (use recon tfp)",
            param="window_poses",
        )
    stream = given_stream(dataset, color, spikes)
    try:
        images = masked_reconstruction(stream, recon, window, dataset.threshold, mask, mask_n, cuts)
    except InputError as err:  # (e.g. a window longer than the stream): named with the dataset
        if err.path is not None or getattr(dataset, "root", None) is None:
            raise
        raise InputError(err.message, path=dataset.root, param=err.params) from err
    images = torch.as_tensor(to_channels_last(images)).half()
    traj = dataset.trajectory
    steps = torch.as_tensor(traj.steps)
    if window_poses == 1:
        poses = torch.as_tensor(traj.poses, dtype=torch.float32)[:, None]
        return ImageTargets(poses, images, steps)
    idx = window_steps(len(traj), window, window_poses)
    poses = torch.as_tensor(np.asarray(traj.poses)[idx], dtype=torch.float32)
    return ImageTargets(poses, images, steps, torch.as_tensor(np.asarray(traj.steps)[idx]))


def gt_targets(dataset: SpikeDataset, color: str = "gray", method: str = "nerf-gt") -> ImageTargets:
    """The sharp ground-truth renders at their poses: poses (K, 1, 4, 4), images (K, H, W, C).
    ``method`` names the caller in the error raised when the dataset has none."""
    gt = _posed(dataset.gt, "gt/", method, dataset)
    steps = np.full(len(gt.images), -1) if gt.steps is None else np.asarray(gt.steps)
    poses = torch.as_tensor(np.asarray(gt.poses), dtype=torch.float32)[:, None]
    return ImageTargets(poses, image_channels(gt.images, color).half(), torch.as_tensor(steps))


def blur_targets(
    dataset: SpikeDataset, color: str = "gray", samples: int | None = None, method: str = "nerf-blur"
) -> ImageTargets:
    """The blur views: at their mid-exposure poses (``samples`` None: poses (K, 1, 4, 4)) or each at
    ``samples`` poses spread over its exposure (poses (K, samples, 4, 4)); images (K, H, W, C).
    ``method`` names the caller in errors."""
    blur = _posed(dataset.blur, "blur/", method, dataset)
    ranges = None if blur.step_ranges is None else np.asarray(blur.step_ranges)
    steps = np.full(len(blur.images), -1) if ranges is None else (ranges[:, 0] + ranges[:, 1] - 1) // 2
    if samples is None:
        poses = torch.as_tensor(np.asarray(blur.poses), dtype=torch.float32)[:, None]
    else:
        if ranges is None:
            raise InputError(
                f"method {method} needs the exposure step ranges of the blur frames",
                path=getattr(dataset, "root", None),
                param="method",
            )
        if samples < 1:
            raise InputError(f"blur samples per exposure must be ≥ 1, found {samples}")
        sub = np.stack([exposure_steps(r, samples) for r in ranges])
        poses = torch.as_tensor(np.stack([step_poses(dataset, s) for s in sub]), dtype=torch.float32)
        images = _valid_blur(half_channels(blur.images, color), dataset)
        return ImageTargets(poses, images, torch.as_tensor(steps), torch.as_tensor(sub))
    return ImageTargets(
        poses, _valid_blur(half_channels(blur.images, color), dataset), torch.as_tensor(steps)
    )


def _valid_blur(images: Tensor, dataset: SpikeDataset) -> Tensor:
    """``images`` (K, H, W, C), or an InputError naming the view that holds a NaN, an infinity or a negative
    value (only an edited ``blur/views.npy`` can: the simulator writes [0, 1]; PNGs cannot), which trained
    to a non-finite loss blamed on the learning rate. Checked where training reads them, not at every load
    of a dataset (the array can be gigabytes)."""
    bad = ~(images.isfinite() & (images >= 0)).flatten(1).all(dim=1)
    if bad.any():
        raise InputError(
            f"blur view {int(bad.nonzero()[0, 0])} holds a NaN, an infinity or a negative value",
            path=getattr(dataset, "root", None),
        )
    return images


def build_spike_targets(
    dataset: SpikeDataset, color: str = "gray", spikes: np.ndarray | None = None
) -> SpikeTargets:
    """The recorded stream of ``color`` as (T, H, W, C) uint8 with per-step poses and φ (``spikes``: the
    stream if already loaded, checked as :func:`stream_targets` checks it)."""
    stream = given_stream(dataset, color, spikes)
    return SpikeTargets(
        torch.as_tensor(to_channels_last(np.asarray(stream, dtype=np.uint8))).contiguous(),
        torch.as_tensor(dataset.trajectory.poses, dtype=torch.float32),
        float(dataset.threshold),
    )


def eval_view_targets(dataset: SpikeDataset, color: str, count: int | None = None) -> ImageTargets | None:
    """Held-out views for evaluation (the first ``count``; all if None), or None if the dataset has none."""
    test = dataset.test
    if test is None or len(test.images) == 0:
        return None
    n = len(test.images) if count is None else min(count, len(test.images))
    idx = np.linspace(0, len(test.images) - 1, n).round().astype(np.int64) if n > 0 else np.zeros(0, np.int64)
    poses = torch.as_tensor(np.asarray(test.poses)[idx], dtype=torch.float32)[:, None]
    images = image_channels(np.asarray(test.images)[idx], color)
    return ImageTargets(poses, images, torch.full((n,), -1, dtype=torch.int64))

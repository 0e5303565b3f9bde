"""The spiking volume renderer: intensity rendered at consecutive steps along the camera path is accumulated
from a start state and fires spikes with the camera's own rule (:func:`spikenerf.camera.firing.fire`).

Each step k renders the pixel with the pose of step k, so a window of L steps is L different rays through the
same pixel. The rendered radiance (linear, 1.0 = white) is the intensity integrated over one step, as in the
camera simulator. Spikes are discrete; the differentiable quantities are ``intensity`` and the accumulators
(``A_k = A_0 + Σ_{j≤k} I_j − φ·Σ_{j≤k} s_j``, where the spikes enter as constants), which is what a spike loss
can take its gradient from.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from spikenerf.camera.firing import fire
from spikenerf.camera.layout import to_camera_layout, to_channels_last
from spikenerf.camera.streams import check_threshold
from spikenerf.core import tensor_checks
from spikenerf.core.errors import InputError
from spikenerf.data.rays import as_poses, pixel_rays
from spikenerf.render.base import RadianceModel
from spikenerf.render.inference import inference_chunk
from spikenerf.render.model import (
    check_bounds,
    check_intrinsics,
    check_model,
    check_poses,
    ray_bounds,
    render_image,
)
from spikenerf.scenes.trajectory import Intrinsics


@dataclass
class SpikeWindow:
    """A rendered window of L consecutive steps for N pixels.

    Attributes:
        intensity: (L, N, C) rendered intensity per step, differentiable w.r.t. the field.
        spikes: (L, N, C) bool, the spikes fired at each step.
        accumulator: (L, N, C) the accumulator after each step (differentiable through ``intensity``).
    """

    intensity: Tensor
    spikes: Tensor
    accumulator: Tensor


def fire_sequence(intensity: Tensor, start: Tensor, threshold: float | Tensor = 1.0) -> tuple[Tensor, Tensor]:
    """The camera rule over a sequence: ``fire`` applied step by step from ``start``.

    Args:
        intensity: (L, ...) intensity of each step. start: (...) accumulator before the first step.
        threshold: φ, scalar or broadcastable to ``start``.
    Returns:
        spikes (L, ...) bool and accumulators (L, ...) after each step (same float ops as the camera, so
        bit-identical to calling ``fire`` in a loop).
    Raises:
        InputError: naming ``start`` unless it is a tensor of one step's shape (``intensity.shape[1:]``, or
            broadcastable to it), ``intensity`` unless it has a step axis, or ``threshold`` unless a finite
            number > 0 (a NaN or zero φ fired no spike or one every step, without a word).
    """
    if not hasattr(intensity, "shape") or len(intensity.shape) == 0:
        raise InputError("intensity must be (L, ...) with a step axis first", param="intensity")
    step = tuple(intensity.shape[1:])
    if (
        not isinstance(start, Tensor)
        or len(start.shape) > len(step)
        or any(a not in (1, b) for a, b in zip(reversed(tuple(start.shape)), reversed(step), strict=False))
    ):
        found = tuple(start.shape) if isinstance(start, Tensor) else type(start).__name__
        raise InputError(f"start must be a tensor of one step's shape {step}, found {found}", param="start")
    tensor_checks.check_threshold(threshold)
    spikes, accs = [], []
    acc = start
    for k in range(intensity.shape[0]):
        s, acc = fire(acc, intensity[k], threshold)
        spikes.append(s)
        accs.append(acc)
    if not spikes:
        empty = intensity.new_zeros((0, *start.shape))
        return empty.bool(), empty
    return torch.stack(spikes), torch.stack(accs)


def render_spike_window(
    model: RadianceModel,
    poses: Tensor | np.ndarray,
    intrinsics: Intrinsics,
    pixels: Tensor,
    start_accumulator: Tensor,
    threshold: float | Tensor = 1.0,
    near: float | None = None,
    far: float | None = None,
    perturb: bool = False,
) -> SpikeWindow:
    """Render intensity for N pixels over L consecutive steps and fire spikes from a start state.

    Args:
        model: the radiance model rendered. intrinsics: the camera of every step.
        poses: (L, 4, 4) camera-to-world of the steps. pixels: (N, 2) int ``(x=column, y=row)``.
        start_accumulator: (N, C) accumulator before the first step (e.g. uniform in [0, φ) or a state
            carried from a previous window). threshold: φ.
        near / far: optional scalar limits; rays are always bounded by the model's scene box.
        perturb: random sample positions along the rays (training).
    Returns:
        :class:`SpikeWindow` with (L, N, C) tensors on the model's device; all L·N rays go through one
        ``render_rays`` call (keep L·N within a training batch).
    """
    device = model.device
    shape = tuple(getattr(poses, "shape", ()))  # (the shape only: this runs in a compiled training step)
    if len(shape) != 3 or shape[1:] != (4, 4):  # (one (4, 4) pose was a RuntimeError of expand)
        hint = " (one pose? pass poses[None])" if shape == (4, 4) else ""
        raise InputError(f"poses must be (L, 4, 4) camera-to-world, found shape {shape}{hint}", param="poses")
    check_intrinsics(intrinsics)  # (near and far: ray_bounds)
    pose = as_poses(poses, device)
    pixels = tensor_checks.as_tensor_arg(pixels, "pixels", device)
    check_window_args(pixels, start_accumulator, intrinsics, model.channels)
    tensor_checks.check_threshold(threshold)
    n_steps, n_pix = pose.shape[0], pixels.shape[0]
    per_ray = pose[:, None].expand(n_steps, n_pix, 4, 4).reshape(-1, 4, 4)
    origins, dirs = pixel_rays(per_ray, intrinsics, pixels.repeat(n_steps, 1))
    lo, hi = ray_bounds(model, origins, dirs, near, far)
    out = model.render_rays(origins, dirs, lo, hi, perturb=perturb)
    intensity = out.color.view(n_steps, n_pix, -1)
    spikes, accs = fire_sequence(intensity, start_accumulator.to(device, intensity.dtype), threshold)
    return SpikeWindow(intensity, spikes, accs)


def check_window_args(pixels: Tensor, start: Tensor, intrinsics: Intrinsics, channels: int) -> None:
    """InputError naming ``pixels`` unless they are (N, 2) integers inside the image (the range only where
    :func:`~spikenerf.core.tensor_checks.readable`), or ``start_accumulator`` unless it is a tensor (N, C)
    (an (N,) or (N, 1) broadcast against C channels without a word), finite where readable."""
    if (
        pixels.dim() != 2
        or pixels.shape[1] != 2
        or pixels.dtype.is_floating_point
        or pixels.dtype == torch.bool
    ):
        raise InputError(
            f"pixels must be (N, 2) integer (x, y), found {pixels.dtype} of shape {tuple(pixels.shape)}",
            param="pixels",
        )
    if tensor_checks.readable(pixels) and pixels.numel():
        x, y = pixels[:, 0], pixels[:, 1]
        if bool(
            (x < 0).any() | (x >= intrinsics.width).any() | (y < 0).any() | (y >= intrinsics.height).any()
        ):
            raise InputError(
                f"pixels must lie in the {intrinsics.width}×{intrinsics.height} image (0 ≤ x < width, "
                "0 ≤ y < height)",
                param="pixels",
            )
    want = (pixels.shape[0], channels)
    if not isinstance(start, Tensor) or tuple(start.shape) != want:
        found = tuple(start.shape) if isinstance(start, Tensor) else type(start).__name__
        raise InputError(
            f"start_accumulator must be a tensor {want} (N, C), found {found}", param="start_accumulator"
        )
    if tensor_checks.readable(start) and not bool(torch.isfinite(start).all()):  # (a NaN start fired nothing)
        raise InputError("start_accumulator holds a NaN or an infinity", param="start_accumulator")


def random_start(
    shape: tuple[int, ...], threshold: float, seed: int, device: torch.device | str = "cpu"
) -> Tensor:
    """A seeded start accumulator of ``shape`` (e.g. (H, W, C)), uniform in [0, φ)."""
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(shape, generator=gen) * threshold).to(device)


def iter_spike_states(
    model: RadianceModel,
    poses: Tensor | np.ndarray,
    intrinsics: Intrinsics,
    threshold: float = 1.0,
    start_accumulator: Tensor | np.ndarray | int | None = None,
    chunk: int = 8192,
    near: float | None = None,
    far: float | None = None,
) -> Iterator[tuple[Tensor, Tensor]]:
    """Yield ``(spikes, accumulator)`` for each step of ``poses`` (T, 4, 4), one full render per step: the
    spikes bool on the CPU and the accumulators after the step on the model's device, both in the camera
    layout (:mod:`spikenerf.camera.layout`), (H, W) gray or (3, H, W) rgb. Passing an accumulator back as
    ``start_accumulator`` with the remaining poses continues the stream exactly.

    ``poses``: (T, 4, 4), finite (a single pose is ``poses[None]``). ``threshold``: φ > 0.
    ``start_accumulator``: the same layout (a tensor or a numpy array), or an int seed for a uniform [0, φ)
    start (None → seed 0). ``chunk``: rays per render call, 0 = automatic. The arguments are checked when
    this is called (InputError naming the parameter), not at the first step.
    """
    check_model(model)
    check_poses(poses, "poses")
    check_threshold(threshold)
    check_bounds(near, far)
    check_intrinsics(intrinsics)
    h, w, c = intrinsics.height, intrinsics.width, model.channels
    if start_accumulator is None or (
        isinstance(start_accumulator, (int, np.integer)) and not isinstance(start_accumulator, bool)
    ):
        acc = random_start((h, w, c), threshold, int(start_accumulator or 0), model.device)
    else:
        want = (h, w) if c == 1 else (3, h, w)
        found = tuple(getattr(start_accumulator, "shape", ()))
        if found != want:
            raise InputError(
                f"start_accumulator must be {want} (the camera layout of this {c}-channel model's "
                f"accumulator) or an int seed, found {type(start_accumulator).__name__} of shape {found}",
                param="start_accumulator",
            )
        acc = to_channels_last(torch.as_tensor(start_accumulator), frame=True, name="start_accumulator")
        acc = acc.to(model.device, torch.float32)
        if not bool(torch.isfinite(acc).all()):  # (a NaN start fired no spike at all)
            raise InputError("start_accumulator holds a NaN or an infinity", param="start_accumulator")
    chunk = inference_chunk(model, chunk)
    return _spike_states(model, as_poses(poses, model.device), intrinsics, threshold, acc, chunk, near, far)


@torch.no_grad()
def _spike_states(
    model: RadianceModel,
    poses: Tensor,
    intrinsics: Intrinsics,
    threshold: float,
    acc: Tensor,
    chunk: int,
    near: float | None,
    far: float | None,
) -> Iterator[tuple[Tensor, Tensor]]:
    """:func:`iter_spike_states` after its checks: poses (T, 4, 4) and the start ``acc`` (H, W, C) on the
    model's device."""
    for pose in poses:
        color = render_image(model, pose, intrinsics, near, far, chunk).color
        spikes, acc = fire(acc, color, threshold)
        yield to_camera_layout(spikes.cpu(), frame=True), to_camera_layout(acc, frame=True)


def iter_spike_stream(
    model: RadianceModel,
    poses: Tensor | np.ndarray,
    intrinsics: Intrinsics,
    threshold: float = 1.0,
    start_accumulator: Tensor | int | None = None,
    chunk: int = 8192,
    near: float | None = None,
    far: float | None = None,
) -> Iterator[Tensor]:
    """The spikes of :func:`iter_spike_states`: bool on the CPU in the camera layout, (H, W) gray or
    (3, H, W) rgb, one step of ``poses`` after another."""
    states = iter_spike_states(model, poses, intrinsics, threshold, start_accumulator, chunk, near, far)
    return (spikes for spikes, _ in states)


def render_spike_stream(
    model: RadianceModel,
    poses: Tensor | np.ndarray,
    intrinsics: Intrinsics,
    threshold: float = 1.0,
    start_accumulator: Tensor | int | None = None,
    chunk: int = 8192,
    near: float | None = None,
    far: float | None = None,
) -> Tensor:
    """Novel-view spike stream for any trajectory: bool on the CPU, (T, H, W) gray or (T, 3, H, W) rgb (the
    camera layout, see :func:`iter_spike_stream`).

    For long streams prefer :func:`iter_spike_stream` and write each step as it comes.
    """
    h, w, c = intrinsics.height, intrinsics.width, model.channels
    steps = list(iter_spike_stream(model, poses, intrinsics, threshold, start_accumulator, chunk, near, far))
    return torch.stack(steps) if steps else to_camera_layout(torch.zeros(0, h, w, c, dtype=torch.bool))

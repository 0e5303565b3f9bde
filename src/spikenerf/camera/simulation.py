"""Whole spike streams from a :class:`~spikenerf.camera.model.SpikeCamera`: :func:`simulate` (the stream as
one array) and :func:`simulate_iter` (one step at a time: memory does not grow with T)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np
import torch

from spikenerf.camera.model import CameraConfig, SpikeCamera
from spikenerf.camera.noise import RealisticNoise
from spikenerf.core.errors import InputError

#: Steps buffered on the device before a copy to host memory in :func:`simulate`.
_CHUNK = 256


def _check_frames(frames: object) -> None:
    """InputError naming ``frames`` unless it can be iterated (a list, an array of steps, a generator)."""
    try:
        iter(frames)  # type: ignore[call-overload]
    except TypeError:
        raise InputError(
            f"frames must be an iterable of steps (e.g. a list of (H, W) arrays, or a (T, H, W) array), "
            f"got {type(frames).__name__}",
            param="frames",
        ) from None


def simulate_iter(
    frames: Iterable,
    height: int,
    width: int,
    config: CameraConfig | None = None,
    device: str | torch.device | None = None,
    noise_params: RealisticNoise | None = None,
) -> Iterator:
    """Stream spikes: one bool (H, W) or (3, H, W) array per input frame; memory does not grow with T.

    ``frames`` yields one step each, in any form :meth:`SpikeCamera.step` accepts; a NaN, an infinity or a
    value below 0 among them raises InputError by the end (:meth:`SpikeCamera.check`).
    """
    _check_frames(frames)
    camera = SpikeCamera(height, width, config, device, noise_params)
    for frame in frames:
        yield camera.step(frame)
    camera.check()  # (the steps since the last periodic check)


def simulate(
    frames: Iterable,
    height: int,
    width: int,
    config: CameraConfig | None = None,
    device: str | torch.device | None = None,
    progress: bool = False,
    noise_params: RealisticNoise | None = None,
) -> np.ndarray:
    """Simulate a whole stream: bool (T, H, W) for gray/bayer or (T, 3, H, W) for rgb, as numpy.

    Args:
        frames: T steps of intensity (see :meth:`SpikeCamera.step`), any iterable.
        height, width: the sensor's size in pixels (positive integers).
        config: the camera (:class:`CameraConfig`: colour mode, threshold φ, noise, seed, warm-up); None: the
            defaults (gray, φ = 1, ideal).
        device: None (numpy), or a torch device to integrate on.
        progress: show a tqdm progress bar.
        noise_params: the realistic noise's parameters (default: the preset of ``camera/noise.py``).
    Raises:
        InputError: a size, the config or a frame is malformed (a NaN, an infinity or a value below 0 in a
            frame: by the end, see :meth:`SpikeCamera.check`).
    """
    _check_frames(frames)
    camera = SpikeCamera(height, width, config, device, noise_params)
    total = len(frames) if hasattr(frames, "__len__") else None  # type: ignore[arg-type]
    if progress:
        from spikenerf.core.progress import bar

        frames = bar(frames, total=total, desc="spike camera", unit="step")
    if device is None and total is not None:
        out = np.empty((total, *camera.spike_shape), dtype=bool)
        for t, frame in enumerate(frames):
            if t >= total:
                raise InputError(f"frames yielded more than its length {total}")
            camera.step(frame, out=out[t])
        camera.check()  # (the steps since the last periodic check)
        return out[: camera.steps]
    chunks: list[np.ndarray] = []
    buf = camera.new_spikes(_CHUNK)
    n = 0
    for frame in frames:
        camera.step(frame, out=buf[n])
        n += 1
        if n == _CHUNK:
            chunks.append(_host_copy(buf))
            n = 0
    camera.check()
    if n or not chunks:
        chunks.append(_host_copy(buf[:n]))
    return np.concatenate(chunks) if len(chunks) > 1 else chunks[0]


def _host_copy(x: np.ndarray | torch.Tensor) -> np.ndarray:
    return x.cpu().numpy().copy() if isinstance(x, torch.Tensor) else x.copy()

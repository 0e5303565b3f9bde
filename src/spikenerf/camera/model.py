"""Integrate-and-fire spike camera model (numpy or torch): its settings (:class:`CameraConfig`: colour mode,
threshold, noise preset, seed, warm-up) and the camera fed one step at a time (:class:`SpikeCamera`). The
firing rule is ``firing.py``, the Bayer filter ``bayer.py``, whole streams ``simulation.py``.

Units: intensity is linear radiance integrated over one readout step (25 µs at 40 kHz); 1.0 = white, i.e.
a white pixel gathers exactly one threshold φ = 1.0 per step. See docs/camera.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from spikenerf.camera.bayer import bayer_mosaic
from spikenerf.camera.firing import Array, fire_
from spikenerf.camera.modes import COLORS, NOISES
from spikenerf.camera.noise import NoiseProcess, RealisticNoise
from spikenerf.camera.streams import check_threshold
from spikenerf.core.color import rgb_to_gray
from spikenerf.core.device import resolve_device
from spikenerf.core.errors import InputError, check_choice, is_integer
from spikenerf.core.limits import check_memory

#: steps between two checks of the accumulator for a NaN or a negative intensity (SpikeCamera.check)
CHECK_EVERY = 64
#: memory a camera holds per pixel and channel (bytes, upper-ish): the float32 accumulator, its seed and
#: scratch, with the temporaries that draw them; the ``realistic`` noise adds its float64 pattern draws, the
#: float32 patterns and its buffers
CAMERA_PIXEL_BYTES = 32
NOISE_PIXEL_BYTES = 160
#: the intensity dtypes a step reads (numpy kinds: bool, signed and unsigned integers, floats)
INTENSITY_KINDS = "biuf"
#: the longest warm-up :class:`CameraConfig` accepts, in steps (it runs before the first recorded step)
MAX_WARMUP = 100_000


@dataclass(frozen=True)
class CameraConfig:
    """Spike camera settings.

    Attributes:
        threshold: φ, intensity units (1.0 = one white step).
        color: ``gray`` (one stream), ``rgb`` (three per-channel streams) or ``bayer`` (RGGB mosaic).
        noise: ``ideal`` or ``realistic`` (see :class:`~spikenerf.camera.noise.RealisticNoise`).
        seed: seeds the initial accumulator and all noise.
        warmup: steps simulated on the first frame and discarded before the first recorded step.
    """

    threshold: float = 1.0
    color: str = "gray"
    noise: str = "ideal"
    seed: int = 0
    warmup: int = 0

    def __post_init__(self) -> None:
        check_threshold(self.threshold)  # > 0 and within float32's range, as the reconstructions check
        check_choice(self.color, COLORS, "color")
        check_choice(self.noise, NOISES, "noise")
        for name in ("seed", "warmup"):
            v = getattr(self, name)
            if not is_integer(v) or v < 0:
                raise InputError(f"{name} must be an integer ≥ 0, got {v!r}", param=name)
        if self.warmup > MAX_WARMUP:
            raise InputError(
                f"warmup must be at most {MAX_WARMUP} steps (2.5 s at 40 kHz: an accumulator settles within "
                f"1/intensity steps), got {self.warmup}",
                param="warmup",
            )


def _resolve(device: str | torch.device | None) -> torch.device | None:
    if device is None:
        return None
    if not isinstance(device, (str, torch.device)):
        raise InputError(f"device must be None (numpy), a string or a torch.device, got {device!r}")
    return resolve_device(str(device))


class SpikeCamera:
    """A spike camera of ``height × width`` pixels: feed one step of intensity, get that step's spikes.

    ``device=None`` runs on numpy; a torch device (``"cpu"``, ``"cuda"``, ``"auto"``) runs on torch tensors.
    The ideal model gives identical spikes on both for the same seed.

    Args:
        height, width: sensor size in pixels.
        config: :class:`CameraConfig`.
        device: None for numpy, else a torch device or its name.
        noise_params: parameters of the ``realistic`` preset (default :class:`RealisticNoise`).
    """

    def __init__(
        self,
        height: int,
        width: int,
        config: CameraConfig | None = None,
        device: str | torch.device | None = None,
        noise_params: RealisticNoise | None = None,
    ) -> None:
        for name, v in (("height", height), ("width", width)):
            if not is_integer(v) or v <= 0:
                raise InputError(f"spike camera {name} must be a positive integer, got {v!r}", param=name)
        if config is not None and not isinstance(config, CameraConfig):  # e.g. "rgb"
            raise InputError(
                f"config must be a CameraConfig (e.g. CameraConfig(color='rgb')), got {config!r}",
                param="config",
            )
        if noise_params is not None and not isinstance(noise_params, RealisticNoise):
            raise InputError(
                f"noise_params must be None or a RealisticNoise, got {noise_params!r:.60}",
                param="noise_params",
            )
        self.config = config if config is not None else CameraConfig()
        realistic = self.config.noise == "realistic"
        channels = 3 if self.config.color == "rgb" else 1
        per_pixel = channels * (CAMERA_PIXEL_BYTES + (NOISE_PIXEL_BYTES if realistic else 0))
        check_memory(float(height) * float(width) * per_pixel, "height/width")
        self.height, self.width = int(height), int(width)
        self.device = _resolve(device)
        self.spike_shape: tuple[int, ...] = (
            (3, self.height, self.width) if self.config.color == "rgb" else (self.height, self.width)
        )
        phi = np.float32(self.config.threshold)
        init_seed, pattern_seed, temporal_seed = np.random.SeedSequence(self.config.seed).spawn(3)
        init = np.random.default_rng(init_seed).random(self.spike_shape, dtype=np.float32) * phi
        self._initial = np.minimum(init, np.nextafter(phi, np.float32(0)))
        self._acc = self._backend(self._initial)
        self._scratch = self._backend(np.zeros(self.spike_shape, np.float32))
        self._threshold: float = float(phi)
        self._noise: NoiseProcess | None = None
        if self.config.noise == "realistic":
            params = noise_params if noise_params is not None else RealisticNoise()
            patterns = params.draw_patterns(self.spike_shape, float(phi), pattern_seed)
            self._noise = NoiseProcess(params, patterns, temporal_seed, self.device, float(phi))
        self._steps = 0
        self._checked = 0  # the steps before this one passed :meth:`check`
        self._warm = self.config.warmup == 0

    def _backend(self, x: np.ndarray) -> np.ndarray | torch.Tensor:
        return x.copy() if self.device is None else torch.from_numpy(x.copy()).to(self.device)

    @property
    def accumulator(self) -> np.ndarray | torch.Tensor:
        """A copy of the accumulator now: float32 (H, W) or (3, H, W), intensity units."""
        return self._acc.clone() if isinstance(self._acc, torch.Tensor) else self._acc.copy()

    @property
    def initial_accumulator(self) -> np.ndarray | torch.Tensor:
        """The seeded accumulator before any step (warm-up included): uniform in [0, φ), float32 (H, W) or
        (3, H, W)."""
        return self._backend(self._initial)

    @property
    def steps(self) -> int:
        """Number of recorded steps so far (warm-up steps not counted)."""
        return self._steps

    def new_spikes(self, steps: int | None = None) -> np.ndarray | torch.Tensor:
        """An uninitialised bool buffer of the spike shape, (H, W) or (3, H, W), with a leading ``steps`` axis
        when given."""
        shape = self.spike_shape if steps is None else (steps, *self.spike_shape)
        if self.device is None:
            return np.empty(shape, dtype=bool)
        return torch.empty(shape, dtype=torch.bool, device=self.device)

    def step(self, intensity: np.ndarray | torch.Tensor, out: np.ndarray | torch.Tensor | None = None):
        """Integrate one step and fire.

        Args:
            intensity: linear radiance of this step (1.0 = white): (H, W) gray or (3, H, W) RGB, or
                sub-frames (S, H, W) / (S, 1, H, W) / (S, 3, H, W) that are averaged. A 3-D input whose first
                axis is 3 is RGB. ``gray`` accepts gray or RGB (converted by ``rgb_to_gray``);
                ``rgb`` and ``bayer`` need RGB. Values must be finite and ≥ 0 (found by :meth:`check`;
                above 1 is brighter than white and saturates: one spike a step); an integer
                array must hold values ≤ 1 (an 8-bit image is refused: scale it to linear [0, 1] first,
                e.g. ``srgb_decode(image / 255)``; on a torch device that check is one sync a step, for
                integer input only).
                Any dtype is read as float32.
            out: optional bool buffer of the spike shape to write into (see :meth:`new_spikes`).
        Returns:
            bool spikes: (H, W) for gray and bayer, (3, H, W) for rgb; numpy or torch like the camera.
        Raises:
            InputError: naming ``intensity`` (a bad shape or value) or ``out``.
        """
        x = self._prepare(intensity)
        if out is None:
            out = self.new_spikes()
        else:
            self._check_out(out)
        if not self._warm:
            for _ in range(self.config.warmup):
                self._advance(x, out)
            self._warm = True
        self._advance(x, out)
        self._steps += 1
        if self._steps % CHECK_EVERY == 0:
            self.check()
        return out

    def _check_out(self, out: object) -> None:
        """InputError naming ``out`` unless it is a writable bool buffer of the spike shape on this camera's
        backend (a numpy array for ``device=None``, else a tensor on the camera's device, as
        :meth:`new_spikes` gives): its type, dtype, shape and flags only, O(1)."""
        device = self.device
        if device is None:
            ok = isinstance(out, np.ndarray) and out.dtype == np.bool_ and out.flags.writeable
        else:
            ok = isinstance(out, torch.Tensor) and out.dtype == torch.bool and out.device.type == device.type
            ok = ok and (device.index is None or out.device.index == device.index)  # type: ignore[union-attr]
        if ok and out.shape == self.spike_shape:  # type: ignore[union-attr]
            return
        if isinstance(out, np.ndarray):
            state = "" if out.flags.writeable else "read-only "
            found = f"a {state}{out.dtype} numpy array of shape {out.shape}"
        elif isinstance(out, torch.Tensor):
            found = f"a {out.dtype} tensor on {out.device} of shape {tuple(out.shape)}"
        else:
            found = type(out).__name__
        kind = "numpy array" if device is None else f"tensor on {device}"
        raise InputError(
            f"out must be a writable bool {kind} of shape {self.spike_shape} (see new_spikes), got {found}",
            param="out",
        )

    def check(self) -> None:
        """InputError naming ``intensity`` when a step since the last check held a NaN, an infinity or a
        value below 0.

        A NaN or an infinity stays in its pixel's accumulator for good (the pixel never fires again, or
        fires every step), and the accumulator of a pixel fed only values ≥ 0 never drops below 0: two
        reductions over the accumulator find them, without a pass over every step's input.
        :meth:`step` calls this every :data:`CHECK_EVERY` steps (on a torch device: one sync then) and
        ``simulate`` and ``simulate_iter`` (:mod:`spikenerf.camera.simulation`) at their end. A value below 0
        too small to empty its accumulator, or one that the next steps fill up again before a check, goes
        unseen; the ``realistic`` noise model clips the charge at 0 (as a pixel does), so there none is seen.
        """
        low, high = float(self._acc.min()), float(self._acc.max())
        if not (math.isnan(low) or low < 0 or math.isinf(high)):
            self._checked = self._steps
            return
        infinity = "an infinity (or a value beyond float32's 3.4e38)"
        what = "a value below 0" if low < 0 else infinity if math.isinf(high) else "a NaN"
        raise InputError(
            f"intensity held {what} at one of steps {self._checked}..{self._steps - 1} (the accumulator of a "
            f"pixel is {low if low < 0 or math.isnan(low) else high:g}): intensity must be finite "
            "linear radiance ≥ 0 (1.0 = white)",
            param="intensity",
        )

    def _advance(self, x: np.ndarray | torch.Tensor, spikes: np.ndarray | torch.Tensor) -> None:
        if self._noise is None:
            fire_(self._acc, x, self._threshold, spikes, self._scratch)
            return
        charge = self._noise.charge(x)
        threshold = self._noise.thresholds()
        fire_(self._acc, charge, threshold, spikes, self._scratch)
        self._noise.after_spikes(spikes)
        self._noise.drop_excess(self._acc, threshold)

    def _prepare(self, intensity: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        """Validate one step's input; convert it to a float32 backend array of the accumulator's shape."""
        if isinstance(intensity, torch.Tensor):
            if intensity.is_complex():
                raise InputError(
                    f"intensity must be real (bool, integer or float), got a {intensity.dtype} tensor",
                    param="intensity",
                )
            integer = not intensity.is_floating_point() and intensity.dtype != torch.bool
            if self.device is None:
                intensity = intensity.detach().cpu().numpy()
        else:
            try:
                intensity = np.asarray(intensity)
            except (TypeError, ValueError) as err:  # (a ragged list)
                raise InputError(
                    f"intensity must be an array of numbers ({err})", param="intensity"
                ) from None
            if intensity.dtype.kind not in INTENSITY_KINDS:  # (complex, strings, objects: O(1), the dtype)
                raise InputError(
                    f"intensity must be a real array (bool, integer or float), got dtype {intensity.dtype}",
                    param="intensity",
                )
            integer = intensity.dtype.kind in "iu"
        if self.device is None:
            with np.errstate(over="ignore"):  # (beyond float32: inf, which check() names)
                x = np.asarray(intensity, dtype=np.float32)
        elif isinstance(intensity, torch.Tensor):
            x = intensity.detach().to(device=self.device, dtype=torch.float32)
        else:  # (contiguous: torch takes no negative strides)
            with np.errstate(over="ignore"):
                a = np.ascontiguousarray(intensity, dtype=np.float32)
            x = torch.from_numpy(a if a.flags.writeable else a.copy()).to(self.device)
        shape = tuple(x.shape)
        if x.ndim < 2 or x.ndim > 4 or shape[-2:] != (self.height, self.width):
            raise InputError(
                f"intensity must be (H, W), (3, H, W), (S, H, W) or (S, C, H, W) with H×W = "
                f"{self.height}×{self.width}, got shape {shape}",
                param="intensity",
            )
        if (x.ndim == 4 and shape[1] not in (1, 3)) or shape[0] == 0:
            raise InputError(
                f"intensity sub-frames must be (S≥1, 1|3, H, W), got shape {shape}", param="intensity"
            )
        _check_integer(x, integer)
        rgb = (x.ndim == 3 and shape[0] == 3) or (x.ndim == 4 and shape[1] == 3)
        if x.ndim == 4 or (x.ndim == 3 and not rgb):
            x = _mean_first(x)
            if x.ndim == 3 and not rgb:
                x = x[0]
        if self.config.color == "gray":
            return rgb_to_gray(x, channel_axis=0) if rgb else x
        if not rgb:
            raise InputError(
                f"color mode {self.config.color!r} needs RGB intensity (3, H, W) or (S, 3, H, W), "
                f"got {shape}",
                param="intensity",
            )
        return x if self.config.color == "rgb" else bayer_mosaic(x)


def _check_integer(x: np.ndarray | torch.Tensor, integer: bool) -> None:
    """InputError naming ``intensity`` where ``x`` was read from an ``integer`` array with values above 1 (an
    8-bit image would saturate every pixel that is not black); a float array costs nothing here."""
    if integer and (high := float(x.max())) > 1:
        raise InputError(
            f"intensity is an integer array with values up to {high:g} (an 8-bit image?): scale it to "
            "linear radiance in [0, 1] first, e.g. core.color.srgb_decode(image / 255)",
            param="intensity",
        )


def _mean_first(x: Array) -> Array:
    """Mean over axis 0 as a sequential float32 sum divided by S (identical on numpy and torch)."""
    total = x[0].clone() if isinstance(x, torch.Tensor) else x[0].copy()
    for s in range(1, x.shape[0]):
        total += x[s]
    if x.shape[0] > 1:
        total /= x.shape[0]
    return total

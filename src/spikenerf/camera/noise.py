"""Realistic spike camera noise: fixed-pattern (per pixel, drawn once) and temporal (per step) noise.

Units follow the camera model: intensity 1.0 = white, the charge that fills one nominal threshold φ in one
25 µs step; thresholds and charges are in those units. The published constants come from the SCSim spike
camera simulator (Hu et al.) and are converted below; docs/camera.md gives the sources and the conversion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch

from spikenerf.camera.modes import NOISE_RANGES
from spikenerf.core.errors import InputError, is_number

Array = np.ndarray | torch.Tensor

# --- Published constants, in the simulator's own units (SCSim reference code, see docs/camera.md) ---------
#: Reset minus reference voltage of the pixel comparator, V_rst − V_ref = 3.3 V − 2.2 V (volts).
SCSIM_SWING_V = 1.1
#: Comparator (threshold) voltage offset per pixel, N(mean, std) in volts.
SCSIM_OFFSET_V = (-0.0076, 0.0497)
#: Integration capacitance per pixel, N(mean, std) (SCSim's capacitance unit; only the ratio is used).
SCSIM_CAPACITANCE = (4.348, 0.0128)
#: Dark current per pixel, N(mean, std), in SCSim's current unit (only its ratio to white is used).
SCSIM_DARK_CURRENT = (0.4442, 0.1731)
#: Photo-response (conversion) factor per pixel, N(mean, std), dimensionless.
SCSIM_PRNU = (1.0128, 0.0584)
#: Per-step threshold voltage noise ("shot" term of the comparator voltage), std in volts.
SCSIM_JITTER_V = 0.00636
#: Photocurrent of a white pixel: SCSim scales a 255 pixel to 20·C·(V_rst − V_ref + V_offset), which (times
#: its 0.05 step factor) is exactly one nominal threshold charge C·(V_rst − V_ref + V_offset) per step.
SCSIM_WHITE_CURRENT = 20.0 * SCSIM_CAPACITANCE[0] * (SCSIM_SWING_V + SCSIM_OFFSET_V[0])
#: The nominal (noise-free) threshold voltage V_rst − V_ref + mean offset = 1.0924 V; our φ stands for it.
SCSIM_NOMINAL_V = SCSIM_SWING_V + SCSIM_OFFSET_V[0]

#: Thresholds are clipped to at least this fraction of φ (guards against extreme parameters).
MIN_RELATIVE_THRESHOLD = 0.05


@dataclass(frozen=True)
class RealisticNoise:
    """Parameters of the ``realistic`` noise preset, in camera units (φ = 1 threshold, 1.0 = white per step).

    Attributes:
        dark_mean: mean dark current, intensity units per step (SCSim 0.4442 / white current 94.995).
        dark_std: pixel-to-pixel std of the dark current, intensity units per step (0.1731 / 94.995).
        threshold_std: relative std of the per-pixel threshold, comparator offset (0.0497 V / 1.0924 V).
        capacitance_std: relative std of the per-pixel integration capacitance (0.0128 / 4.348).
        prnu_std: photo-response non-uniformity, relative std of the per-pixel gain (0.0584 / 1.0128).
        jitter_std: relative std of the per-step threshold noise (0.00636 V / 1.0924 V).
        photons_per_white: photo-electrons collected in one step by a white pixel; sets the Poisson shot noise
            (our choice, following the SCSim code's 5·10⁴); ``math.inf`` disables shot noise.
        readout_delay: integration time lost after each spike, in steps (our choice: SCSim's 100 ns reset
            at 25 µs per step = 0.004); values ≥ 1 give whole refractory steps.
        excess_carry: what a pixel that still holds a whole threshold or more after firing (it saw more
            than φ in a step) keeps of those whole thresholds: 1 (the default, as the ideal model) keeps
            them, to fire in later steps; 0 drops them, as a pixel that resets at each crossing and reports
            one spike a step does (the paper's "mod φ"); the remainder below φ is always kept.
    """

    dark_mean: float = SCSIM_DARK_CURRENT[0] / SCSIM_WHITE_CURRENT
    dark_std: float = SCSIM_DARK_CURRENT[1] / SCSIM_WHITE_CURRENT
    threshold_std: float = SCSIM_OFFSET_V[1] / SCSIM_NOMINAL_V
    capacitance_std: float = SCSIM_CAPACITANCE[1] / SCSIM_CAPACITANCE[0]
    prnu_std: float = SCSIM_PRNU[1] / SCSIM_PRNU[0]
    jitter_std: float = SCSIM_JITTER_V / SCSIM_NOMINAL_V
    photons_per_white: float = 5.0e4
    readout_delay: float = 100e-9 * 40_000
    excess_carry: float = 1.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            low, high, unit = NOISE_RANGES[f.name]
            number = is_number(value)
            if not number or not low <= value <= high:  # (NaN fails too)
                extra = " (inf disables shot noise)" if f.name == "photons_per_white" else ""
                bounds = f"[{low:g}, {high:g}]{unit}{extra}"
                raise InputError(
                    f"noise parameter {f.name} must lie within {bounds}, got {value!r}", param=f.name
                )

    def draw_patterns(
        self, shape: tuple[int, ...], threshold: float, seed: int | np.random.SeedSequence
    ) -> FixedPatterns:
        """Draw the per-pixel fixed patterns once (numpy, float32), reproducibly from ``seed``."""
        rng = np.random.default_rng(seed)
        gain = np.maximum(1.0 + self.prnu_std * rng.standard_normal(shape), 0.0)
        dark = np.maximum(self.dark_mean + self.dark_std * rng.standard_normal(shape), 0.0)
        capacitance = 1.0 + self.capacitance_std * rng.standard_normal(shape)
        offset = 1.0 + self.threshold_std * rng.standard_normal(shape)
        scale = threshold * np.maximum(capacitance, MIN_RELATIVE_THRESHOLD)
        thr = np.maximum(scale * offset, MIN_RELATIVE_THRESHOLD * threshold)
        return FixedPatterns(
            gain=gain.astype(np.float32),
            dark=dark.astype(np.float32),
            threshold=thr.astype(np.float32),
            jitter=(scale * self.jitter_std).astype(np.float32),
        )


def noise_with(overrides: dict | None, param: str = "noise_params") -> RealisticNoise:
    """The ``realistic`` preset with some parameters replaced, e.g. ``{"dark_mean": 0.0}``.

    Args:
        overrides: ``{name: value}`` over :class:`RealisticNoise`'s fields; None or empty: the preset.
        param: the name errors give (a CLI passes its flag).
    Returns:
        The parameters; InputError naming ``param`` on an unknown name, and naming the field on a value out
        of its range (:data:`NOISE_RANGES`).
    """
    if overrides is None:
        return RealisticNoise()
    if not isinstance(overrides, dict):
        found = f"{overrides!r:.60}"
        raise InputError(f"{param} must be a mapping of noise parameters, found {found}", param=param)
    names = [f.name for f in fields(RealisticNoise)]
    if unknown := [str(k) for k in overrides if k not in names]:
        raise InputError(
            f"{param}: unknown noise parameter {', '.join(unknown)} (known: {', '.join(names)})", param=param
        )
    values = {k: float(v) if is_number(v) else v for k, v in overrides.items()}
    return RealisticNoise(**values)


@dataclass(frozen=True)
class FixedPatterns:
    """Per-pixel fixed patterns, each float32 of the accumulator's shape: (H, W) or (3, H, W).

    Attributes:
        gain: PRNU gain applied to the intensity (dimensionless, mean 1).
        dark: dark current added every step (intensity units per step).
        threshold: the pixel's threshold φ_p (intensity units), mean ≈ φ.
        jitter: std of the per-step threshold noise (intensity units).
    """

    gain: np.ndarray
    dark: np.ndarray
    threshold: np.ndarray
    jitter: np.ndarray


def _to_backend(x: np.ndarray, device: torch.device | None) -> Array:
    return x.copy() if device is None else torch.from_numpy(x.copy()).to(device)


def _clamp_min_(x: Array, low: float) -> Array:
    """In place ``x ← max(x, low)``."""
    return x.clamp_(min=low) if isinstance(x, torch.Tensor) else np.maximum(x, np.float32(low), out=x)


def _clamp_max_(x: Array, high: float) -> Array:
    """In place ``x ← min(x, high)``."""
    return x.clamp_(max=high) if isinstance(x, torch.Tensor) else np.minimum(x, np.float32(high), out=x)


def _sqrt(x: Array, out: Array) -> Array:
    return torch.sqrt(x, out=out) if isinstance(x, torch.Tensor) else np.sqrt(x, out=out)


def _copy_(dst: Array, src: Array) -> Array:
    """``dst[...] = src`` with a dtype cast (bool → float gives 1.0 / 0.0)."""
    if isinstance(dst, torch.Tensor):
        return dst.copy_(src)
    np.copyto(dst, src, casting="unsafe")
    return dst


#: Added to the threshold of a pixel inside a whole dead step, so that it cannot fire (float32-safe).
_BLOCKED = 1e30


class NoiseProcess:
    """The temporal side of the realistic model for one camera: shot noise, threshold jitter, readout delay.

    Per step, with fixed patterns (gain g, dark d, threshold φ_p, jitter σ_p), N = photons_per_white and the
    remaining dead time D of the pixel (steps): ``q = g·I + d``; shot noise ``q ← max(q + √(q/N)·z, 0)``
    (Gaussian approximation of Poisson(N·q)/N); readout delay ``q ← q·(1 − min(D, 1))``, and a pixel with
    D ≥ 1 cannot fire this step; ``D ← max(D − 1, 0)``; threshold ``φ_k = max(φ_p + σ_p·z', 0.05·φ)``; a
    pixel that fires gets ``D = readout_delay``. Call :meth:`charge`, then :meth:`thresholds`, then fire,
    then :meth:`after_spikes`. Numpy and torch share this code and torch's generator: numpy and torch-CPU
    give identical streams; CUDA draws other normals, so it agrees with them in distribution only.
    """

    def __init__(
        self,
        params: RealisticNoise,
        patterns: FixedPatterns,
        seed: np.random.SeedSequence,
        device: torch.device | None = None,
        threshold: float = 1.0,
    ) -> None:
        self.params = params
        self._gain = _to_backend(patterns.gain, device)
        self._dark = _to_backend(patterns.dark, device)
        self._threshold = _to_backend(patterns.threshold, device)
        self._jitter = _to_backend(patterns.jitter, device)
        self._min_threshold = float(np.float32(MIN_RELATIVE_THRESHOLD * threshold))
        zeros = np.zeros(patterns.gain.shape, np.float32)
        self._q, self._tmp, self._thr, self._mark = (_to_backend(zeros, device) for _ in range(4))
        self._delay = params.readout_delay
        self._dead = _to_backend(zeros, device) if self._delay > 0 else None
        # whole dead steps exist only when the delay reaches a full step
        self._block = _to_backend(zeros, device) if self._delay >= 1 else None
        n = params.photons_per_white
        self._shot = 1.0 / math.sqrt(n) if math.isfinite(n) else 0.0
        # torch's generator on both backends (on CPU it is ~2.4× faster than numpy's normal sampler here)
        self._rng = torch.Generator(device=device if device is not None else "cpu")
        self._rng.manual_seed(int(seed.generate_state(1, np.uint64)[0] >> np.uint64(1)))

    def _randn(self, out: Array) -> Array:
        """Fill ``out`` with standard normal draws (a numpy buffer through a zero-copy tensor view)."""
        (out if isinstance(out, torch.Tensor) else torch.from_numpy(out)).normal_(generator=self._rng)
        return out

    def charge(self, intensity: Array) -> Array:
        """Charge collected this step, intensity units; (H, W) or (3, H, W). Returns an internal buffer."""
        q, tmp = self._q, self._tmp
        _copy_(q, intensity)
        q *= self._gain
        q += self._dark
        if self._shot:
            _sqrt(_clamp_min_(q, 0.0), out=tmp)
            tmp *= self._randn(self._thr)
            tmp *= self._shot
            q += tmp
            _clamp_min_(q, 0.0)
        dead = self._dead
        if dead is not None:
            _copy_(tmp, dead)
            if self._block is not None:  # delay ≥ 1 step: block whole dead steps, count down
                _copy_(self._block, tmp >= 1.0)
                self._block *= _BLOCKED
                _clamp_max_(tmp, 1.0)
                dead -= 1.0
                _clamp_min_(dead, 0.0)
            tmp *= -1.0
            tmp += 1.0
            q *= tmp  # q·(1 − min(D, 1))
        return q

    def thresholds(self) -> Array:
        """This step's thresholds φ_k (intensity units, accumulator shape); an internal buffer."""
        thr = self._threshold
        if self.params.jitter_std:
            thr = self._randn(self._thr)
            thr *= self._jitter
            thr += self._threshold
            _clamp_min_(thr, self._min_threshold)
        if self._block is not None:
            _copy_(self._thr, thr)
            thr = self._thr
            thr += self._block
        return thr

    def drop_excess(self, accumulator: Array, threshold: Array | float) -> None:
        """After firing with ``threshold`` (this step's φ_k, as :meth:`thresholds` gave it): keep only
        ``excess_carry`` of the whole thresholds still in ``accumulator`` (float32, updated in place;
        ``A ← A − (1 − c)·φ_k·⌊A / φ_k⌋``). Nothing to do at the default ``excess_carry`` 1."""
        drop = 1.0 - self.params.excess_carry
        if drop <= 0.0:
            return
        tmp = self._tmp
        if isinstance(tmp, torch.Tensor):
            torch.div(accumulator, threshold, out=tmp).floor_()
        else:
            np.floor(np.divide(accumulator, threshold, out=tmp), out=tmp)
        tmp *= threshold
        tmp *= drop
        accumulator -= tmp

    def after_spikes(self, spikes: Array) -> None:
        """Start the readout delay of the pixels that fired (bool, the accumulator's shape)."""
        if self._dead is None:
            return
        mark = _copy_(self._mark, spikes)
        mark *= self._delay
        if self._block is None:  # delay < 1: it ends within the next step, so D is just the new marks
            self._dead, self._mark = mark, self._dead
        elif isinstance(mark, torch.Tensor):  # a pixel that fired had D = 0 after the countdown
            torch.maximum(self._dead, mark, out=self._dead)
        else:
            np.maximum(self._dead, mark, out=self._dead)

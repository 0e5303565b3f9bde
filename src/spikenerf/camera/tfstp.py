"""TFSTP: texture from short-term plasticity (Zheng et al., CVPR 2021), the reconstruction SpikeCV ships.

Each pixel drives a Tsodyks–Markram synapse: available resources ``R`` and utilisation ``u``, updated at each
spike from the interval ``Δ`` (steps) since the previous one and relaxing towards ``R = 1``, ``u = u0`` in
between. At a spike (SpikeCV's update, both from the values before the spike)::

    R ← 1 − (1 − R·(1 − u))·exp(−Δ/D)
    u ← u0 + (u + f·(1 − u) − u0)·exp(−Δ/F)

For a steady interval the state converges to a fixed point that each variable inverts for the interval::

    Δ_R = −D·log((1 − R) / (1 − R·(1 − u)))
    Δ_u = −F·log((u − u0) / (u·(1 − f) + f − u0))

and the image is ``Î = φ · (1/Δ_R + 1/Δ_u) / 2``: exact (``φ/m``) on a pixel firing every ``m`` steps, so the
calibration is the steady-state inversion, in the toolkit's units (1.0 = one threshold a step, as TFP).

The state is kept as the deficits ``1 − R`` and ``u − u0``, and inverted as ``Δ + D·log(A'/A)`` (see
:func:`_rate`), never through the logarithm of a vanishing deficit, so neither a short ``D`` nor a long
interval loses the estimate (SpikeCV's float32 ``R`` rounds to 1.0 after ≈ 17 steps at ``D = 1``). The state
starts at the fixed point of the first interval (as if the pixel had always fired at that rate). Like TFI (and
SpikeCV's offline reconstruction) frame ``k`` is read after the spike that closes the interval containing it,
with TFI's virtual edge spikes (:func:`spikenerf.camera.reconstruct.tfi`): the state after the spikes before
``k``, advanced by that interval. Three scans over time, vectorised over the pixels; the forward scan starts
at frame 0 whatever frames are asked for (the state carries the history).
"""

from __future__ import annotations

import numpy as np

from spikenerf.camera.streams import Array, Frames, check_threshold, first_two, flat_stream, like, row_uint8
from spikenerf.core.errors import InputError, is_number

#: SpikeCV's TFSTP parameters (its ``spkProc/reconstruction/tfstp.py``): D and F in steps (time_unit 1)
DEFAULTS = {"u0": 0.15, "f": 0.15, "D": 1.0, "F": 10.0}


def check_stp(u0: float, f: float, D: float, F: float) -> None:
    """InputError naming the parameter unless ``0 < u0 < 1``, ``0 < f < 1`` and D, F are finite > 0
    (steps)."""
    for name, value, high in (("u0", u0, 1.0), ("f", f, 1.0), ("D", D, np.inf), ("F", F, np.inf)):
        ok = is_number(value) and bool(np.isfinite(value)) and 0 < value < high
        if not ok:
            bound = "0 < {0} < 1" if high == 1.0 else "a finite number of steps > 0"
            raise InputError(f"{name} must be {bound.format(name)}, found {value!r}", param=name)


def tfstp(
    spikes: Array,
    threshold: float = 1.0,
    frames: Frames = None,
    *,
    u0: float = DEFAULTS["u0"],
    f: float = DEFAULTS["f"],
    D: float = DEFAULTS["D"],
    F: float = DEFAULTS["F"],
) -> Array:
    """Texture from short-term plasticity (see the module doc for the model and its calibration).

    Args:
        spikes: (T, H, W) or (T, 3, H, W) 0/1 spikes (numpy or torch; bool, integer, or float 0.0/1.0).
        threshold: φ, a number > 0.
        frames: the output frames (slice, index, None = all, or ascending indices (N,)); only those are
            kept (12 bytes a pixel each while the scans run), but the forward scan runs from frame 0 and the
            backward scans from the stream's end: N frames cost one scan, what the last of them alone costs.
        u0, f: resting utilisation and its increment per spike, in (0, 1). D, F: recovery times of the
            resources and of the utilisation, in steps (> 0).
    Returns:
        float32 (N, ...) linear intensity in [0, φ], the same array type as ``spikes``; 0 where a pixel
        never fires.
    """
    check_threshold(threshold)
    check_stp(u0, f, D, F)
    flat, rest, out_idx = flat_stream(spikes, frames)
    total, pixels = flat.shape
    first, second = first_two(flat)
    # TFI's virtual previous spike: the first interval is max(first + 1, second − first)
    start_extra = np.where(second < total, np.maximum(second - 2 * first - 1, 0), 0).astype(np.int32)
    last = -start_extra - 1
    penult = np.full(pixels, -1, np.int32)
    rate_d, rate_f = np.float32(-1.0 / D), np.float32(-1.0 / F)
    # the state starts at the fixed point of the first interval (as if the pixel had always fired so)
    r, v = _fixed_point(first + 1 + start_extra, u0, f, D, F)
    n = out_idx.size
    r_at, v_at = np.empty((n, pixels), np.float32), np.empty((n, pixels), np.float32)
    prev = np.empty((n, pixels), np.int32)
    wanted = dict(zip(out_idx.tolist(), range(n), strict=True))
    stop = int(out_idx.max()) + 1 if n else 0
    rest_v = np.float32(f * (1.0 - u0))
    for i in range(total):
        if i in wanted:  # the state after the spikes strictly before i
            j = wanted[i]
            r_at[j], v_at[j], prev[j] = r, v, last
        fired = np.flatnonzero(row_uint8(flat[i]))
        if i < stop and fired.size:  # (past the output frames only the last two spikes matter)
            before = last[fired]
            delta, vf = (i - before).astype(np.float32), v[fired]
            # r ← e^(−Δ/D)·(u + r·(1 − u)) with u = u0 + v;  v ← e^(−Δ/F)·(v·(1 − f) + f·(1 − u0))
            r[fired] = np.exp(delta * rate_d) * (u0 + vf + r[fired] * ((1 - u0) - vf))
            v[fired] = np.exp(delta * rate_f) * (vf * (1 - f) + rest_v)
            penult[fired], last[fired] = before, i
        else:
            penult[fired], last[fired] = last[fired], i
    # TFI's virtual next spike after the last one: the last interval is max(T − last, last − penult)
    nxt = np.where(penult >= 0, np.maximum(2 * last - penult, total), total).astype(np.int32)
    out = r_at  # each output row is written over its state once used
    silent = first >= total
    delta = np.empty(pixels, np.int32)
    for i in range(total - 1, -1, -1):
        np.copyto(nxt, i, where=row_uint8(flat[i]).view(bool))
        if i in wanted:
            j = wanted[i]
            np.subtract(nxt, prev[j], out=delta)
            rate = _rate(r_at[j], v_at[j], delta.astype(np.float32), u0, f, D, F)
            rate[silent] = 0.0
            np.multiply(rate, np.float32(threshold), out=out[j])
    return like(out.reshape(n, *rest), spikes)


def _fixed_point(delta: np.ndarray, u0: float, f: float, D: float, F: float) -> tuple[np.ndarray, np.ndarray]:
    """The steady state ``r = 1 − R``, ``v = u − u0`` (P,) float32 of a pixel firing every ``delta`` (P,)
    steps: ``v = f·(1 − u0)·a / (1 − (1 − f)·a)``, ``r = b·u / (1 − b·(1 − u))``, with ``a = e^(−Δ/F)``,
    ``b = e^(−Δ/D)``."""
    a, b = np.exp(-delta / F), np.exp(-delta / D)
    v = f * (1.0 - u0) * a / (1.0 - (1.0 - f) * a)
    u = u0 + v
    return (b * u / (1.0 - b * (1.0 - u))).astype(np.float32), v.astype(np.float32)


def _rate(
    r: np.ndarray,
    v: np.ndarray,
    delta: np.ndarray,
    u0: float,
    f: float,
    D: float,
    F: float,
) -> np.ndarray:
    """The rate ``(1/Δ_R + 1/Δ_u) / 2`` (spikes a step, (P,) float32) that the steady-state inversion gives
    after a spike ``delta`` (P,) float32 steps after the state ``r = 1 − R``, ``v = u − u0`` (P,) float32.

    With ``A = u + r·(1 − u)`` before the spike and ``A'`` after it, ``r' = e^(−Δ/D)·A`` and the inversion
    ``Δ_R = −D·log(r'/A')`` is ``Δ + D·log(A'/A)``; likewise ``Δ_u = Δ + F·log(B'/B)`` with
    ``B = v·(1 − f) + f·(1 − u0)``. No logarithm of a vanishing state: nothing underflows, and the
    estimate is exact (``1/Δ``) at the fixed point, where ``A' = A`` and ``B' = B``."""
    rest_v = np.float32(f * (1.0 - u0))
    big_a = u0 + v + r * ((1 - u0) - v)
    big_b = v * (1 - f) + rest_v
    r2, v2 = np.exp(delta * np.float32(-1.0 / D)) * big_a, np.exp(delta * np.float32(-1.0 / F)) * big_b
    big_a2 = u0 + v2 + r2 * ((1 - u0) - v2)
    big_b2 = v2 * (1 - f) + rest_v
    inv_r = delta + np.float32(D) * np.log(big_a2 / big_a)
    inv_v = delta + np.float32(F) * np.log(big_b2 / big_b)
    return np.float32(0.5) / inv_r + np.float32(0.5) / inv_v

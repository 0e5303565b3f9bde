"""Images from spikes, in one place: TFP, TFI or TFSTP (:mod:`spikenerf.camera.reconstruct`) or the shipped
learned reconstructor (:mod:`spikenerf.recon`, imported only when asked for).

One dispatch, :func:`reconstructor` (``tfp``, ``tfi``, ``tfstp``, ``learned``), in four forms:

* :func:`reconstructor` → ``recon(read, total, start, stop)``: frames ``start:stop`` of a long stream that
  ``read(a, b)`` reads on demand, only the frames the result depends on (``reconstruct``, ``import``);
* :func:`frames_reconstructor` → ``recon(read, total, frames)``: scattered frames (N,) of such a stream in as
  few scans as the method allows (TFSTP one, from frame 0) and only those held (``recon-eval``, the
  no-reference checks);
* :func:`frame_at`: frame ``k`` of a stream, an array or a reader (dataset previews and TFP keyframes, the
  novel-view spike preview, the report's figures);
* :func:`reconstruct_stream`: every step (or a slice) of an in-memory stream, the training targets; there the
  learned reconstruction of a whole stream is made on the training device and cached in the run folder
  (:mod:`spikenerf.data.recon_cache`); :func:`reconstruct_cut` makes them from a stream cut into pieces
  (a hold-out's bands: no image reads a spike across a cut).
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import pairwise
from typing import Literal, get_args

import numpy as np

from spikenerf.camera.frame_range import resolve_frames
from spikenerf.camera.reconstruct import DEFAULT_WINDOW, ReconMethod, reconstruct_at, reconstruct_frames
from spikenerf.camera.streams import frame_indices
from spikenerf.core.errors import InputError, check_choice

#: image reconstructions: the camera's (TFP, TFI, TFSTP) and the learned one (spikenerf.recon)
TargetRecon = Literal[ReconMethod, "learned"]
RECONS: tuple[str, ...] = get_args(TargetRecon)
#: ``read(a, b)`` → frames ``a:b`` (b − a, ...) of a stream, 0/1
Reader = Callable[[int, int], np.ndarray]
#: ``recon(read, total, start, stop)`` → float32 (stop − start, ...) linear frames of a ``total``-frame stream
Reconstructor = Callable[[Reader, int, int, int], np.ndarray]
#: ``recon(read, total, frames)`` → float32 (N, ...) linear frames ``frames`` (N,) (ascending, distinct)
FramesReconstructor = Callable[[Reader, int, np.ndarray], np.ndarray]


def reconstructor(
    recon: str = "tfp",
    window: int | None = None,
    threshold: float = 1.0,
    *,
    weights: object = None,
    color: str = "gray",
) -> Reconstructor:
    """The reconstruction ``recon`` as ``recon(read, total, start, stop)`` (see :data:`Reconstructor`).

    Args:
        recon: ``tfp``, ``tfi``, ``tfstp`` or ``learned``.
        window: TFP's window in frames, odd (None = ``DEFAULT_WINDOW``); for ``learned``, the window the
            network must have been trained on (None = not checked); TFI and TFSTP have none (ignored).
        threshold: φ of the camera.
        weights, color: ``learned`` only: the weights file (None = shipped) or a network loaded already
            (``recon.net.load_weights``, reused as it is) and the stream's colour (gray, one channel of an
            rgb recording, or a Bayer mosaic). The weights are checked now.
    Returns:
        A function whose result equals the whole stream's reconstruction at ``start:stop`` exactly.
    """
    if recon == "learned":
        from spikenerf.recon.infer import learned_reconstructor

        return learned_reconstructor(weights, color, window, threshold)
    check_choice(recon, RECONS, "recon")
    tfp_window = DEFAULT_WINDOW if window is None else window
    return lambda read, total, start, stop: reconstruct_frames(
        read, total, start, stop, recon, tfp_window, threshold
    )


def frames_reconstructor(
    recon: str = "tfp",
    window: int | None = None,
    threshold: float = 1.0,
    *,
    weights: object = None,
    color: str = "gray",
) -> FramesReconstructor:
    """The reconstruction ``recon`` (arguments as :func:`reconstructor`) as ``recon(read, total, frames)``
    (see :data:`FramesReconstructor`): equal to stacking ``reconstructor(...)(read, total, k, k + 1)`` over
    the frames k, bit for bit. TFP, TFI and TFSTP go through
    :func:`~spikenerf.camera.reconstruct.reconstruct_at` (TFSTP: one scan from frame 0 for all frames, not
    one each); learned reconstructs each frame from its own window (a call each, as its cost does not grow
    with the frame's index)."""
    if recon == "learned":
        one = reconstructor(recon, window, threshold, weights=weights, color=color)
        return lambda read, total, frames: np.stack(
            [one(read, total, int(k), int(k) + 1)[0] for k in frame_indices(frames, total)]
        )  # (the frames checked as reconstruct_at checks them)
    check_choice(recon, RECONS, "recon")
    tfp_window = DEFAULT_WINDOW if window is None else window
    return lambda read, total, frames: reconstruct_at(read, total, frames, recon, tfp_window, threshold)


def frame_at(
    spikes: np.ndarray | Reader,
    k: int,
    recon: str = "tfp",
    window: int | None = DEFAULT_WINDOW,
    threshold: float = 1.0,
    total: int | None = None,
) -> np.ndarray:
    """Frame ``k`` (...) float32 linear of a (T, ...) stream, reading only the frames it depends on.

    ``spikes`` is the stream (an array or memory map) or a :data:`Reader` of a ``total``-frame stream;
    ``recon``, ``window``, ``threshold``: see :func:`reconstructor`.
    """
    if callable(spikes):
        if total is None:
            raise InputError("total: the number of frames is needed with a reader", param="total")
        read = spikes
    else:
        stream = spikes
        read, total = (lambda a, b: stream[a:b]), len(stream)
    return reconstructor(recon, window, threshold)(read, total, int(k), int(k) + 1)[0]


def reconstruct_stream(
    spikes: np.ndarray,
    recon: str = "tfp",
    window: int = DEFAULT_WINDOW,
    threshold: float = 1.0,
    frames: slice | None = None,
) -> np.ndarray:
    """Î of every step (or of ``frames``): TFP (``window`` frames, odd), TFI, TFSTP or the shipped learned
    reconstructor (its trained window, which ``window`` must equal) of a (T, H, W) gray or (T, 3, H, W) rgb
    stream → float32 linear (N, ...)."""
    if recon == "learned":  # on the training device and cached in the run folder inside a trainer
        from spikenerf.data.recon_cache import learned_stream

        return learned_stream(spikes, threshold, frames, window)
    check_choice(recon, RECONS, "recon")
    selected = resolve_frames(frames, len(spikes))
    read = lambda a, b: spikes[a:b]  # noqa: E731  (only the kept frames are computed and held)
    tfp_window = DEFAULT_WINDOW if window is None else window
    return reconstruct_frames(read, len(spikes), selected.start, selected.stop, recon, tfp_window, threshold,
                              selected.step)  # fmt: skip


def reconstruct_cut(
    spikes: np.ndarray, recon: str, window: int, threshold: float, cuts: np.ndarray
) -> np.ndarray:
    """Î of every step of a (T, ...) stream cut at the steps ``cuts`` (M,) (ascending, in 1..T−1): each
    piece ``[cuts[i−1], cuts[i])`` reconstructed as a stream of its own (:func:`reconstruct_stream`), so no
    image reads a spike across a cut (TFI's and TFSTP's stream-edge rules apply at the cuts, and TFSTP's
    state starts afresh) → float32 (T, ...) linear."""
    bounds = [0, *(int(c) for c in np.asarray(cuts).reshape(-1)), len(spikes)]
    if any(b <= a for a, b in pairwise(bounds)):
        raise InputError(f"cuts must ascend inside 1..{len(spikes) - 1}, found {bounds[1:-1]}", param="cuts")
    return np.concatenate(
        [reconstruct_stream(spikes[a:b], recon, window, threshold) for a, b in pairwise(bounds)]
    )

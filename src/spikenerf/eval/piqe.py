"""PIQE, a no-reference image quality score that needs no trained weights (docs/metrics.md).

PIQE (Perception-based Image Quality Evaluator; Venkatanath N., Praneeth D., Maruthi Chandrasekhar Bh.,
Channappayya S. S., Medasani S. S., "Blind image quality evaluation using perception based features",
NCC 2015), with the constants of the MathWorks implementation (``piqe`` in MATLAB's Image Processing
Toolbox), which pyiqa and pypiqe follow:

1. the image as 8-bit grey levels: grey = 0.299 R + 0.587 G + 0.114 B of the display values (Rec. 601 luma,
   :data:`spikenerf.core.color.GRAY_WEIGHTS`), then ``round(255 · grey)``;
2. its MSCN coefficients ``(I − μ) / (σ + 1)``, with μ and σ the local mean and standard deviation under a
   7 × 7 Gaussian window of σ = 7/6 px (edge pixels replicated beyond the border);
3. non-overlapping 16 × 16 blocks of the MSCN image; a block is *active* (salient) when the sample
   variance v of its 256 coefficients exceeds 0.1;
4. an active block shows a *noticeable distortion* when one of the 11 runs of 6 consecutive coefficients
   along any of its four edges has a sample standard deviation below 0.1 (a flat run: blocking, a sudden
   artefact), and *noise* when ``√v > 2β``, with β = |√v − r| / max(√v, r) and r the ratio of the standard
   deviation of the two centre columns (0-based 7 and 8) to that of the surround;
5. each active block scores ``(1 − v)`` for a distortion plus ``v`` for noise, and the image
   ``(Σ block scores + 1) / (N_active + 1) · 100``.

Lower is better: 0 when no active block is distorted or noisy, rising with the share of those that are; an
image with no active block (flat, or smooth everywhere) scores exactly 100. PIQE reads large flat or smooth
areas as distortion and mild noise as texture, so a clean synthetic render can score worse than a noisy one
(docs/metrics.md). The formula does not clip: only a block whose MSCN variance exceeds 1 (a 1-px
checkerboard reaches 0.99, a grid of single bright pixels 1.001) and which is flagged by one of the two
tests alone could take the score past 0 or 100.

Two details follow the MathWorks code, so that the numbers agree with it: the surround of the noise test
leaves out columns 7 and 9 (0-based; MATLAB deletes column 8 and then column 9 of the narrowed block), not
the two centre columns, and grey levels of exactly k + 0.5 round up (MATLAB's ``round``). Unlike MATLAB,
which pads an image whose side is not a multiple of 16 by replicating its last row/column (the padded strip
then shows flat edge runs and is scored as distorted), and pypiqe, which pads it by mirroring, only whole
blocks from the top-left corner are scored: the last ``H mod 16`` rows and ``W mod 16`` columns enter the
MSCN of their neighbours (up to 3 px, the window's reach) but no block, so an image scores exactly as its
top-left crop of ``16·(H // 16) + 3`` rows and ``16·(W // 16) + 3`` columns (at most H × W) does. pyiqa
and pypiqe also rescale the image so that its maximum is 255 (MATLAB and this module do not).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from spikenerf.core.color import GRAY_WEIGHTS, is_tensor
from spikenerf.core.errors import InputError

#: the side of a scored block, px
BLOCK = 16
#: a block is active (salient) when the sample variance of its MSCN coefficients exceeds this
ACTIVITY_THRESHOLD = 0.1
#: an edge run whose sample standard deviation is below this marks a noticeable distortion
EDGE_THRESHOLD = 0.1
#: the length of an edge run, px (11 runs per 16-px edge)
RUN = 6
#: the Gaussian window of the local mean and deviation: taps and σ (px)
WINDOW, WINDOW_SIGMA = 7, 7 / 6
#: the centre columns of the noise test and the columns its surround leaves out (0-based)
CENTRE_COLUMNS, SURROUND_DROPPED = (7, 8), (7, 9)
#: what values are allowed past [0, 1] before an image is refused (float rounding of a display transform)
RANGE_SLACK = 1e-3


@dataclass(frozen=True)
class PiqeResult:
    """The score and the per-block findings of :func:`piqe` (BH = H // 16, BW = W // 16 blocks).

    score: the PIQE score (), 0…100 (see the module doc), higher = worse. active, distorted, noisy:
    bool (BH, BW), the active blocks and those of them with a noticeable distortion / noise. variance:
    float64 (BH, BW), each block's MSCN sample variance. block_scores: float64 (BH, BW), each block's
    contribution (0 for an inactive block)."""

    score: float
    active: np.ndarray
    distorted: np.ndarray
    noisy: np.ndarray
    variance: np.ndarray
    block_scores: np.ndarray


def grey_levels(image: Any) -> np.ndarray:
    """8-bit grey levels (H, W) float64 in {0, …, 255} of a display image (H, W) or (H, W, 3) in [0, 1],
    numpy or torch: Rec. 601 luma of RGB, ``round(255 · grey)`` (halves up).

    Raises:
        InputError: naming ``image`` when it is not (H, W) or (H, W, 3), is under 16 px a side, holds
            integers, NaN or infinity, or values outside [0, 1] by more than 1e-3 (those within are clipped).
    """
    if is_tensor(image):
        image = image.detach().cpu()
        kind = str(image.dtype).removeprefix("torch.")
        floating = image.is_floating_point()
        x = image.double().numpy() if floating else None
    else:
        arr = np.asarray(image)
        kind, floating = str(arr.dtype), np.issubdtype(arr.dtype, np.floating)
        x = arr.astype(np.float64) if floating else None
    shape = tuple(image.shape)
    if not (len(shape) == 2 or (len(shape) == 3 and shape[2] == 3)):
        raise InputError(f"image must be (H, W) or (H, W, 3), found shape {shape}", param="image")
    if min(shape[:2]) < BLOCK:
        raise InputError(
            f"image must be at least {BLOCK} px a side (PIQE scores {BLOCK}×{BLOCK} blocks), found {shape}",
            param="image",
        )
    if x is None:
        raise InputError(
            f"image holds {kind} values; give display values in [0, 1] as floats (x / 255 for 8-bit)",
            param="image",
        )
    if not np.isfinite(x).all():
        raise InputError("image holds NaN or infinite values", param="image")
    low, high = float(x.min()), float(x.max())
    if low < -RANGE_SLACK or high > 1 + RANGE_SLACK:
        raise InputError(
            f"image must hold display values in [0, 1], found [{low:.4g}, {high:.4g}] (x / 255 for 8-bit)",
            param="image",
        )
    x = np.clip(x, 0.0, 1.0)
    grey = x if x.ndim == 2 else x @ np.asarray(GRAY_WEIGHTS)
    return np.floor(255.0 * grey + 0.5)


def gaussian_window() -> np.ndarray:
    """The normalised 1-D Gaussian (7,) of σ = 7/6 px; its outer product is the 7 × 7 window."""
    taps = np.arange(WINDOW) - WINDOW // 2
    k = np.exp(-(taps**2) / (2 * WINDOW_SIGMA**2))
    return k / k.sum()


def _blur(x: np.ndarray) -> np.ndarray:
    """(H, W) filtered by the 7 × 7 Gaussian, separably, with the edge pixels replicated: (H, W)."""
    k, r = gaussian_window(), WINDOW // 2
    padded = np.pad(x, r, mode="edge")
    rows = sliding_window_view(padded, WINDOW, axis=1) @ k  # (H + 6, W)
    return sliding_window_view(rows, WINDOW, axis=0) @ k  # (H, W)


def mscn(levels: np.ndarray) -> np.ndarray:
    """Mean-subtracted contrast-normalised coefficients (H, W) of grey levels (H, W) in 0…255:
    ``(I − μ) / (σ + 1)`` with μ, σ² the Gaussian-weighted local mean and variance (|E[I²] − μ²|)."""
    mu = _blur(levels)
    sigma = np.sqrt(np.abs(_blur(levels * levels) - mu * mu))
    return (levels - mu) / (sigma + 1.0)


def blocks_of(coefficients: np.ndarray) -> np.ndarray:
    """The whole non-overlapping 16 × 16 blocks (BH, BW, 16, 16) of (H, W), from the top-left corner
    (BH = H // 16, BW = W // 16; a view)."""
    h, w = (n // BLOCK * BLOCK for n in coefficients.shape)
    return sliding_window_view(coefficients[:h, :w], (BLOCK, BLOCK))[::BLOCK, ::BLOCK]


def score_blocks(blocks: np.ndarray) -> PiqeResult:
    """Steps 3–5 of the module doc on MSCN blocks (BH, BW, 16, 16): the activity, distortion and noise
    tests and the pooled score.

    Raises:
        InputError: naming ``blocks`` when they are not (BH, BW, 16, 16) with BH, BW ≥ 1, or not finite.
    """
    b = np.asarray(blocks, dtype=np.float64)
    if b.ndim != 4 or b.shape[2:] != (BLOCK, BLOCK) or b.shape[0] * b.shape[1] == 0:
        raise InputError(f"blocks must be (BH, BW, 16, 16), found shape {b.shape}", param="blocks")
    if not np.isfinite(b).all():
        raise InputError("blocks hold NaN or infinite values", param="blocks")
    variance = b.var(axis=(2, 3), ddof=1)
    active = variance > ACTIVITY_THRESHOLD
    last = BLOCK - 1
    sides = [b[..., 0, :], b[..., :, last], b[..., last, :], b[..., :, 0]]  # top, right, bottom, left
    edges = np.stack(sides, axis=2)  # (BH, BW, 4, 16)
    runs = sliding_window_view(edges, RUN, axis=-1)  # (BH, BW, 4, 11, 6)
    distorted = active & (runs.std(axis=-1, ddof=1) < EDGE_THRESHOLD).any(axis=(2, 3))
    centre = b[..., list(CENTRE_COLUMNS)].std(axis=(2, 3), ddof=1)
    surround = np.delete(b, list(SURROUND_DROPPED), axis=3).std(axis=(2, 3), ddof=1)
    sigma = np.sqrt(variance)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where((centre == 0) & (surround == 0), 0.0, centre / surround)  # 0/0 → 0, as MATLAB
        beta = np.abs(sigma - ratio) / np.maximum(sigma, ratio)  # NaN (∞/∞) fails the test below
        noisy = active & (sigma > 2 * beta)
    block_scores = np.where(distorted, 1 - variance, 0.0) + np.where(noisy, variance, 0.0)
    score = (block_scores.sum() + 1.0) / (active.sum() + 1.0) * 100.0
    return PiqeResult(float(score), active, distorted, noisy, variance, block_scores)


def piqe(image: Any) -> PiqeResult:
    """The PIQE score of one display image (H, W) grey or (H, W, 3) RGB, values in [0, 1] (numpy or
    torch, any device; computed in float64 numpy on the CPU), with its per-block findings (BH, BW) =
    (H // 16, W // 16); see the module doc. ``piqe(x).score`` is the number, 0…100, higher = worse.

    Raises:
        InputError: naming ``image`` (see :func:`grey_levels`).
    """
    return score_blocks(blocks_of(mscn(grey_levels(image))))

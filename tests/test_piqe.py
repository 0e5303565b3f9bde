"""PIQE (``spikenerf.eval.piqe``): against a slow per-block loop written from the MathWorks description,
hand-computed blocks, its documented values and properties, and its input errors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from scipy.ndimage import correlate, gaussian_filter

from spikenerf.core.color import GRAY_WEIGHTS
from spikenerf.core.errors import InputError
from spikenerf.eval.piqe import grey_levels, piqe, score_blocks


def texture(shape: tuple[int, ...], smooth: float, seed: int) -> np.ndarray:
    """A random texture in [0.2, 0.8]: white noise blurred by ``smooth`` px (0: none)."""
    x = np.random.default_rng(seed).random(shape)
    x = gaussian_filter(x, smooth) if smooth else x
    return 0.2 + 0.6 * (x - x.min()) / (x.max() - x.min())


def slow_piqe(grey: np.ndarray) -> tuple[float, list[tuple[bool, bool, bool]]]:
    """PIQE of a grey image (H, W) in [0, 1], block by block in plain loops, as the MathWorks code describes
    it (no padding: the whole blocks only): (score, [(active, distorted, noisy) per block, row-major])."""
    levels = np.floor(255 * grey + 0.5)
    taps = np.arange(-3, 4)
    g = np.exp(-np.add.outer(taps**2, taps**2) / (2 * (7 / 6) ** 2))
    g /= g.sum()
    mu = correlate(levels, g, mode="nearest")
    sigma = np.sqrt(np.abs(correlate(levels**2, g, mode="nearest") - mu**2))
    norm = (levels - mu) / (sigma + 1)
    total, active_count, found = 0.0, 0, []
    for i in range(0, grey.shape[0] - 15, 16):
        for j in range(0, grey.shape[1] - 15, 16):
            block = norm[i : i + 16, j : j + 16]
            var = float(np.var(block, ddof=1))
            if var <= 0.1:
                found.append((False, False, False))
                continue
            active_count += 1
            edges = [block[0, :], block[:, 15], block[15, :], block[:, 0]]
            distorted = any(np.std(e[s : s + 6], ddof=1) < 0.1 for e in edges for s in range(11))
            centre = np.concatenate([block[:, 7], block[:, 8]])
            narrowed = np.delete(block, 7, axis=1)  # MATLAB: Block(:, 8) = [], then Block(:, 9) = []
            narrowed = np.delete(narrowed, 8, axis=1)
            ratio = np.std(centre, ddof=1) / np.std(narrowed, ddof=1)
            ratio = 0.0 if np.isnan(ratio) else ratio
            beta = abs(np.sqrt(var) - ratio) / max(np.sqrt(var), ratio)
            noisy = bool(np.sqrt(var) > 2 * beta)
            total += distorted * (1 - var) + noisy * var
            found.append((True, bool(distorted), noisy))
    return (total + 1) / (active_count + 1) * 100, found


#: (shape, blur px, noise σ, seed, flat strip px at the left): between them, inactive blocks (the strip),
#: active ones, distorted ones (smooth texture, flat runs) and noisy ones
CASES = [((48, 64), 0.0, 0.0, 0, 24), ((48, 64), 1.5, 0.0, 1, 24), ((40, 37), 1.5, 0.01, 1, 0),
         ((64, 48), 2.5, 0.01, 1, 0), ((33, 80), 1.0, 0.03, 0, 0)]  # fmt: skip


def case_image(shape: tuple[int, int], smooth: float, noise: float, seed: int, strip: int) -> np.ndarray:
    """The image (H, W) of one of :data:`CASES`."""
    image = texture(shape, smooth, seed)
    image[:, :strip] = 0.5
    return np.clip(image + noise * np.random.default_rng(seed + 9).standard_normal(shape), 0, 1)


@pytest.mark.parametrize("case", CASES)
def test_agrees_with_a_slow_per_block_loop(case: tuple) -> None:
    image = case_image(*case)
    result = piqe(image)
    expected, blocks = slow_piqe(image)
    assert result.score == pytest.approx(expected, abs=1e-9)
    rows, cols = case[0][0] // 16, case[0][1] // 16
    assert result.active.shape == result.distorted.shape == result.noisy.shape == (rows, cols)
    found = list(zip(result.active.ravel(), result.distorted.ravel(), result.noisy.ravel(), strict=True))
    assert found == blocks


def test_the_slow_loop_cases_reach_every_branch() -> None:
    """The cases above see active and inactive, distorted and noisy blocks (else they would prove little)."""
    seen = np.zeros(4, dtype=int)
    for case in CASES:
        r = piqe(case_image(*case))
        seen += [(~r.active).sum(), r.active.sum(), r.distorted.sum(), r.noisy.sum()]
    assert (seen > 0).all(), seen


def checkerboard(a: float) -> np.ndarray:
    """An MSCN block (16, 16) of ±a in a 1-px checkerboard."""
    return a * (-1.0) ** np.add.outer(np.arange(16), np.arange(16))


def test_hand_computed_blocks() -> None:
    # ±a: variance 256a²/255; every edge run alternates (std a√1.2); centre and surround both have mean 0,
    # so their ratio is √(32/31) / √(224/223) whatever a is
    ratio = np.sqrt(32 / 31) / np.sqrt(224 / 223)
    half = score_blocks(checkerboard(0.5)[None, None])
    sigma = 0.5 * np.sqrt(256 / 255)
    assert sigma <= 2 * abs(sigma - ratio) / max(sigma, ratio)  # not noisy, by hand
    assert half.active[0, 0] and not half.distorted[0, 0] and not half.noisy[0, 0]
    assert half.score == pytest.approx(50.0, abs=1e-12)  # (0 + 1) / (1 + 1) · 100
    # a = 1: β ≈ 0.0116 < σ / 2, so noisy, scoring its variance: past 100, as the formula allows
    one = score_blocks(checkerboard(1.0)[None, None])
    assert one.noisy[0, 0] and not one.distorted[0, 0]
    assert one.score == pytest.approx((256 / 255 + 1) / 2 * 100, abs=1e-9)
    # a flat run of 6 on the top edge: distorted; variance 250a²/255, surround std a√(218/223)
    flat = checkerboard(0.5)
    flat[0, :6] = 0.0
    var = 250 * 0.25 / 255
    sigma, ratio = np.sqrt(var), np.sqrt(32 / 31) / np.sqrt(218 / 223)
    assert sigma <= 2 * abs(sigma - ratio) / max(sigma, ratio)
    runs = score_blocks(flat[None, None])
    assert runs.distorted[0, 0] and not runs.noisy[0, 0]
    assert runs.variance[0, 0] == pytest.approx(var, abs=1e-12)
    assert runs.score == pytest.approx((1 - var + 1) / 2 * 100, abs=1e-9)
    # pooled over blocks, an inactive (all-zero) one adding nothing and not counted
    grid = np.stack([np.stack([checkerboard(0.5), checkerboard(1.0)]), np.stack([flat, np.zeros((16, 16))])])
    pooled = score_blocks(grid)
    assert pooled.active.tolist() == [[True, True], [True, False]]
    assert pooled.block_scores[1, 1] == 0.0
    assert pooled.score == pytest.approx((0 + 256 / 255 + (1 - var) + 1) / (3 + 1) * 100, abs=1e-9)


def test_the_surround_leaves_out_columns_7_and_9() -> None:
    """The MathWorks code deletes column 8 (1-based) and then column 9 of the narrowed block, i.e. columns 7
    and 9 (0-based): the surround keeps centre column 8. Here that column is 3× the rest of a ±a
    checkerboard, with a chosen so that the block variance is 1: all columns have mean 0, so by hand
    centre std a√(160/31), surround std a√(352/223) → noisy (keeping column 8 out instead would give a
    surround std a√(224/223), a larger ratio and no noise)."""
    a = np.sqrt(255 / 384)
    block = checkerboard(a)
    block[:, 8] *= 3
    sigma, ratio, other = 1.0, np.sqrt(160 / 31 * 223 / 352), np.sqrt(160 / 31 * 223 / 224)
    assert sigma > 2 * (ratio - sigma) / ratio and sigma <= 2 * (other - sigma) / other
    result = score_blocks(block[None, None])
    assert result.variance[0, 0] == pytest.approx(1.0, abs=1e-12)
    assert result.noisy[0, 0] and not result.distorted[0, 0]
    assert result.score == pytest.approx(100.0, abs=1e-9)  # (1 + 1) / (1 + 1) · 100


def test_a_block_that_varies_only_in_column_9_has_a_ratio_of_0() -> None:
    """Column 9 is in neither the centre nor the surround: both deviations are 0, and 0/0 counts as a ratio
    of 0 (MATLAB), so β = 1 and the block is noisy only for σ > 2. Here σ = 1.5 (±b in column 9, variance
    16b²/255 = 2.25): not noisy; distorted (its top edge has a flat run), so it scores 1 − 2.25 — a contrived
    MSCN block that takes the score below 0, as the formula allows."""
    block = np.zeros((16, 16))
    block[:, 9] = np.sqrt(2.25 * 255 / 16) * (-1.0) ** np.arange(16)
    result = score_blocks(block[None, None])
    assert result.variance[0, 0] == pytest.approx(2.25, abs=1e-12)
    assert result.distorted[0, 0] and not result.noisy[0, 0]
    assert result.score == pytest.approx((1 - 2.25 + 1) / 2 * 100, abs=1e-9)


def test_grey_levels_round_halves_up_as_matlab() -> None:
    """255 · (k + 0.5) / 255 is exactly k + 0.5 in floating point: MATLAB's round (and ours) gives k + 1,
    where numpy's and torch's round to even would give k for even k."""
    halves = np.array([[(k + 0.5) / 255 for k in range(0, 32, 2)]] * 16)
    np.testing.assert_array_equal(grey_levels(halves), np.arange(1, 33, 2)[None].repeat(16, 0))


@pytest.mark.parametrize("value", [0.0, 0.37, 1.0])
def test_a_flat_image_has_no_active_block_and_scores_100(value: float) -> None:
    result = piqe(np.full((32, 48), value))
    assert not result.active.any() and result.score == 100.0
    assert piqe(np.full((20, 20, 3), value)).score == 100.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_raises_the_score_of_a_textured_image(seed: int) -> None:
    base = texture((64, 64), 2.0, seed)
    noise = np.random.default_rng(seed + 100).standard_normal(base.shape)
    scores = [piqe(np.clip(base + s * noise, 0, 1)).score for s in (0.05, 0.1, 0.2, 0.3)]
    assert all(a < b for a, b in itertools.pairwise(scores)), scores
    assert all(0 <= s <= 100 for s in scores)


def test_grey_and_rgb_numpy_and_torch_agree() -> None:
    rgb = np.clip(np.stack([texture((48, 40), 1.0, s) for s in range(3)], axis=-1) * [1.2, 0.9, 1.1], 0, 1)
    grey = rgb @ np.asarray(GRAY_WEIGHTS)
    result = piqe(rgb)
    assert 0 <= result.score <= 100
    np.testing.assert_array_equal(grey_levels(rgb), grey_levels(grey))
    assert piqe(grey).score == result.score
    assert piqe(np.repeat(grey[..., None], 3, axis=-1)).score == pytest.approx(result.score, abs=1e-9)
    assert piqe(torch.from_numpy(rgb)).score == result.score
    # float32 (a render): the same grey levels, up to a rounding of a level's half, so a close score
    assert piqe(torch.from_numpy(rgb).float()).score == pytest.approx(result.score, abs=1.0)
    # different content scores differently (the checks above are not of a constant)
    assert piqe(texture((48, 40), 0.0, 7)).score != result.score


def test_only_whole_blocks_are_scored() -> None:
    """The last H mod 16 rows and W mod 16 columns enter the MSCN of their neighbours (the 7 × 7 window
    reaches 3 px) but no block: pixels beyond that reach change nothing."""
    image = np.clip(
        texture((40, 45), 1.0, 5) + 0.05 * np.random.default_rng(6).standard_normal((40, 45)), 0, 1
    )
    result = piqe(image)
    assert result.active.shape == (2, 2)
    far = image.copy()
    far[35:, :] = 0.0
    far[:, 35:] = 1.0
    assert piqe(far).score == result.score
    assert piqe(image[:35, :35]).score == result.score
    near = image.copy()
    near[32:35, :] = 0.0  # within 3 px of the scored rows: their MSCN changes
    assert piqe(near).variance[1].tolist() != result.variance[1].tolist()
    assert piqe(np.full((16, 16), 0.5)).active.shape == (1, 1)  # the smallest image: one block


@pytest.mark.parametrize("height, width", [(50, 70), (33, 47), (16, 31)])
def test_a_side_not_a_multiple_of_16_scores_its_whole_blocks_with_3_px_of_context(
    height: int, width: int
) -> None:
    """The rule of the module doc, at sizes that are not multiples of 16: (H // 16, W // 16) blocks, the
    score exactly that of the top-left crop reaching 3 px (the MSCN window) past them; pixels beyond it
    change nothing, pixels within it do (so cropping to whole blocks first is not the same)."""
    image = np.clip(texture((height, width), 1.0, 8) + 0.05 * np.random.default_rng(9).standard_normal(
        (height, width)), 0, 1)  # fmt: skip
    result = piqe(image)
    rows, cols = height // 16 * 16, width // 16 * 16
    assert result.active.shape == (height // 16, width // 16)
    reach = piqe(image[: min(rows + 3, height), : min(cols + 3, width)])
    assert reach.score == result.score and np.array_equal(reach.variance, result.variance)
    if rows + 3 < height or cols + 3 < width:  # beyond the reach: anything at all
        changed = image.copy()
        changed[rows + 3 :, :] = 1.0
        changed[:, cols + 3 :] = 0.0
        assert piqe(changed).score == result.score
    if rows < height:  # within it: the bottom blocks' MSCN moves
        near = image.copy()
        near[rows:, :] = 1.0 - near[rows:, :]
        assert not np.array_equal(piqe(near).variance[-1], result.variance[-1])
        assert not np.array_equal(piqe(image[:rows, :cols]).variance[-1], result.variance[-1, : cols // 16])


@pytest.mark.parametrize(
    ("image", "says"),
    [
        (np.zeros((32, 32, 4)), r"image must be \(H, W\) or \(H, W, 3\), found shape \(32, 32, 4\)"),
        (np.zeros((3, 32, 32)), r"image must be \(H, W\) or \(H, W, 3\)"),
        (np.zeros(64), r"image must be \(H, W\) or \(H, W, 3\)"),
        (np.zeros((15, 64)), r"image must be at least 16 px a side"),
        (np.zeros((64, 8, 3)), r"image must be at least 16 px a side"),
        (np.full((32, 32), np.nan), r"image holds NaN or infinite values"),
        (np.full((32, 32), np.inf), r"image holds NaN or infinite values"),
        (np.zeros((32, 32), dtype=np.uint8), r"image holds uint8 values"),
        (torch.zeros(32, 32, dtype=torch.uint8), r"image holds uint8 values"),
        (np.full((32, 32), 255.0), r"image must hold display values in \[0, 1\], found \[255, 255\]"),
        (np.full((32, 32), -0.01), r"image must hold display values in \[0, 1\]"),
    ],
)
def test_bad_images_name_the_parameter(image: object, says: str) -> None:
    with pytest.raises(InputError, match=f"^{says}") as err:
        piqe(image)
    assert err.value.params == ("image",)


def test_bad_blocks_name_the_parameter() -> None:
    for blocks in (np.zeros((1, 1, 8, 8)), np.zeros((0, 2, 16, 16)), np.zeros((16, 16))):
        with pytest.raises(InputError, match=r"^blocks must be \(BH, BW, 16, 16\)"):
            score_blocks(blocks)
    with pytest.raises(InputError, match=r"^blocks hold NaN"):
        score_blocks(np.full((1, 1, 16, 16), np.nan))


def test_values_a_rounding_past_the_range_are_clipped() -> None:
    image = texture((32, 32), 1.0, 8)
    image[0, 0], image[5, 5] = 1.0 + 1e-6, -1e-6
    clipped = np.clip(image, 0, 1)
    assert piqe(image).score == piqe(clipped).score

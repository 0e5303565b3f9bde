"""Full-reference image metrics on displayed values: PSNR and SSIM (mip-NeRF convention).

Inputs are torch tensors of shape (N, C, H, W) or (C, H, W) holding display values in [0, 1] (for spikenerf:
linear radiance passed through :func:`spikenerf.core.color.srgb_encode`). Both metrics use data range 1.
Results are per image: a tensor of shape (N,) for batched input, a 0-d tensor for a single (C, H, W) image.
LPIPS lives in :mod:`spikenerf.eval.lpips`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from spikenerf.core.errors import InputError, is_finite
from spikenerf.core.psnr import mse_to_psnr
from spikenerf.core.tensor_checks import as_tensor_arg


@dataclass(frozen=True)
class SSIMConfig:
    """SSIM constants; the defaults are the mip-NeRF / JAX-NeRF evaluation convention."""

    window: int = 11  # taps of the separable Gaussian window
    sigma: float = 1.5  # Gaussian standard deviation, pixels
    k1: float = 0.01
    k2: float = 0.03
    data_range: float = 1.0


def _batched(
    a: torch.Tensor, b: torch.Tensor, data_range: float | None = None
) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Check and lift (C,H,W) to (1,C,H,W); returns (a, b, was_single). Arrays are read as tensors.

    Raises:
        InputError: naming ``a``/``b`` for shapes that differ or are not (N,C,H,W)/(C,H,W), or (given a
            ``data_range``) an integer image scored on the range 1 (8-bit values 0..255 as 0..1 gave a
            PSNR of −21.8 dB), or images without pixels (C, H or W = 0: a mean of nothing, NaN); naming
            ``data_range`` unless it is None or a finite number > 0. A batch of no images (N = 0) is allowed:
            its results are empty.
    """
    if data_range is not None and not (is_finite(data_range) and data_range > 0):
        raise InputError(f"data_range must be a finite number > 0, found {data_range!r}", param="data_range")
    a, b = as_tensor_arg(a, "a"), as_tensor_arg(b, "b")
    if a.shape != b.shape:
        shapes = f"{tuple(a.shape)} vs {tuple(b.shape)}"
        raise InputError(f"a and b: image shapes differ: {shapes}", param=("a", "b"))
    if a.ndim not in (3, 4):
        raise InputError(
            f"a and b must be (N,C,H,W) or (C,H,W) images, found shape {tuple(a.shape)}", param=("a", "b")
        )
    if a.shape[-3:].numel() == 0:
        raise InputError(
            f"a and b must hold pixels (C, H, W ≥ 1), found shape {tuple(a.shape)}", param=("a", "b")
        )
    for name, x in (("a", a), ("b", b)):
        if data_range == 1 and not x.dtype.is_floating_point and x.dtype != torch.bool:
            raise InputError(
                f"{name} holds {x.dtype} values, scored here on the range [0, 1]: convert 8-bit images to "
                "floats (x / 255), or give data_range=255",
                param=name,
            )
    return (a[None], b[None], True) if a.ndim == 3 else (a, b, False)


def mean_or_none(values: list[float | None]) -> float | None:
    """The plain mean of per-view values, or None when there are none or any of them is None."""
    vals = [v for v in values if v is not None]
    return float(sum(vals) / len(vals)) if vals and len(vals) == len(values) else None


def masked_mean(x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Mean over all but the first axis of x (N, ...), counting only where ``mask`` (same shape, bool) is
    set; no mask = the plain mean. An image with an empty mask gives NaN. Returns (N,) float64."""
    x = x.double().flatten(1)
    if mask is None:
        return x.mean(1)
    m = mask.flatten(1).to(x.dtype)
    return (x * m).sum(1) / m.sum(1)


def _mask_batched(mask: torch.Tensor | None, shape: torch.Size) -> torch.Tensor | None:
    if mask is None:
        return None
    mask = as_tensor_arg(mask, "mask")  # (a numpy mask, as the images may be)
    mask = mask[None] if mask.ndim == 3 else mask
    if mask.shape != shape:
        raise InputError(
            f"mask shape {tuple(mask.shape)} differs from the images' {tuple(shape)}", param="mask"
        )
    return mask.bool()


def mse(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared error per image, over the pixels where ``mask`` is set (all if None; NaN if none).

    a, b, mask: (N,C,H,W) or (C,H,W). Returns (N,) or ().
    """
    a, b, single = _batched(a, b)
    out = masked_mean((a.double() - b.double()).square(), _mask_batched(mask, a.shape))
    return out[0] if single else out


def psnr(
    a: torch.Tensor, b: torch.Tensor, data_range: float = 1.0, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB, 10·log10(range² / MSE); +inf for identical images.

    Args:
        a, b: (N,C,H,W) or (C,H,W), values in [0, data_range].
        mask: optional bool of the same shape: the MSE counts only those pixels (a masked PSNR).
    Returns:
        (N,) or () float64, dB.
    """
    _batched(a, b, data_range)  # (its range: an integer image is refused on the range 1)
    return mse_to_psnr(mse(a, b, mask), data_range)


def gaussian_window(taps: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Normalised 1-D Gaussian, (taps,) float64, centred on the middle tap (mip-NeRF's ``filt``)."""
    x = torch.arange(taps, dtype=torch.float64) - (taps - 1) / 2
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def _blur_valid(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Separable 'valid' filtering of (N,C,H,W) with the 1-D kernel w: (N,C,H-k+1,W-k+1)."""
    c = x.shape[1]
    k = w.numel()
    x = F.conv2d(x, w.view(1, 1, k, 1).expand(c, 1, k, 1), groups=c)
    return F.conv2d(x, w.view(1, 1, 1, k).expand(c, 1, 1, k), groups=c)


def ssim_map(a: torch.Tensor, b: torch.Tensor, config: SSIMConfig = SSIMConfig()) -> torch.Tensor:
    """The SSIM map with 'valid' Gaussian filtering (no padding), per channel.

    Follows mip-NeRF's ``compute_ssim``: local (co)variances from E[xy] − E[x]E[y], variances clamped at 0,
    the covariance clamped to ±sqrt(σ_a² σ_b²).

    Args:
        a, b: (N,C,H,W), H and W at least ``config.window``.
    Returns:
        (N, C, H − window + 1, W − window + 1) float64.
    """
    a, b, _ = _batched(a, b, config.data_range)
    if min(a.shape[-2:]) < config.window:
        last = a.shape[-1] in (1, 3) and a.shape[-3] not in (1, 3)
        hint = "; channels last? images here are (C, H, W): permute (H, W, C) ones first" if last else ""
        raise InputError(
            f"SSIM needs images of at least {config.window} px a side, found {tuple(a.shape[-2:])}{hint}",
            param=("a", "b"),
        )
    a, b = a.double(), b.double()
    w = gaussian_window(config.window, config.sigma).to(a.device)
    mu_a, mu_b = _blur_valid(a, w), _blur_valid(b, w)
    var_a = (_blur_valid(a * a, w) - mu_a**2).clamp_min(0.0)
    var_b = (_blur_valid(b * b, w) - mu_b**2).clamp_min(0.0)
    cov = _blur_valid(a * b, w) - mu_a * mu_b
    cov = torch.sign(cov) * torch.minimum(torch.sqrt(var_a * var_b), cov.abs())
    c1 = (config.k1 * config.data_range) ** 2
    c2 = (config.k2 * config.data_range) ** 2
    num = (2 * mu_a * mu_b + c1) * (2 * cov + c2)
    den = (mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2)
    return num / den


def ssim(
    a: torch.Tensor, b: torch.Tensor, config: SSIMConfig = SSIMConfig(), mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Structural similarity, the mean of :func:`ssim_map` over channels and valid pixels.

    Args:
        a, b: (N,C,H,W) or (C,H,W), values in [0, data_range], H and W ≥ 11.
        mask: optional bool of the same shape: average the map only over the window centres where it is
            set (the map's valid region is the image less ``window // 2`` pixels at every border).
    Returns:
        (N,) or () float64 in [-1, 1]; 1 for identical images (NaN where the mask leaves nothing).
    """
    if not isinstance(config, SSIMConfig):
        raise InputError(f"config must be an SSIMConfig, found {type(config).__name__}", param="config")
    a, b, single = _batched(a, b, config.data_range)
    m = _mask_batched(mask, a.shape)
    if m is not None:
        r = config.window // 2
        m = m[..., r : m.shape[-2] - r, r : m.shape[-1] - r]
    out = masked_mean(ssim_map(a, b, config), m)
    return out[0] if single else out

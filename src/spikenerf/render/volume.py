"""Volume rendering as small pure functions: samples along rays, compositing weights, inverse-CDF sampling.

Rays have unit directions, so ray parameters ``t`` and interval lengths ``δ`` are world distances, and
densities ``σ`` are per world unit. Compositing is on a white background:
``C = Σ wᵢ cᵢ + (1 − Σ wᵢ) · 1``, with ``wᵢ = Tᵢ (1 − exp(−σᵢ δᵢ))``, ``Tᵢ = exp(−Σ_{j<i} σⱼ δⱼ)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from spikenerf.core.errors import InputError, is_finite, is_integer, same_shape
from spikenerf.render import volume_triton

BACKGROUND = 1.0
MAX_TAU = 1e3  # optical depth at which transmittance is 0 in float32 and float64


@dataclass
class RenderOutput:
    """What every renderer returns: for N rays (``render_rays``, ``render_rays_chunked``), or shaped as an
    image by ``render_image`` (``color`` (H, W, C), ``depth`` and ``opacity`` (H, W)).

    Attributes:
        color: (N, C) linear radiance composited on white.
        depth: (N,) expected termination distance ``Σ wᵢ tᵢ / Σ wᵢ`` (0 where nothing is hit; mask with
            ``opacity`` for display).
        opacity: (N,) ``Σ wᵢ`` in [0, 1].
        weights: (N, S) compositing weights of the final pass, or None.
        coarse_color: (N, C) the coarse network's colour (NeRF's two-pass MLP only, else None). The trainer
            supervises it with the same target and loss as ``color``.
        num_samples: how many density evaluations the pass made (after empty-space skipping; with a static
            sample budget, the budget).
        dropped_samples: () int64, the samples that did not fit in a static sample budget (the grid's
            ``static_samples``; None otherwise): kept samples past the budget plus the candidate steps
            past its march (``MARCH_SLOTS`` = 4 per budget slot), which are not tested for occupancy and
            count whole, and (with ``static_visible``) the slots before an early stop past that second
            budget: an upper bound, so that the budgets raised by the count hold them. A tensor,
            so that no host sync is needed to make it.
        dropped_colors: () int64, the slots above the weight threshold whose colour the grid's
            ``static_colors`` budget left out (None without that budget).
    """

    color: Tensor
    depth: Tensor
    opacity: Tensor
    weights: Tensor | None = None
    coarse_color: Tensor | None = None
    num_samples: int = 0
    dropped_samples: Tensor | None = None
    dropped_colors: Tensor | None = None


def _same_shapes(reference: str, tensors: dict[str, Tensor | None], dims: int | None = None) -> None:
    """InputError naming the first of ``tensors`` whose shape differs from that of the one named
    ``reference`` (:func:`~spikenerf.core.errors.same_shape`), or, with ``dims``, naming ``reference``
    unless it has that many dimensions; None entries are skipped."""
    ref = tensors[reference]
    assert ref is not None  # (the reference is always given)
    if dims is not None and ref.dim() != dims:
        shape = tuple(ref.shape)
        raise InputError(f"{reference} must have {dims} dimension(s), found shape {shape}", param=reference)
    for name, x in tensors.items():
        if x is not None:
            same_shape(ref, x, name, reference)


def weights_from_density(sigma: Tensor, deltas: Tensor) -> Tensor:
    """Compositing weights (N, S) from densities (N, S) per unit length and interval lengths (N, S) ≥ 0.

    Raises:
        InputError: ``deltas`` not of ``sigma``'s shape.
    """
    _same_shapes("sigma", {"sigma": sigma, "deltas": deltas})
    tau = sigma * deltas
    trans = torch.exp(-torch.cumsum(tau, dim=-1))
    trans = torch.cat([torch.ones_like(trans[..., :1]), trans[..., :-1]], dim=-1)
    return trans * (1.0 - torch.exp(-tau))


def composite(
    weights: Tensor, colors: Tensor, t: Tensor, background: float = BACKGROUND
) -> tuple[Tensor, Tensor, Tensor]:
    """Colour (N, C), depth (N,), opacity (N,) from weights (N, S), colours (N, S, C), distances t (N, S).

    Raises:
        InputError: ``weights`` not (N, S), ``t`` not of its shape, ``colors`` not (N, S, C), or
            ``background`` not a finite number.
    """
    _same_shapes("weights", {"weights": weights, "t": t}, dims=2)
    if colors.dim() != 3 or tuple(colors.shape[:2]) != tuple(weights.shape):
        raise InputError(
            f"colors must be (N, S, C) with (N, S) = {tuple(weights.shape)}, found {tuple(colors.shape)}",
            param="colors",
        )
    _check_background(background)
    opacity = weights.sum(dim=-1)
    color = (weights[..., None] * colors).sum(dim=-2) + (1.0 - opacity)[..., None] * background
    depth = (weights * t).sum(dim=-1) / opacity.clamp_min(1e-10)
    return color, depth, opacity


def ray_offsets(ray: Tensor, n_rays: int) -> Tensor:
    """(N + 1,) int64: where each ray's samples start among M packed samples, then M.

    Args:
        ray: (M,) int64 ray of each sample, non-decreasing. n_rays: N (rays without samples are allowed).
    Returns:
        offsets with ray r's samples at ``offsets[r]:offsets[r + 1]`` (a ``searchsorted``: no host sync).
    """
    return torch.searchsorted(ray, torch.arange(n_rays + 1, device=ray.device, dtype=ray.dtype))


def segment_sum(values: Tensor, ray: Tensor, offsets: Tensor, fused: bool = False) -> Tensor:
    """Per-ray sums (N, ...) of packed values (M, ...): rows ``offsets[r]:offsets[r + 1]`` summed for ray r.

    Args:
        values: (M, ...). ray: (M,) non-decreasing ray of each row.
        offsets: (N + 1,) from :func:`ray_offsets`. fused: (N, K) float32 values summed by the Triton
            kernel of ``volume_triton.py`` (check ``volume_triton.applies``).
    Returns:
        (N, ...), 0 for a ray without rows; differentiable in ``values``. On a CPU ``torch.segment_reduce``
        (each ray's rows added in order by one thread: 3–4× faster than ``index_add``'s scatter with its
        gradient, the same sums); elsewhere ``index_add``.
    """
    if values.dim() == 0 or values.shape[0] != ray.shape[0]:
        raise InputError(
            f"values must be (M, ...) with the M = {ray.shape[0]} rows of ray, found {tuple(values.shape)}",
            param="values",
        )
    if fused and values.dim() <= 2:
        return volume_triton.segment_sum(values, ray, offsets)
    if values.device.type == "cpu" and values.dtype in (torch.float32, torch.float64):
        return torch.segment_reduce(values, "sum", offsets=offsets, axis=0, unsafe=True)
    return values.new_zeros((len(offsets) - 1, *values.shape[1:])).index_add(0, ray, values)


def packed_weights(
    sigma: Tensor,
    deltas: Tensor,
    ray: Tensor,
    n_rays: int,
    offsets: Tensor | None = None,
    fused: bool = False,
) -> Tensor:
    """Compositing weights (M,) of M samples packed ray after ray (no padding); :func:`weights_from_density`.

    Args:
        sigma: (M,) density per unit length. deltas: (M,) interval lengths ≥ 0.
        ray: (M,) int64 ray of each sample, non-decreasing (samples of a ray are contiguous and in order).
        n_rays: N, the number of rays (rays without samples are allowed).
        offsets: (N + 1,) :func:`ray_offsets` of ``ray`` where the caller has them (made here otherwise).
        fused: the depth before each sample from the Triton kernel (:func:`packed_depth_before`).
    Returns:
        (M,) weights ``Tᵢ (1 − exp(−σᵢ δᵢ))``; ``Tᵢ`` sums only the earlier samples of the same ray
        (:func:`packed_depth_before`).
    Raises:
        InputError: ``sigma`` not (M,), or ``deltas`` or ``ray`` not of its shape.
    """
    _same_shapes("sigma", {"sigma": sigma, "deltas": deltas, "ray": ray}, dims=1)
    tau = sigma * deltas
    before = packed_depth_before(tau, ray, n_rays, offsets, fused)
    return torch.exp(-before).to(tau.dtype) * (1.0 - torch.exp(-tau))


def packed_depth_before(
    tau: Tensor, ray: Tensor, n_rays: int, offsets: Tensor | None = None, fused: bool = False
) -> Tensor:
    """Optical depth (M,) of the same ray's earlier samples, ``Σ_{j<i} τⱼ``, for M packed samples.

    Args:
        tau: (M,) optical depth ``σ δ`` of each sample. ray: (M,) non-decreasing ray of each sample.
        n_rays: N, the number of rays. offsets: (N + 1,) :func:`ray_offsets` of ``ray``, or None.
        fused: float32 ``tau`` scanned ray by ray by the Triton kernel of ``volume_triton.py`` (check
            ``volume_triton.applies``); the result is then float32, with the same clamp.
    Returns:
        (M,) float64 (float32 on MPS, which has no float64). The running sum is taken in that precision over
        all samples, then the sum at the ray's first sample is removed, so a ray's depth does not depend on
        how much optical depth the rays before it had. The scan sees ``τ`` clamped to ≤ 1e3 (NaN → 1e3):
        ``exp(−1e3)`` is already 0, so no weight changes, and one infinite or NaN sample cannot make
        ``inf − inf`` for every later ray.
    Raises:
        InputError: ``tau`` not (M,), or ``ray`` not of its shape.
    """
    _same_shapes("tau", {"tau": tau, "ray": ray}, dims=1)
    if offsets is None:
        offsets = ray_offsets(ray, n_rays)
    if fused:
        return volume_triton.depth_before(tau, offsets, MAX_TAU)
    wide = torch.float32 if tau.device.type == "mps" else torch.float64
    tau64 = tau.to(wide)
    tau64 = torch.where(tau64.isnan(), MAX_TAU, tau64.clamp(max=MAX_TAU))
    running = torch.cat([tau64.new_zeros(1), torch.cumsum(tau64, dim=0)])  # (M + 1,): depth before sample i
    at_start = running.index_select(0, offsets[:-1])  # (N,): all earlier rays' depth
    return running[:-1] - at_start.index_select(0, ray)


@torch.no_grad()
def early_stop_mask(
    sigma: Tensor,
    deltas: Tensor,
    ray: Tensor,
    n_rays: int,
    min_transmittance: float,
    offsets: Tensor | None = None,
    fused: bool = False,
) -> Tensor:
    """Early ray termination (instant-ngp, nerfacc's ``early_stop_eps``): (M,) bool, True for the packed
    samples before which the ray's transmittance is still ≥ ``min_transmittance`` (a prefix of each ray).

    Args as :func:`packed_weights` (no gradient flows); ``min_transmittance`` in [0, 1): 0 keeps every
    sample. A sample left out has weight < ``min_transmittance``, and so have all the later ones together.
    """
    if not 0.0 <= min_transmittance < 1.0:
        raise InputError(
            f"min_transmittance must lie in [0, 1), found {min_transmittance}", param="min_transmittance"
        )
    if min_transmittance == 0.0:
        return torch.ones_like(ray, dtype=torch.bool)
    depth = packed_depth_before(sigma * deltas, ray, n_rays, offsets, fused)
    return depth <= -math.log(min_transmittance)


def packed_composite(
    weights: Tensor,
    ray: Tensor,
    n_rays: int,
    t: Tensor,
    colors: Tensor,
    color_index: Tensor | None,
    background: float = BACKGROUND,
    offsets: Tensor | None = None,
    fused: bool = False,
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`composite` of packed samples → colour (N, C), depth (N,), opacity (N,).

    Args:
        weights: (M,) from :func:`packed_weights`. ray: (M,) non-decreasing ray of each sample.
        n_rays: N, the number of rays (rays without samples are allowed). t: (M,) sample distances.
        colors: (K, C) colours of the samples ``color_index`` (K,, increasing); the other samples count as
            colour 0 (the renderers decode colour only where the weight matters). With ``color_index``
            None, colours (M, C) of every sample (a fixed shape: zero the colours that should not count).
        background: the grey level behind the samples (white, 1.0, by default).
        offsets: (N + 1,) :func:`ray_offsets` of ``ray``, or None. Per-ray sums: :func:`segment_sum`
            (``fused``: its Triton kernel).
    Returns:
        colour (N, C) composited over ``background``, depth (N,) (0 where empty), opacity (N,).
    Raises:
        InputError: ``weights`` not (M,), ``ray`` or ``t`` not of its shape, ``colors`` not (K, C) with K
            the length of ``color_index`` (M without it), or ``background`` not a finite number.
    """
    _same_shapes("weights", {"weights": weights, "ray": ray, "t": t}, dims=1)
    rows = weights.shape[0] if color_index is None else color_index.shape[0]
    if colors.dim() != 2 or colors.shape[0] != rows:
        which = "weights" if color_index is None else "color_index"
        raise InputError(
            f"colors must be (K, C) with K = {rows}, the length of {which}, found {tuple(colors.shape)}",
            param="colors",
        )
    _check_background(background)
    if offsets is None:
        offsets = ray_offsets(ray, n_rays)
    sums = segment_sum(torch.stack([weights, weights * t], dim=1), ray, offsets, fused)
    opacity = sums[:, 0]
    depth = sums[:, 1] / opacity.clamp_min(1e-10)
    if color_index is None:
        color = segment_sum(weights[:, None] * colors, ray, offsets, fused)
    else:
        target = ray.index_select(0, color_index)
        wc = weights.index_select(0, color_index)[:, None] * colors
        color = segment_sum(wc, target, ray_offsets(target, n_rays), fused)
    return color + (1.0 - opacity)[:, None] * background, depth, opacity


def _check_count(n: object, name: str) -> None:
    """InputError naming ``name`` unless ``n`` is an integer ≥ 1 (a number of samples per ray)."""
    if not is_integer(n) or n < 1:  # type: ignore[operator]
        raise InputError(f"{name} must be an integer ≥ 1 (samples per ray), found {n!r}", param=name)


def _check_background(background: object) -> None:
    """InputError naming ``background`` unless it is a finite number (a grey level; white is 1.0)."""
    if not is_finite(background):
        raise InputError(f"background must be a finite number, found {background!r}", param="background")


def stratified_samples(near: Tensor, far: Tensor, n: int, perturb: bool) -> tuple[Tensor, Tensor]:
    """``n`` samples per ray in equal bins of [near, far]: one uniform draw per bin, or the bin centre.

    Args:
        near, far: (N,). perturb: random position in each bin (training) or its centre.
    Returns:
        t (N, n) sorted distances, and the bin edges (N, n + 1).
    Raises:
        InputError: ``n`` not an integer ≥ 1, ``near`` not (N,), or ``far`` not of its shape.
    """
    _check_count(n, "n")
    _same_shapes("near", {"near": near, "far": far}, dims=1)
    u = torch.linspace(0.0, 1.0, n + 1, device=near.device, dtype=near.dtype)
    edges = near[:, None] + (far - near)[:, None] * u
    offset = torch.rand_like(edges[:, :-1]) if perturb else torch.full_like(edges[:, :-1], 0.5)
    return edges[:, :-1] + offset * (edges[:, 1:] - edges[:, :-1]), edges


def deltas_from_samples(t: Tensor, far: Tensor) -> Tensor:
    """Interval lengths (N, S): ``t_{i+1} − t_i``, and ``far − t_last`` for the last sample (clamped ≥ 0).

    Raises:
        InputError: ``t`` not (N, S), or ``far`` not (N,).
    """
    if t.dim() != 2 or tuple(far.shape) != (t.shape[0],):
        raise InputError(
            f"t must be (N, S) and far (N,), found {tuple(t.shape)} and {tuple(far.shape)}",
            param=("t", "far"),
        )
    nxt = torch.cat([t[:, 1:], far[:, None].expand(-1, 1)], dim=-1)
    return (nxt - t).clamp_min(0.0)


def sample_pdf(edges: Tensor, weights: Tensor, n: int, perturb: bool) -> Tensor:
    """Inverse-CDF (hierarchical) samples from piecewise-constant weights over bins.

    Args:
        edges: (N, B + 1) sorted bin edges. weights: (N, B) ≥ 0 (detached by the caller).
        n: samples per ray. perturb: uniform random quantiles, else evenly spaced quantiles in [0, 1].
    Returns:
        (N, n) distances inside [edges[:, 0], edges[:, -1]] (unsorted when ``perturb``).
    Raises:
        InputError: ``n`` not an integer ≥ 1, ``weights`` not (N, B), or ``edges`` not (N, B + 1).
    """
    _check_count(n, "n")
    if weights.dim() != 2 or tuple(edges.shape) != (weights.shape[0], weights.shape[1] + 1):
        raise InputError(
            f"edges must be (N, B + 1) for weights (N, B), found {tuple(edges.shape)} and "
            f"{tuple(weights.shape)}",
            param=("edges", "weights"),
        )
    w = weights + 1e-5
    pdf = w / w.sum(dim=-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, dim=-1)], dim=-1).clamp_max(1.0)
    if perturb:
        u = torch.rand(edges.shape[0], n, device=edges.device, dtype=edges.dtype)
    else:
        u = torch.linspace(0.0, 1.0, n, device=edges.device, dtype=edges.dtype).expand(edges.shape[0], n)
    u = u.contiguous()
    idx = torch.searchsorted(cdf.contiguous(), u, right=True)
    nbins = weights.shape[-1]
    below = (idx - 1).clamp(0, nbins)
    above = idx.clamp(0, nbins)
    cdf_b, cdf_a = cdf.gather(1, below), cdf.gather(1, above)
    e_b, e_a = edges.gather(1, below), edges.gather(1, above)
    denom = cdf_a - cdf_b
    frac = (u - cdf_b) / torch.where(denom < 1e-8, torch.ones_like(denom), denom)
    return e_b + frac.clamp(0.0, 1.0) * (e_a - e_b)

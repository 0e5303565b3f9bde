"""Training losses: the masked reconstruction loss and the spike losses (differentiable and paper-faithful).

All intensities are *linear* radiance per readout step (1.0 = white for one step), so the losses are in
linear space. The spike camera rule is ``A ← A + I``; fire when ``A ≥ φ``; then ``A ← A − φ``.

The differentiable spike loss is the *integral (interval) constraint*. With ``D_m = Σ_{k≤m} I_k − φ·N_m``
(``N_m`` = recorded spikes in steps ``1..m``, ``D_0 = 0``) the accumulator after step ``m`` is
``A_m = A_0 + D_m``. Every state of an ideal pixel with ``I ≤ φ`` lies in ``[0, φ)``, so for any pair
``a < b`` of window positions ``D_b − D_a = A_b − A_a ∈ (−φ, φ)``, i.e. the integral over steps ``a+1..b``
lies in ``(φ(N_ab − 1), φ(N_ab + 1))``. These bounds do not involve the unknown start accumulator, and the
recorded spikes are reproduced from *some* ``A_0 ∈ [0, φ)`` exactly when every pair satisfies them.
See docs/method.md for the derivation.
"""

from __future__ import annotations

import torch

from spikenerf.camera.firing import fire
from spikenerf.core import tensor_checks
from spikenerf.core.color import srgb_slope
from spikenerf.core.errors import InputError, is_integer, is_number, nonempty, same_shape
from spikenerf.core.psnr import mse_to_psnr as mse_to_psnr  # re-exported for the trainer
from spikenerf.core.tensor_checks import check_threshold
from spikenerf.train.settings import LOSS_WEIGHTS, LossWeight, PairMode
from spikenerf.train.settings import SPIKE_LOSS_KINDS as SPIKE_LOSS_KINDS  # (defined there)
from spikenerf.train.settings import SpikeLossKind as SpikeLossKind


def recon_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error in linear intensity.

    Args:
        pred: (N, C) rendered linear colour.
        target: (N, C) linear target (``M ⊙ Î`` for spike-nerf: 0 where no spike fell in the mask window).
    Returns:
        Scalar mean over rays and channels.
    Raises:
        InputError: ``pred`` not a tensor or empty (N = 0 or C = 0: the mean of nothing is NaN; a training
            step always draws rays), or ``target`` (a tensor or array) not of ``pred``'s shape (an (N, 1)
            against (N,) would broadcast to (N, N)).
    """
    check_tensor(pred, "pred")
    if not pred.dtype.is_floating_point:  # (an integer mean is a RuntimeError deep in torch)
        raise InputError(f"pred must be floating-point renders, found {pred.dtype}", param="pred")
    target = tensor_checks.as_tensor_arg(target, "target", pred.device)
    same_shape(pred, target, "target", "pred")
    nonempty(pred, "pred", "ray and channel")
    return torch.mean((pred - target.to(pred.dtype)) ** 2)


def check_tensor(x: object, name: str) -> None:
    """InputError naming ``name`` unless ``x`` is a torch tensor (a render, which the loss differentiates)."""
    if not isinstance(x, torch.Tensor):
        raise InputError(f"{name} must be a torch tensor, found {type(x).__name__}", param=name)


def check_steps(intensity: object) -> None:
    """InputError naming ``intensity`` unless it is a tensor (L, ...) with a step axis (not 0-d)."""
    check_tensor(intensity, "intensity")
    if intensity.dim() == 0:  # type: ignore[attr-defined]
        raise InputError(
            "intensity must be (L, ...) with a step axis first, found a 0-d tensor", param="intensity"
        )


def recorded_spikes(spikes: object, like: torch.Tensor) -> torch.Tensor:
    """``spikes`` (a tensor or array, as ``read_dat`` gives) on ``like``'s device, as spikes: bool as they
    are, integers as ``!= 0`` (0/255 frames are spikes, as for TFP), floats as they are, which must be 0.0
    or 1.0 (an InputError naming ``spikes`` where they can be read: ``tensor_checks.readable``)."""
    s = tensor_checks.as_tensor_arg(spikes, "spikes")
    if s.dtype.is_floating_point or s.dtype.is_complex:
        if tensor_checks.readable(s):
            odd = (s != 0) & (s != 1)
            if bool(odd.any()):
                raise InputError(
                    "spikes must be 0/1 (bool, integers, or floats 0.0 and 1.0), found the float value "
                    f"{s[odd].flatten()[0].item()!r} (intensities?)",
                    param="spikes",
                )
    elif s.dtype != torch.bool:
        s = s != 0
    return s.to(like.device)


def window_mean_loss(
    means: torch.Tensor, target: torch.Tensor, band: torch.Tensor | None = None, weight: LossWeight = "linear"
) -> torch.Tensor:
    """Spike-integral loss: rendered window means against the windows' spike-count means.

    ``means`` holds G independent unbiased estimates of each window's mean render (each the mean of renders
    at steps drawn by ``data.integral.stratified_steps``). With G = 1 the loss is the squared error, whose
    expectation is the squared bias plus the estimate's variance: the variance term pulls the renders inside
    a window together (a blur along the motion). With G ≥ 2 it is the U-statistic
    ``mean_{i≠j} (m_i − t)(m_j − t)``, an unbiased estimate of ``(E m − t)²`` with no variance term, so
    its gradient is unbiased for the exact forward model's (docs/spike-integral.md).

    Args:
        means: (B, G, C) linear window-mean estimates. target: (B, C) ``φ N / L`` of each window.
        band: (B, 1) half-width of each window's feasible interval, ``φ / L`` (None: 0). Errors within it
            count as 0 (the interval constraint of a noise-free pixel), beyond it by their distance to it.
            With G ≥ 2 this is biased: each estimate is cut to the band before the U-statistic, which then
            estimates ``(E cut(m − t))²``, not ``cut(E m − t)²`` (> 0 when ``E m`` lies inside the band).
        weight: ``linear``: every ray and channel alike; ``srgb``: each (B, C) term times
            :func:`srgb_weights` of the estimates' mean, a constant of the graph (not of the noisy target),
            so a ray's loss is still least at its expected target. (With G ≥ 2 the weight, read from the
            estimates, is correlated with them: the product form is then unbiased only to first order.)
    Returns:
        Scalar loss (linear intensity squared; may be slightly negative for G ≥ 2, never in expectation).
    Raises:
        InputError: naming ``means`` where it is not floating-point, holds no estimate (G = 0) or no window
            (B = 0 or C = 0: the mean of nothing is NaN; a training step always draws windows); naming
            ``target``, ``band`` or ``weight`` where those are not as above.
    """
    check_tensor(means, "means")
    if not means.dtype.is_floating_point:
        raise InputError(f"means must be floating-point renders, found {means.dtype}", param="means")
    if weight not in LOSS_WEIGHTS:
        raise InputError(f"weight must be one of {', '.join(LOSS_WEIGHTS)}, found {weight!r}", param="weight")
    target = tensor_checks.as_tensor_arg(target, "target", means.device)
    if means.dim() != 3 or target.shape != (means.shape[0], means.shape[2]):
        raise InputError(f"means must be (B, G, C) and target (B, C), found {tuple(means.shape)}, "
                         f"{tuple(target.shape)}", param=("means", "target"))  # fmt: skip
    if means.shape[1] == 0:
        raise InputError(
            "means must hold at least one estimate per window (G ≥ 1), found G = 0", param="means"
        )
    nonempty(means, "means", "window and channel")
    if band is not None:
        band = tensor_checks.as_tensor_arg(band, "band", means.device)
        if band.shape != (means.shape[0], 1):
            raise InputError(
                f"band must be (B, 1) = {(means.shape[0], 1)}, found {tuple(band.shape)}", param="band"
            )
        if tensor_checks.readable(band) and bool((band < 0).any()):  # (NaN passes: a NaN loss shows)
            raise InputError("band must be ≥ 0 (a half-width), found a negative value", param="band")
    d = means - target.to(means.dtype)[:, None]
    if band is not None:
        width = band.to(d.dtype)[:, None]
        d = torch.sign(d) * torch.relu(d.abs() - width)
    g = means.shape[1]
    if weight == "linear":
        if g == 1:
            return torch.mean(d**2)
        total = d.sum(dim=1)
        return torch.mean((total**2 - (d**2).sum(dim=1)) / (g * (g - 1)))
    w = srgb_weights(means.mean(dim=1))
    if g == 1:
        return torch.mean(w * d[:, 0] ** 2)
    total = d.sum(dim=1)
    return torch.mean(w * (total**2 - (d**2).sum(dim=1)) / (g * (g - 1)))


#: the least linear value :func:`srgb_weights` takes the slope at (one 8-bit display step above black)
SRGB_WEIGHT_FLOOR = 1 / 255


def srgb_weights(render: torch.Tensor) -> torch.Tensor:
    """Per-term weights that make a linear squared error count as the sRGB metric counts it: the squared
    slope of ``srgb_encode`` at the detached ``render`` (:func:`core.color.srgb_slope`, taken at no less
    than :data:`SRGB_WEIGHT_FLOOR`: 11.1² at black, 1.2² at mid-grey 0.18, 0.44² at white), divided by
    their mean so that the loss keeps the linear loss's scale (and the learning rate its meaning).

    Args:
        render: (B, C) linear renders (the window means' estimates).
    Returns:
        (B, C) weights ≥ 0 of mean 1 (empty for an empty batch), in ``render``'s dtype, without gradient.
    """
    check_tensor(render, "render")
    with torch.no_grad():
        x = render.detach()
        w = srgb_slope(x.to(torch.promote_types(x.dtype, torch.float32)), SRGB_WEIGHT_FLOOR) ** 2
        return (w / w.mean()).to(render.dtype)


def spike_prefix(intensity: torch.Tensor, spikes: torch.Tensor, threshold: float) -> torch.Tensor:
    """Prefix residuals ``D_m = Σ_{k≤m} I_k − φ·N_m`` of a window, with ``D_0 = 0``.

    Args:
        intensity: (L, ...) rendered linear intensity per step (differentiable).
        spikes: (L, ...) recorded spikes (bool or 0/1) of the same pixels and steps.
        threshold: φ.
    Returns:
        (L + 1, ...) residuals, in intensity units (the accumulator change since the window start).
    Raises:
        InputError: ``spikes`` not of ``intensity``'s shape, or ``threshold`` not a finite number > 0.
    """
    check_steps(intensity)
    spikes = recorded_spikes(spikes, intensity)  # (a numpy stream, as read_dat gives)
    same_shape(intensity, spikes, "spikes", "intensity")
    check_threshold(threshold)
    resid = intensity - threshold * spikes.to(intensity.dtype)
    zero = torch.zeros_like(resid[:1])
    return torch.cat([zero, torch.cumsum(resid, dim=0)], dim=0)


def spike_interval_violation(
    intensity: torch.Tensor,
    spikes: torch.Tensor,
    threshold: float,
    pairs: PairMode = "all",
    max_intensity: float | None = 1.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """How far each window pair's integral falls outside its feasible interval.

    For positions ``a < b`` (``0..L``) the feasible set is ``D_b − D_a ∈ (−φ, φ)``. If intensities may exceed
    φ (``max_intensity`` is None or above φ) the camera can carry ``A ≥ φ``; then only bounds that are
    exact without that assumption are kept: the upper bound needs step ``b`` silent (``A_b < φ``) and the
    lower bound needs step ``a`` silent (``a = 0`` counts as unknown).

    Args:
        intensity: (L, ...) rendered intensity per step. spikes: (L, ...) recorded spikes.
        threshold: φ. pairs: ``"all"`` sub-windows or only the whole ``"window"`` (a = 0, b = L).
        max_intensity: the largest intensity the model can render (1.0 for colours in [0, 1]).
    Returns:
        violation: (P, ...) ≥ 0, in intensity units; length: (P,) steps ``b − a`` of each pair;
        valid: (P, ...) bool, whether the pair's bounds apply.
    """
    check_steps(intensity)
    if max_intensity is not None and not (is_number(max_intensity) and max_intensity > 0):
        raise InputError(
            f"max_intensity must be None or a number > 0, found {max_intensity!r}", param="max_intensity"
        )
    length = intensity.shape[0]
    spikes = recorded_spikes(spikes, intensity)
    d = spike_prefix(intensity, spikes, threshold)
    if pairs == "window":
        a_idx = torch.tensor([0], device=d.device)
        b_idx = torch.tensor([length], device=d.device)
    elif pairs == "all":
        a_idx, b_idx = torch.triu_indices(length + 1, length + 1, offset=1, device=d.device)
    else:
        raise InputError(f"pairs must be 'all' or 'window', found {pairs!r}", param="pairs")
    diff = d[b_idx] - d[a_idx]
    upper = torch.relu(diff - threshold)
    lower = torch.relu(-threshold - diff)
    bounded = max_intensity is not None and max_intensity <= threshold
    if bounded:
        valid = torch.ones_like(diff, dtype=torch.bool)
        violation = upper + lower
    else:
        fired = torch.cat([torch.ones_like(spikes[:1], dtype=torch.bool), spikes.bool()], dim=0)
        silent_b, silent_a = ~fired[b_idx], ~fired[a_idx]
        violation = upper * silent_b + lower * silent_a
        valid = silent_a | silent_b
    return violation, (b_idx - a_idx).to(intensity.dtype), valid


def spike_interval_loss(
    intensity: torch.Tensor,
    spikes: torch.Tensor,
    threshold: float,
    pairs: PairMode = "all",
    max_intensity: float | None = 1.0,
) -> torch.Tensor:
    """Differentiable spike loss: squared hinge on the integral constraint of every window pair.

    Each violation is normalised by ``φ · (b − a)`` (a per-step intensity error in units of φ, the same
    scale as the reconstruction MSE when φ = 1), squared, and averaged over valid pairs, pixels and channels.
    It is zero iff the rendered intensities reproduce the recorded spikes from some start accumulator in
    ``[0, φ)``; its gradient raises the intensity where too few spikes would fire, lowers it where too many.

    Args:
        intensity: (L, N, C) rendered linear intensity of N pixels over L consecutive steps.
        spikes: (L, N, C) recorded spikes of the same pixels and steps.
        threshold: φ. pairs: ``"all"`` or ``"window"``. max_intensity: see :func:`spike_interval_violation`.
    Returns:
        Scalar loss (dimensionless); 0, with a gradient of zeros, where no pair's bounds apply or the window
        holds no pixel (N = 0): a step whose window constrains nothing keeps training on its other terms.
    """
    violation, length, valid = spike_interval_violation(intensity, spikes, threshold, pairs, max_intensity)
    scale = (threshold * length).reshape(-1, *([1] * (violation.dim() - 1)))
    sq = (violation / scale) ** 2
    count = valid.sum().clamp_min(1)
    return (sq * valid).sum() / count


def paper_spike_loss(
    intensity: torch.Tensor,
    spikes: torch.Tensor,
    threshold: float,
    start_accumulator: torch.Tensor,
    warmup: int = 4,
) -> torch.Tensor:
    """The paper-faithful spike loss, **without gradient** (for comparison only).

    As in the paper's code, predicted spikes are fired from *detached* intensities starting from a random
    accumulator; the first ``warmup`` steps are discarded and the mean squared difference to the recorded
    spikes is returned. Spikes are a step function of the intensity, so the result carries no gradient:
    adding it to the total loss changes nothing in training (docs/method.md).

    Args:
        intensity: (L, N, C) rendered intensity. spikes: (L, N, C) recorded spikes.
        threshold: φ. start_accumulator: (N, C) start state in [0, φ). warmup: steps to discard (< L).
    Returns:
        Scalar tensor with ``requires_grad=False``.
    Raises:
        InputError: naming ``intensity`` where it holds no step (L = 0) or no pixel (N = 0 or C = 0: the
            mean of nothing is NaN), ``spikes``, ``threshold`` or ``start_accumulator`` where not as above.
    """
    check_steps(intensity)
    if intensity.shape[0] == 0:
        raise InputError("intensity must hold at least one step, found L = 0", param="intensity")
    nonempty(intensity, "intensity", "pixel and channel")
    spikes = recorded_spikes(spikes, intensity)
    same_shape(intensity, spikes, "spikes", "intensity")
    check_threshold(threshold)
    if not is_integer(warmup) or warmup < 0:  # (a float or a string failed deep in a slice or a max())
        raise InputError(f"warmup must be an integer ≥ 0 (steps), found {warmup!r}", param="warmup")
    acc = tensor_checks.as_tensor_arg(start_accumulator, "start_accumulator", intensity.device)
    if tuple(acc.shape) != tuple(intensity.shape[1:]):  # (N,) against (N, C) broadcast silently
        raise InputError(
            f"start_accumulator must be (N, C) = {tuple(intensity.shape[1:])}, found {tuple(acc.shape)}",
            param="start_accumulator",
        )
    if tensor_checks.readable(acc) and not bool(torch.isfinite(acc).all()):  # (a NaN start fired nothing)
        raise InputError("start_accumulator holds a NaN or an infinity", param="start_accumulator")
    with torch.no_grad():
        acc = acc.detach().to(intensity.dtype)
        fired = []
        for step in intensity.detach():
            out, acc = fire(acc, step, threshold)
            fired.append(out)
        pred = torch.stack(fired).to(intensity.dtype)
        start = min(max(warmup, 0), intensity.shape[0] - 1)
        return torch.mean((pred[start:] - spikes[start:].to(intensity.dtype)) ** 2)


def spike_weight(iteration: int, lam: float, warmup_iters: int, ramp_iters: int) -> float:
    """λ schedule: 0 before ``warmup_iters``, then a linear ramp to ``lam`` over ``ramp_iters`` iterations."""
    if lam <= 0 or iteration < warmup_iters:
        return 0.0
    if ramp_iters <= 0:
        return lam
    return lam * min(1.0, (iteration - warmup_iters + 1) / ramp_iters)

"""Test-time pose optimisation: fit each held-out view's pose to its own image with the field frozen.

The evaluation protocol of NeRF with estimated or refined poses (BARF, Lin et al. 2021; NeRF--, NoPe-NeRF,
SPARF): a run trained on estimated poses lives in its own slightly rotated and shifted frame, so its test
views are first registered to it. Each view gets a 6-DoF correction ``ξ = (ω, ρ)`` (so(3) × R³, the same
camera-frame correction as :mod:`spikenerf.train.pose_refine`: ``c2w' = c2w · [exp(ω) | ρ]``), fitted by
Adam on random pixels of that view for a fixed number of steps, with every field parameter frozen. Only the
6 numbers per view move. A view that shows the mean light of a camera motion (a TFP keyframe scored for a
run with window-aware targets) is given as S poses across that motion: one correction moves all S, and the
fitted image is the mean of their S renders. docs/metrics.md explains why this is reported beside the plain
score, never instead of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from spikenerf.core.errors import InputError, is_finite, is_integer
from spikenerf.data.rays import pixel_rays
from spikenerf.render.base import RadianceModel
from spikenerf.render.model import ray_bounds
from spikenerf.scenes.trajectory import Intrinsics
from spikenerf.train.pose_refine import se3_exp

#: the rate decays exponentially to this fraction of ``lr`` over the steps (settles the random-batch noise)
FINAL_RATIO = 0.1
#: at most this many rays per Adam step: the views are fitted in groups of ``MAX_RAYS // (batch · S)``, and
#: with S poses per view at most ``MAX_RAYS // S`` pixels of a view are drawn per step
MAX_RAYS = 8192


@dataclass
class PoseFit:
    """The result of :func:`fit_view_poses`.

    Attributes:
        poses: (V, 4, 4) or (V, S, 4, 4) float32 corrected camera-to-world poses (as given), on the CPU.
        rotation_deg: (V,) float64 angle of each view's rotation correction (degrees).
        translation: (V,) float64 length of each view's shift (scene units).
        loss_first: mean squared error (linear) of the first step's batch, all views.
        loss_last: the same for the last step's batch.
    """

    poses: Tensor
    rotation_deg: Tensor
    translation: Tensor
    loss_first: float
    loss_last: float


def check_fit_args(
    steps: int, lr: float, batch: int, names: tuple[str, str, str] = ("steps", "lr", "batch")
) -> None:
    """InputError when ``steps`` < 0, ``lr`` is not finite > 0 or ``batch`` < 1, naming the value as in
    ``names`` (the caller's own parameters; the error's ``param`` is the name's first word)."""
    problems = (
        (not is_integer(steps) or not 0 <= steps < 2**63, "an integer ≥ 0 (below 2**63)", steps),
        (not (is_finite(lr) and lr > 0), "a finite number > 0", lr),
        (not is_integer(batch) or batch < 1, "an integer ≥ 1", batch),
    )
    for name, (bad, wanted, value) in zip(names, problems, strict=True):
        if bad:
            raise InputError(f"{name} must be {wanted}, found {value!r}", param=name.split()[0])


def fit_view_poses(
    model: RadianceModel,
    poses: Tensor,
    images: Tensor,
    intrinsics: Intrinsics,
    near: float | None = None,
    far: float | None = None,
    steps: int = 200,
    lr: float = 2e-3,
    batch: int = 1024,
    seed: int = 0,
) -> PoseFit:
    """Fit a camera-frame correction of each view's pose to its image, the model frozen.

    Args:
        model: the trained radiance model; its parameters are not changed (nor is their ``requires_grad``).
        poses: (V, 4, 4) initial camera-to-world poses (OpenGL axes), or (V, S, 4, 4): S poses per view whose
            mean render the image shows; one correction per view moves all S (each in its camera frame).
        images: (V, H, W, C) linear target images, C = ``model.channels``.
        intrinsics: the views' pinhole camera (H × W). near/far: optional scalar ray limits.
        steps: Adam steps (0: the poses come back unchanged). lr: Adam's first rate (radians and scene
            units per step), decaying exponentially to ``FINAL_RATIO`` · lr at the last step.
        batch: random pixels per view and step (at most ``MAX_RAYS // S``); views are fitted in groups of
            ``MAX_RAYS // (batch · S)``, at least one (each view's fit is independent: Adam works per
            element). seed: the pixel draws (same seed → same result).
    Returns:
        a :class:`PoseFit`: corrected poses shaped as given, (V, 4, 4) or (V, S, 4, 4), and each view's
            correction size.
    """
    check_fit_args(steps, lr, batch)
    given = torch.as_tensor(poses).to(model.device, torch.float32)
    images = torch.as_tensor(images).to(model.device, torch.float32)
    v, h, w = images.shape[:3]
    poses = given[:, None] if given.ndim == 3 else given  # (V, S, 4, 4)
    bad = poses.shape[::2] != (v, 4) or poses.shape[-1] != 4 or poses.shape[1] < 1
    if bad or (h, w) != (intrinsics.height, intrinsics.width):
        raise ValueError(f"poses {tuple(given.shape)} and images {tuple(images.shape)} do not match")
    gen = torch.Generator().manual_seed(seed)
    frozen = [p for p in model.parameters() if p.requires_grad]
    was_training = model.training
    model.eval()
    batch = min(batch, max(1, MAX_RAYS // poses.shape[1]))  # one view's rays stay within MAX_RAYS
    group = max(1, MAX_RAYS // (batch * poses.shape[1]))  # views fitted together: a training step's memory
    xis, firsts, lasts = [], [], []
    try:
        for p in frozen:
            p.requires_grad_(False)
        for lo in range(0, v, group):
            sl = slice(lo, lo + group)
            xi, first, last = _fit_group(
                model, poses[sl], images[sl], intrinsics, (near, far), steps, lr, batch, gen
            )
            xis.append(xi)
            firsts.append(first * len(xi))
            lasts.append(last * len(xi))
    finally:
        for p in frozen:
            p.requires_grad_(True)
        model.train(was_training)
    xi = torch.cat(xis) if xis else torch.zeros(0, 6, device=model.device)
    with torch.no_grad():
        fitted = (poses @ se3_exp(xi)[:, None]).reshape(given.shape).cpu()
    return PoseFit(
        poses=fitted,
        rotation_deg=torch.rad2deg(xi[:, :3].norm(dim=1)).double().cpu(),
        translation=xi[:, 3:].norm(dim=1).double().cpu(),
        loss_first=sum(firsts) / v if steps and v else math.nan,
        loss_last=sum(lasts) / v if steps and v else math.nan,
    )


def _fit_group(
    model: RadianceModel,
    poses: Tensor,
    images: Tensor,
    intrinsics: Intrinsics,
    bounds: tuple[float | None, float | None],
    steps: int,
    lr: float,
    batch: int,
    gen: torch.Generator,
) -> tuple[Tensor, float, float]:
    """Fit the corrections ξ (G, 6) of G views (poses (G, S, 4, 4), images (G, H, W, C)) together; returns ξ
    (detached) and the per-pixel loss of the first and the last step (NaN with no steps)."""
    v, h, w = images.shape[:3]
    s = poses.shape[1]
    xi = torch.zeros(v, 6, device=model.device, requires_grad=True)
    opt = torch.optim.Adam([xi], lr=lr)
    decay = torch.optim.lr_scheduler.ExponentialLR(opt, FINAL_RATIO ** (1 / max(steps, 1)))
    losses: list[float] = []
    for _ in range(steps):
        idx = torch.randint(0, h * w, (v, batch), generator=gen).to(model.device)  # (G, B)
        pixels = torch.stack([idx % w, idx // w], -1).reshape(-1, 2)  # (G·B, 2) (x, y)
        view = torch.arange(v, device=model.device).repeat_interleave(batch)
        corrected = poses @ se3_exp(xi)[:, None]  # (G, S, 4, 4)
        origins, dirs = pixel_rays(
            corrected[view].reshape(-1, 4, 4), intrinsics, pixels.repeat_interleave(s, 0)
        )
        lo, hi = ray_bounds(model, origins, dirs, *bounds)
        color = model.render_rays(origins, dirs, lo, hi, perturb=False).color.unflatten(0, (-1, s)).mean(1)
        target = images[view, pixels[:, 1], pixels[:, 0]]
        loss = ((color - target) ** 2).mean() * v  # each view's mean: its gradient does not shrink with G
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        decay.step()
        losses.append(loss.item() / v)
    return xi.detach(), (losses[0] if losses else math.nan), (losses[-1] if losses else math.nan)

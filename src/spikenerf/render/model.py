"""Building models, bounding rays by the scene box, and rendering whole images."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from spikenerf.data.rays import as_poses, image_rays, ray_box_bounds
from spikenerf.fields.registry import FIELD_REGISTRY, build_field
from spikenerf.render.base import RadianceModel
from spikenerf.render.grid_model import GridModel
from spikenerf.render.inference import render_autocast
from spikenerf.render.mlp_model import MLPModel
from spikenerf.render.volume import RenderOutput
from spikenerf.scenes.trajectory import Intrinsics

#: field kind (a ``spikenerf.fields.FIELD_REGISTRY`` key) -> the model that pairs it with its sampler
MODELS: dict[str, type[RadianceModel]] = {m.kind: m for m in (GridModel, MLPModel)}


def build_model(
    kind: str, channels: int, scene_box: Tensor | np.ndarray, config: Any = None
) -> RadianceModel:
    """A renderable radiance model.

    Args:
        kind: "grid" (TensoRF-VM, fast, the default) or "mlp" (the paper's vanilla NeRF).
        channels: 1 (gray) or 3 (rgb).
        scene_box: (2, 3) world bounds (min, max) of the content.
        config: None (defaults), a ``GridFieldConfig`` / ``MLPFieldConfig``, or a dict of their fields.
    """
    field = build_field(kind, channels, torch.as_tensor(np.asarray(scene_box), dtype=torch.float32), config)
    return MODELS[kind](field)  # type: ignore[call-arg]


def model_from_hparams(hparams: dict[str, Any], state_dict: dict[str, Tensor] | None = None) -> RadianceModel:
    """Rebuild a model from :meth:`RadianceModel.hparams` (``scene_box`` (2, 3)) and optionally load a state
    dict (tensor shapes as saved: a checkpoint of an upsampled grid resizes the grid). A grid saved before
    ``decoder_bf16`` existed keeps its float32 decoder."""
    config = hparams["config"]
    if isinstance(config, dict) and hparams["kind"] in FIELD_REGISTRY:
        config = {**FIELD_REGISTRY[hparams["kind"]].saved_defaults, **config}
    model = build_model(hparams["kind"], hparams["channels"], np.asarray(hparams["scene_box"]), config)
    if state_dict is not None:
        model.load_state_dict(state_dict)
    return model


def ray_bounds(
    model: RadianceModel, origins: Tensor, dirs: Tensor, near: float | None = None, far: float | None = None
) -> tuple[Tensor, Tensor]:
    """near/far (N,) of rays inside the model's scene box, optionally narrowed to scalar ``[near, far]``."""
    lo, hi = ray_box_bounds(origins, dirs, model.scene_box)
    if near is not None:
        lo = lo.clamp_min(near)
    if far is not None:
        hi = hi.clamp_max(far)
    return lo, torch.maximum(hi, lo)


@torch.no_grad()
def render_rays_chunked(
    model: RadianceModel, origins: Tensor, dirs: Tensor, near: Tensor, far: Tensor, chunk: int = 8192,
    precision: str = "fp32",
) -> RenderOutput:  # fmt: skip
    """Deterministic render of many rays in chunks of ``chunk`` rays: a :class:`RenderOutput` with colour
    (N, C), depth (N,), opacity (N,) float32 and the summed ``num_samples`` (no per-sample weights).
    ``precision``: fp32, or fp16/bf16 autocast (:mod:`spikenerf.render.inference`)."""
    parts = []
    for i in range(0, origins.shape[0], chunk):
        with render_autocast(model.device, precision):
            p = model.render_rays(
                origins[i : i + chunk], dirs[i : i + chunk], near[i : i + chunk], far[i : i + chunk]
            )
        parts.append(p)
    return RenderOutput(
        color=torch.cat([p.color.float() for p in parts]),
        depth=torch.cat([p.depth.float() for p in parts]),
        opacity=torch.cat([p.opacity.float() for p in parts]),
        num_samples=sum(p.num_samples for p in parts),
    )


@torch.no_grad()
def render_image(
    model: RadianceModel,
    c2w: Tensor | np.ndarray,
    intrinsics: Intrinsics,
    near: float | None = None,
    far: float | None = None,
    chunk: int = 8192,
    precision: str = "fp32",
) -> RenderOutput:
    """Render one view (no perturbation, no gradients) on the model's device.

    Args:
        c2w: (4, 4) camera-to-world (OpenGL axes). near/far: optional scalar limits inside the scene box.
        chunk: rays per render call. precision: fp32 | fp16 | bf16 (see :func:`render_rays_chunked`).
    Returns:
        a :class:`RenderOutput` shaped as the image: ``color`` (H, W, C) linear in [0, 1] on white, ``depth``
        (H, W) world distance along the ray (0 where empty), ``opacity`` (H, W).
    """
    pose = as_poses(c2w, model.device)
    origins, dirs = image_rays(pose, intrinsics)
    lo, hi = ray_bounds(model, origins, dirs, near, far)
    out = render_rays_chunked(model, origins, dirs, lo, hi, chunk, precision)
    h, w = intrinsics.height, intrinsics.width
    return RenderOutput(
        out.color.view(h, w, -1), out.depth.view(h, w), out.opacity.view(h, w), num_samples=out.num_samples
    )


def render_mean(
    model: RadianceModel,
    poses: Tensor | np.ndarray,
    intrinsics: Intrinsics,
    near: float | None = None,
    far: float | None = None,
    chunk: int = 8192,
    precision: str = "fp32",
) -> Tensor:
    """The mean color (H, W, C), linear, of the renders at ``poses`` (S, 4, 4): what a view shows whose light
    was gathered over a camera motion (a TFP window, an exposure); S = 1 is :func:`render_image`'s color."""
    colors = [render_image(model, pose, intrinsics, near, far, chunk, precision).color for pose in poses]
    return torch.stack(colors).mean(dim=0)

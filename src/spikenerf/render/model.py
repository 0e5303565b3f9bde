"""Building models, bounding rays by the scene box, and rendering whole images."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from torch import Tensor

from spikenerf.core.errors import InputError, is_integer, is_number
from spikenerf.core.tensor_checks import as_tensor_arg
from spikenerf.data.rays import as_poses, image_rays, ray_box_bounds
from spikenerf.fields.registry import FIELD_REGISTRY, build_field
from spikenerf.render.base import RadianceModel
from spikenerf.render.grid_model import GridModel
from spikenerf.render.inference import inference_chunk, render_autocast
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
    box = as_tensor_arg(scene_box, "scene_box").to(torch.float32)  # (a string or a ragged list: named)
    field = build_field(kind, channels, box, config)
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
    """near/far (N,) of rays inside the model's scene box, optionally narrowed to scalar ``[near, far]``.

    Raises:
        InputError: naming ``origins``/``dirs`` unless they are tensors (N, 3) of one shape, or ``near``/
            ``far`` unless None or a finite number (a NaN bound gave NaN bounds) with ``near < far``.
            Shapes and Python numbers only: no device sync, and a compiled training step keeps its one graph.
    """
    for name, rays in (("origins", origins), ("dirs", dirs)):
        if not isinstance(rays, Tensor) or rays.dim() != 2 or rays.shape[1] != 3:
            found = f"{type(rays).__name__} of shape {tuple(getattr(rays, 'shape', ()))}"
            raise InputError(f"{name} must be a tensor (N, 3), found {found}", param=name)
    if tuple(dirs.shape) != tuple(origins.shape):
        raise InputError(
            f"dirs must have the shape of origins, {tuple(origins.shape)}, found {tuple(dirs.shape)}",
            param="dirs",
        )
    check_bounds(near, far)  # (a NaN bound gave NaN bounds; near ≥ far every ray empty, a white image)
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
    ``precision``: fp32, or fp16/bf16 autocast (:mod:`spikenerf.render.inference`). ``chunk``: an integer
    ≥ 1 (InputError naming it otherwise: 0 was a ValueError of range(), a negative one of torch.cat)."""
    if not is_integer(chunk) or chunk < 1:
        raise InputError(
            f"chunk must be an integer ≥ 1 (rays per render call), found {chunk!r}", param="chunk"
        )
    n = origins.shape[0]
    if n == 0:  # no ray: empty outputs (torch.cat of no parts failed)
        empty = torch.zeros(0, device=model.device)
        return RenderOutput(empty.new_zeros(0, model.channels), empty, empty.clone(), num_samples=0)
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


def check_poses(poses: Tensor | np.ndarray, param: str, one: bool = False) -> None:
    """InputError naming ``param`` unless ``poses`` is finite camera-to-world (4, 4) (``one``) or (N, 4, 4)
    (N ≥ 0). A tensor on a GPU is read back for the finite check (one host sync: render calls only, never a
    training step)."""
    if isinstance(poses, (list, tuple)) and poses and all(isinstance(p, Tensor) for p in poses):
        shapes = {tuple(p.shape) for p in poses}
        if len(shapes) > 1:
            raise InputError(f"{param}: poses of different shapes {sorted(shapes)}", param=param)
        poses = torch.stack(list(poses))  # (a list of tensors, maybe on a GPU: no numpy view of them)
    if hasattr(poses, "poses") and hasattr(poses, "steps"):  # a Trajectory (orbit(...)) read as (N,) objects
        message = f"{param}: pass the trajectory's poses (trajectory.poses), not the Trajectory"
        raise InputError(message, param=param)
    shape = tuple(poses.shape) if hasattr(poses, "shape") else tuple(np.shape(poses))
    want = (4, 4) if one else ("N", 4, 4)
    if len(shape) != len(want) or shape[-2:] != (4, 4):
        shown = "(4, 4)" if one else "(N, 4, 4)"
        hint = " (one pose? pass poses[None])" if not one and shape == (4, 4) else ""
        raise InputError(f"{param} must be {shown} camera-to-world, found shape {shape}{hint}", param=param)
    if isinstance(poses, Tensor):
        finite = bool(torch.isfinite(poses).all())
    else:
        finite = bool(np.isfinite(np.asarray(poses, dtype=np.float64)).all())
    if not finite:
        raise InputError(f"{param} holds a NaN or an infinity", param=param)


def check_model(model: object) -> None:
    """InputError naming ``model`` unless it is a :class:`RadianceModel` (``build_model``, or
    ``model_from_hparams`` of a checkpoint; None was an AttributeError deep in the renderer)."""
    if not isinstance(model, RadianceModel):
        found = type(model).__name__
        raise InputError(f"model must be a RadianceModel (build_model(...)), found {found}", param="model")


def check_intrinsics(intrinsics: object) -> None:
    """InputError naming ``intrinsics`` unless it is an :class:`Intrinsics` (None or a dict was an
    AttributeError deep in the ray builder)."""
    if not isinstance(intrinsics, Intrinsics):
        found = type(intrinsics).__name__
        raise InputError(
            f"intrinsics must be an Intrinsics (scenes.Intrinsics), found {found}", param="intrinsics"
        )


def check_bounds(near: float | None, far: float | None) -> None:
    """InputError naming ``near``/``far`` unless each is None or a finite number and ``near < far`` when
    both are given (``chunk`` is checked by :func:`spikenerf.render.inference.inference_chunk`)."""
    for name, value in (("near", near), ("far", far)):
        if value is None:
            continue
        if not is_number(value) or not math.isfinite(value):  # (math, not numpy: it runs in a compiled step)
            raise InputError(f"{name} must be None or a finite number, found {value!r}", param=name)
    if near is not None and far is not None and not near < far:
        raise InputError(
            f"near must be less than far, found near {near:g}, far {far:g}", param=("near", "far")
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
        c2w: (4, 4) finite camera-to-world (OpenGL axes); one pose, not a stack (see :func:`render_mean`).
        near/far: optional scalar limits inside the scene box, ``near < far``.
        chunk: rays per render call, 0 = automatic (:func:`spikenerf.render.inference.inference_chunk`).
        precision: fp32 | fp16 | bf16 (see :func:`render_rays_chunked`).
    Returns:
        a :class:`RenderOutput` shaped as the image: ``color`` (H, W, C) linear in [0, 1] on white, ``depth``
        (H, W) world distance along the ray (0 where empty), ``opacity`` (H, W).
    Raises:
        InputError: naming ``c2w``, ``near``/``far`` or ``chunk``.
    """
    check_model(model)
    check_poses(c2w, "c2w", one=True)
    check_bounds(near, far)
    check_intrinsics(intrinsics)
    chunk = inference_chunk(model, chunk)
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
    """The mean color (H, W, C), linear, of the renders at ``poses`` (S, 4, 4) (S ≥ 1, finite): what a view
    shows whose light was gathered over a camera motion (a TFP window, an exposure); S = 1 is
    :func:`render_image`'s color. ``near``, ``far``, ``chunk``, ``precision``: as :func:`render_image`."""
    check_poses(poses, "poses")
    if len(poses) == 0:
        raise InputError("poses: need at least one pose (S ≥ 1), found none", param="poses")
    check_bounds(near, far)
    chunk = inference_chunk(model, chunk)
    colors = [render_image(model, pose, intrinsics, near, far, chunk, precision).color for pose in poses]
    return torch.stack(colors).mean(dim=0)

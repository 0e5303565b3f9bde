"""Rays through pixel centres and their intersection with the scene box (small pure functions).

Conventions: camera-to-world poses with OpenGL camera axes (+X right, +Y up, looking down −Z); image row 0 is
the top of the image, so it has the most positive camera y. Pixel ``(x, y)`` = (column, row) is hit at its
centre ``(x + 0.5, y + 0.5)``. Directions are unit vectors, so ray parameters ``t`` are world distances.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from spikenerf.core.errors import InputError
from spikenerf.scenes.trajectory import Intrinsics


def _as_tensor(x: Tensor | np.ndarray, dtype: torch.dtype | None = None) -> Tensor:
    t = torch.as_tensor(np.ascontiguousarray(x) if isinstance(x, np.ndarray) else x)  # (no negative strides)
    if dtype is not None:
        return t.to(dtype)
    return t if t.is_floating_point() else t.float()


def camera_directions(intrinsics: Intrinsics, pixels: Tensor, dtype: torch.dtype = torch.float32) -> Tensor:
    """Unnormalised directions in camera space for integer pixels: every ray of the toolkit starts here.

    Args:
        intrinsics: the camera. pixels: (N, 2) int, ``(x=column, y=row)``. dtype: of the result.
    Returns:
        (N, 3) ``((x + .5 − cx)/fx, −(y + .5 − cy)/fy, −1)`` for a pinhole camera. With a lens
        (``intrinsics.distortion``) the pixel centre's normalised coordinates are the distorted ones: they
        are undistorted (:meth:`~spikenerf.scenes.distortion.Distortion.undistort`, OpenCV's y down) first,
        so the ray is the one the lens bent onto that pixel.
    Raises:
        InputError: ``pixels`` not (N, 2).
    """
    if pixels.dim() != 2 or pixels.shape[1] != 2:
        raise InputError(f"pixels must be (N, 2) (x, y) pairs, found {tuple(pixels.shape)}", param="pixels")
    px = pixels.to(dtype)
    lens = intrinsics.distortion
    if lens is not None:
        xd = (px[:, 0] + 0.5 - intrinsics.cx) / intrinsics.fl_x
        x, y = lens.undistort(xd, (px[:, 1] + 0.5 - intrinsics.cy) / intrinsics.fl_y)
        return torch.stack([x, -y, -torch.ones_like(x)], dim=-1)
    u = (px[:, 0] + 0.5 - intrinsics.cx) / intrinsics.fl_x
    v = -(px[:, 1] + 0.5 - intrinsics.cy) / intrinsics.fl_y
    return torch.stack([u, v, -torch.ones_like(u)], dim=-1)


def pixel_rays(c2w: Tensor | np.ndarray, intrinsics: Intrinsics, pixels: Tensor) -> tuple[Tensor, Tensor]:
    """World rays through the centres of the given pixels.

    Args:
        c2w: (4, 4) one pose for all pixels, or (N, 4, 4) one pose per pixel (camera-to-world, OpenGL axes).
        intrinsics: pinhole camera.
        pixels: (N, 2) int, ``(x=column, y=row)``.
    Returns:
        origins (N, 3) and unit directions (N, 3), in the dtype of ``c2w`` (float32 if it is not floating),
        also under ``--amp`` (autocast is off here: bfloat16 directions miss their pixel by up to 3 px at
        400×400).
    Raises:
        InputError: ``c2w`` not (4, 4) or (N, 4, 4) with the N of ``pixels``, or ``pixels`` not (N, 2).
    """
    pose = _as_tensor(c2w)
    pixels = torch.as_tensor(pixels, device=pose.device)
    n = pixels.shape[0] if pixels.dim() else -1
    if (
        tuple(pose.shape[-2:]) != (4, 4)
        or pose.dim() not in (2, 3)
        or (pose.dim() == 3 and pose.shape[0] != n)
    ):
        raise InputError(
            f"c2w must be (4, 4) or (N, 4, 4) for the N = {n} pixels, found {tuple(pose.shape)}", param="c2w"
        )
    d_cam = camera_directions(intrinsics, pixels, pose.dtype)
    rot = pose[..., :3, :3]
    with torch.autocast(pose.device.type, enabled=False):
        if pose.dim() == 2:
            dirs = d_cam @ rot.T
            origins = pose[:3, 3].expand_as(dirs)
        else:
            dirs = torch.einsum("nij,nj->ni", rot, d_cam)
            origins = pose[:, :3, 3]
        return origins, torch.nn.functional.normalize(dirs, dim=-1)


def image_pixels(intrinsics: Intrinsics, device: torch.device | str | None = None) -> Tensor:
    """All pixels of the image in row-major order: (H·W, 2) int64 ``(x, y)``."""
    ys, xs = torch.meshgrid(
        torch.arange(intrinsics.height, device=device),
        torch.arange(intrinsics.width, device=device),
        indexing="ij",
    )
    return torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1)


def image_rays(c2w: Tensor | np.ndarray, intrinsics: Intrinsics) -> tuple[Tensor, Tensor]:
    """Rays of every pixel of one view, row-major (index = row · W + column).

    Args:
        c2w: (4, 4) camera-to-world.
    Returns:
        origins (H·W, 3), unit directions (H·W, 3).
    """
    pose = _as_tensor(c2w)
    return pixel_rays(pose, intrinsics, image_pixels(intrinsics, pose.device))


def ray_box_bounds(
    origins: Tensor, dirs: Tensor, scene_box: Tensor | np.ndarray, min_near: float = 0.01
) -> tuple[Tensor, Tensor]:
    """Where rays enter and leave an axis-aligned box (slab test).

    Args:
        origins: (N, 3). dirs: (N, 3) (unit, so the result is a distance).
        scene_box: (2, 3) min and max corners.
        min_near: lower clamp of ``near`` (a camera inside the box starts here, never behind itself).
    Returns:
        near (N,), far (N,), with ``far ≥ near``; rays that miss the box get ``far = near`` (an empty segment,
        which renders as background).
    """
    box = _as_tensor(scene_box, origins.dtype).to(origins.device)
    tiny = torch.finfo(dirs.dtype).tiny ** 0.5
    safe = torch.where(dirs.abs() < tiny, torch.full_like(dirs, tiny), dirs)
    t0 = (box[0] - origins) / safe
    t1 = (box[1] - origins) / safe
    near = torch.minimum(t0, t1).amax(dim=-1).clamp_min(min_near)
    far = torch.maximum(t0, t1).amin(dim=-1)
    return near, torch.maximum(far, near)


def as_poses(poses: Tensor | np.ndarray, device: torch.device | str) -> Tensor:
    """Camera-to-world pose(s) (..., 4, 4) as a float32 tensor on ``device`` (numpy or torch input; a numpy
    view with negative strides, such as ``poses[::-1]``, is copied: torch takes none)."""
    return torch.as_tensor(poses if isinstance(poses, Tensor) else np.ascontiguousarray(poses)).to(
        device, torch.float32
    )

"""One frame of every built-in scene in a single sRGB PNG (needs ``bpy``).

Usage: ``python -m spikenerf.scenes.blender.contact_sheet docs/images/scenes.png [--size 200] [--spp 16]``
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from spikenerf.core.atomic import atomic_path
from spikenerf.core.color import display_uint8, srgb_encode
from spikenerf.scenes.blender.catalog import BUILTIN_SCENES, DEFAULT_CAMERA_ANGLE_X, default_orbit_radius
from spikenerf.scenes.blender.source import BlenderSource, scene_extent
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.trajectory import orbit


def scene_frame(
    name: str, size: int, spp: int, azimuth_deg: float = -50.0, elevation_deg: float = 30.0, seed: int = 0
) -> np.ndarray:
    """One (size, size, 3) float32 linear frame of a built-in scene on its default orbit."""
    box = scene_extent(name, seed)
    radius = default_orbit_radius(box, DEFAULT_CAMERA_ANGLE_X)
    center = box.mean(0)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    eye = center + radius * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    traj = orbit(radius, elevation_deg, duration=1.0, fps=1.0, center=tuple(center))
    src = BlenderSource(
        name, size, size, traj, np.stack([look_at(eye, center)]), spp=spp, seed=seed, progress=False
    )
    return src.test_views()[1][0]


def contact_sheet(frames: list[np.ndarray], columns: int = 3, pad: int = 4) -> np.ndarray:
    """Tile (H, W, 3) frames on a white sheet, ``columns`` per row; returns a (H', W', 3) array."""
    h, w = frames[0].shape[:2]
    rows = math.ceil(len(frames) / columns)
    sheet = np.ones((rows * h + (rows + 1) * pad, columns * w + (columns + 1) * pad, 3), np.float32)
    for i, f in enumerate(frames):
        r, c = divmod(i, columns)
        y, x = pad + r * (h + pad), pad + c * (w + pad)
        sheet[y : y + h, x : x + w] = f
    return sheet


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--size", type=int, default=200)
    parser.add_argument("--spp", type=int, default=16)
    args = parser.parse_args(argv)
    frames = [scene_frame(name, args.size, args.spp) for name in BUILTIN_SCENES]
    png = display_uint8(srgb_encode(contact_sheet(frames)))
    with atomic_path(args.out) as tmp:
        iio.imwrite(tmp, png, extension=".png")
    print(f"wrote {args.out} ({', '.join(BUILTIN_SCENES)})")


if __name__ == "__main__":
    main()

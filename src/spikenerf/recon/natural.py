"""Natural-image pairs for the learned reconstructor: photographs shipped by scikit-image, filmed by a camera
that pans, rolls and zooms over them (a planar scene), then simulated by the spike camera.

The analytic scenes give the network geometry and motion; these give it natural textures and edge
statistics that procedural textures lack. The photographs come with the ``scikit-image`` package (its
``skimage.data`` files that ship in the wheel; nothing is downloaded): :data:`NATURAL_TRAIN` feeds the train
split and :data:`NATURAL_HELDOUT`, never trained on, the val split and
``python -m benchmarks.experiments.bench_learned_recon --content natural``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from spikenerf.camera.layout import to_camera_layout
from spikenerf.core.color import srgb_decode
from spikenerf.core.errors import InputError
from spikenerf.recon.pairs import PairConfig, Sample, draw_settings, simulate_samples
from spikenerf.scenes.analytic import CAMERA_ANGLE_X

INSTALL_HINT = "natural_draws: photographs need scikit-image: pip install 'spikenerf[natural]'"
#: photographs of ``skimage.data`` in the train split (outdoor, portrait, animal, food, texture, space,
#: microscopy, medical, text) ...
NATURAL_TRAIN = (
    "astronaut", "chelsea", "coffee", "grass", "gravel", "brick", "hubble_deep_field",
    "immunohistochemistry", "moon", "rocket", "retina", "coins", "cell", "text",
)  # fmt: skip
#: ... and the ones held out of it (val split, benchmarks): other subjects, never trained on
NATURAL_HELDOUT = ("camera", "stereo_motorcycle", "page", "clock")
MOTIONS = ("still", "pan", "roll-zoom")


def require_skimage() -> Any:
    """The ``skimage.data`` module, or InputError with the one-line install hint when it is missing."""
    try:
        import skimage.data as data
    except ImportError:
        raise InputError(INSTALL_HINT, param="natural_draws") from None
    return data


def load_images(names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The named ``skimage.data`` photographs as linear RGB float32 (H, W, 3) in [0, 1].

    Raises:
        InputError: scikit-image is missing (with its install hint), or a name it does not ship.
    """
    data = require_skimage()
    images = {}
    for name in names:
        if not hasattr(data, name):
            raise InputError(f"natural_draws: scikit-image has no photograph {name!r}", param="natural_draws")
        image = getattr(data, name)()
        if isinstance(image, tuple):  # stereo pairs: the left view
            image = image[0]
        image = np.asarray(image)
        image = image.astype(np.float32) / (1.0 if image.dtype == bool else 255.0)
        if image.ndim == 2:
            image = np.repeat(image[..., None], 3, axis=2)
        images[name] = srgb_decode(np.ascontiguousarray(image[..., :3]))
    return images


def motion_grids(
    rng: np.random.Generator, shape: tuple[int, int], size: int, window: int, max_speed: float, ss: int
) -> tuple[torch.Tensor, dict]:
    """``grid_sample`` grids (K, size·ss, size·ss, 2) of a random planar camera motion over an image of
    ``shape`` (H, W), centred on the middle step, and its description.

    The view covers ``size`` output pixels at a random zoom (source pixels per output pixel, log-uniform); a
    pan moves it at up to ``max_speed`` degrees per step of the analytic camera's field of view, a roll-zoom
    turns it by up to ``max_speed`` degrees and scales it by up to ±0.5 % per step.
    """
    h, w = shape
    motion = str(rng.choice(MOTIONS, p=[0.25, 0.45, 0.3]))
    top = min(2.0, max(0.6, min(h, w) / (1.6 * size)))  # ≤ 2: sub-samples at most one source pixel apart
    scale = float(math.exp(rng.uniform(math.log(0.6), math.log(top))))
    px_per_degree = size / math.degrees(CAMERA_ANGLE_X)
    speed = 0.0 if motion == "still" else float(rng.uniform(min(0.02, max_speed), max_speed))
    heading, roll0 = rng.uniform(0, 2 * math.pi), rng.uniform(0, 2 * math.pi)
    velocity = np.zeros(2)
    spin, zoom = 0.0, 0.0
    if motion == "pan":
        velocity = speed * px_per_degree * scale * np.array([math.cos(heading), math.sin(heading)])
    elif motion == "roll-zoom":
        spin, zoom = math.radians(speed) * rng.choice([-1.0, 1.0]), float(rng.uniform(-0.005, 0.005))
    reach = size * scale * (math.sqrt(0.5) + abs(zoom) * window) + np.abs(velocity) * window / 2
    centre = [rng.uniform(min(r, n / 2), max(n - r, n / 2)) for r, n in zip(reach, (w, h), strict=True)]
    n = size * ss
    offsets = (torch.arange(n, dtype=torch.float64) + 0.5) / ss - size / 2  # output pixels from the centre
    v, u = torch.meshgrid(offsets, offsets, indexing="ij")
    grids = []
    for j in range(window):
        rel = j - window // 2
        angle, s = roll0 + spin * rel, scale * math.exp(zoom * rel)
        c, sn = math.cos(angle) * s, math.sin(angle) * s
        x = centre[0] + velocity[0] * rel + c * u - sn * v
        y = centre[1] + velocity[1] * rel + sn * u + c * v
        grids.append(torch.stack([2 * x / w - 1, 2 * y / h - 1], dim=-1))  # align_corners=False
    info = {"motion": motion, "speed": round(speed, 4), "zoom": round(scale, 3)}
    return torch.stack(grids).float(), info


def render_motion(image: np.ndarray, grids: torch.Tensor, ss: int) -> np.ndarray:
    """Linear RGB frames (K, 3, size, size) of ``image`` (H, W, 3) sampled along ``grids`` (bilinear,
    mirrored at the borders, ``ss × ss`` sub-samples averaged per pixel)."""
    source = torch.from_numpy(np.ascontiguousarray(to_camera_layout(image, frame=True)))
    source = source[None].expand(len(grids), -1, -1, -1)
    frames = F.grid_sample(source, grids, mode="bilinear", padding_mode="reflection", align_corners=False)
    return F.avg_pool2d(frames, ss).numpy() if ss > 1 else frames.numpy()


def natural_pairs(
    images: dict[str, np.ndarray], draws: range, cfg: PairConfig, seed: int
) -> Iterator[Sample]:
    """Samples of the random ``draws``: each picks a photograph of ``images`` (round robin), a colour mode,
    a noise preset, a brightness and a planar motion; deterministic in ``(seed, index)``."""
    names = sorted(images)
    for i in draws:
        rng = np.random.default_rng([seed, i])
        mode, noise, bright = draw_settings(rng, cfg)
        name = names[i % len(names)]
        size = cfg.size * (2 if mode == "bayer" else 1)
        ss = 1 if mode == "bayer" else cfg.supersample
        grids, info = motion_grids(rng, images[name].shape[:2], size, cfg.window, cfg.max_speed, ss)
        frames = render_motion(images[name], grids, ss) * np.float32(bright)
        info.update(scene=f"natural:{name}", brightness=round(bright, 4))
        yield from simulate_samples(frames, mode, noise, cfg, int(rng.integers(2**31)), info)

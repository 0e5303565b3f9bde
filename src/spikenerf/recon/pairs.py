"""Training pairs for the learned reconstructor: a spike window of K steps and the sharp frame at its middle.

A *sample* is one single-channel image: a gray stream, one channel of a per-channel RGB stream, or one
plane of a Bayer mosaic (the RGGB pattern split into its four half-resolution planes). Each pair is drawn at
random: a scene (a random procedural scene of textured spheres and boxes, a named analytic scene, or any
:class:`~spikenerf.scenes.base.FrameSource` such as a Blender scene or an image sequence), a camera motion
(still, orbit, pan; speeds from 0 to several times the paper's 0.36°/step), a colour mode, ideal or realistic
noise, and a brightness scale (log-uniform), then the window is simulated by the spike camera.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from spikenerf.camera.bayer import bayer_mosaic
from spikenerf.camera.layout import to_camera_layout
from spikenerf.camera.model import CameraConfig, SpikeCamera
from spikenerf.camera.modes import COLORS, NOISES
from spikenerf.camera.noise import RealisticNoise
from spikenerf.camera.reconstruct import DEFAULT_WINDOW
from spikenerf.core.color import rgb_to_gray
from spikenerf.scenes import analytic
from spikenerf.scenes.base import FrameSource
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.trajectory import Intrinsics

MOTIONS = ("still", "orbit", "pan")
KINDS = ("solid", "checker", "stripes", "rings")


@dataclass(frozen=True)
class PairConfig:
    """How pairs are drawn.

    Attributes:
        size: sample side P in pixels (Bayer pairs render 2P and give four P × P planes).
        window: K, steps in the spike window (odd).
        modes: colour modes to draw from. noises: noise presets to draw from.
        brightness: (lo, hi) of the log-uniform brightness scale applied to the radiance.
        max_speed: largest angular speed, degrees per step (the paper's orbit is 0.36).
        threshold: φ of the simulated camera. noise_scale: multiplies every realistic-noise parameter.
        supersample: analytic rays per pixel side.
    """

    size: int = 64
    window: int = DEFAULT_WINDOW
    modes: tuple[str, ...] = COLORS
    noises: tuple[str, ...] = NOISES
    brightness: tuple[float, float] = (0.04, 1.0)
    max_speed: float = 1.5
    threshold: float = 1.0
    noise_scale: float = 1.0
    supersample: int = 2


@dataclass
class Sample:
    """One training sample: ``window`` bool (K, P, P) spikes, ``target`` float32 (P, P) sharp rate
    (intensity / φ) at the middle step, and a description (mode, noise, motion, speed, brightness, scene)."""

    window: np.ndarray
    target: np.ndarray
    info: dict


def random_texture(rng: np.random.Generator) -> analytic.Texture:
    """A procedural texture of random kind, colours and frequency."""
    a, b = (tuple(float(v) for v in rng.uniform(0.02, 0.95, 3)) for _ in range(2))
    return analytic.Texture(
        str(rng.choice(KINDS)), a, b, float(math.exp(rng.uniform(math.log(2), math.log(20))))
    )


def random_scene(rng: np.random.Generator) -> tuple[analytic.Primitive, ...]:
    """2–7 textured spheres and boxes inside [-1, 1]³, often on a ground slab, sometimes inside a textured
    room (a large box seen from inside: it replaces the white background and shadows everything inside)."""
    prims: list[analytic.Primitive] = []
    if rng.random() < 0.3:
        prims.append(analytic.Box((-6.0, -6.0, -0.7), (6.0, 6.0, 6.0), random_texture(rng)))
    if rng.random() < 0.6:
        a = rng.uniform(0.7, 1.0)
        prims.append(analytic.Box((-a, -a, -0.7), (a, a, -0.5), random_texture(rng)))
    for _ in range(int(rng.integers(2, 8))):
        c = (*rng.uniform(-0.8, 0.8, 2), rng.uniform(-0.45, 0.6))
        r = float(rng.uniform(0.1, 0.45))
        if rng.random() < 0.55:
            prims.append(analytic.Sphere(tuple(float(v) for v in c), r, random_texture(rng)))
        else:
            half = rng.uniform(0.4, 1.0, 3) * r
            lo, hi = tuple(float(v) for v in np.subtract(c, half)), tuple(float(v) for v in np.add(c, half))
            prims.append(analytic.Box(lo, hi, random_texture(rng)))
    return tuple(prims)


def motion_poses(rng: np.random.Generator, window: int, max_speed: float) -> tuple[np.ndarray, dict]:
    """Camera-to-world poses (K, 4, 4) of a random motion centred on the middle step, and its description."""
    motion = str(rng.choice(MOTIONS, p=[0.25, 0.45, 0.3]))
    top = max_speed if motion == "orbit" else max_speed / 3
    speed = 0.0 if motion == "still" else float(rng.uniform(min(0.02, top), top))  # (max_speed 0: all still)
    radius, elev = rng.uniform(1.7, 4.0), math.radians(rng.uniform(5, 60))
    az0, center = rng.uniform(0, 2 * math.pi), rng.uniform(-0.4, 0.4, 3)
    rel = np.arange(window) - window // 2
    poses = []
    for j in rel:
        az = az0 + (math.radians(speed * j) if motion == "orbit" else 0.0)
        eye = center + radius * np.array(
            [math.cos(elev) * math.cos(az), math.cos(elev) * math.sin(az), math.sin(elev)]
        )
        pose = look_at(eye, center)
        if motion == "pan":  # rotate the view about the world up axis through the eye
            t = math.radians(speed * j)
            rz = np.array([[math.cos(t), -math.sin(t), 0], [math.sin(t), math.cos(t), 0], [0, 0, 1.0]])
            pose[:3, :3] = rz @ pose[:3, :3]
        poses.append(pose)
    return np.stack(poses), {"motion": motion, "speed": round(speed, 4)}


class PrimitiveRenderer:
    """Renders a tuple of analytic primitives at ``size × size`` (linear RGB (H, W, 3)) from any pose."""

    def __init__(self, primitives: tuple[analytic.Primitive, ...], size: int, supersample: int) -> None:
        self.primitives = primitives
        self.dirs = analytic.camera_directions(
            Intrinsics.from_fov(size, size, analytic.CAMERA_ANGLE_X), supersample
        )
        self.supersample = supersample

    def __call__(self, c2w: np.ndarray) -> np.ndarray:
        dirs = self.dirs @ c2w[:3, :3].T
        return analytic.render_primitives(self.primitives, c2w[:3, 3], dirs, self.supersample)


def render_window(render, poses: np.ndarray) -> np.ndarray:
    """Linear RGB frames (K, 3, H, W) along ``poses``; a still camera renders once."""
    if np.allclose(poses, poses[:1]):
        frame = to_camera_layout(render(poses[0]), frame=True)
        return np.broadcast_to(frame, (len(poses), *frame.shape))
    return np.stack([to_camera_layout(render(p), frame=True) for p in poses])


def simulate_samples(
    frames: np.ndarray, mode: str, noise: str, cfg: PairConfig, seed: int, info: dict
) -> list[Sample]:
    """Spike windows and sharp targets of linear RGB ``frames`` (K, 3, H, W) (brightness already applied).

    Returns one sample (gray), three (rgb channels) or four (Bayer planes R, G, G, B).
    """
    k, _, h, w = frames.shape
    params = None if cfg.noise_scale == 1.0 else _scaled_noise(cfg.noise_scale)
    camera = SpikeCamera(h, w, CameraConfig(cfg.threshold, mode, noise, seed), noise_params=params)
    spikes = np.stack([camera.step(f).copy() for f in frames])  # (K, H, W) or (K, 3, H, W)
    sharp = frames[k // 2] / np.float32(cfg.threshold)
    meta = {**info, "mode": mode, "noise": noise}
    if mode == "gray":
        return [Sample(spikes, rgb_to_gray(sharp, channel_axis=0).astype(np.float32), meta)]
    if mode == "rgb":
        return [Sample(spikes[:, c], sharp[c].astype(np.float32), {**meta, "plane": c}) for c in range(3)]
    mosaic = bayer_mosaic(sharp)
    return [
        Sample(spikes[:, i::2, j::2], mosaic[i::2, j::2].astype(np.float32), {**meta, "plane": 2 * i + j})
        for i in (0, 1)
        for j in (0, 1)
    ]


def _scaled_noise(factor: float) -> RealisticNoise:
    base = RealisticNoise()
    return RealisticNoise(
        dark_mean=base.dark_mean * factor,
        dark_std=base.dark_std * factor,
        threshold_std=base.threshold_std * factor,
        capacitance_std=base.capacitance_std * factor,
        prnu_std=base.prnu_std * factor,
        jitter_std=base.jitter_std * factor,
        photons_per_white=base.photons_per_white / factor**2,
        readout_delay=base.readout_delay,
    )


def draw_settings(rng: np.random.Generator, cfg: PairConfig) -> tuple[str, str, float]:
    """A random colour mode, noise preset and log-uniform brightness of ``cfg``'s ranges."""
    mode, noise = str(rng.choice(cfg.modes)), str(rng.choice(cfg.noises))
    lo, hi = cfg.brightness
    return mode, noise, float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def analytic_pairs(scenes: list[str] | None, draws: range, cfg: PairConfig, seed: int) -> Iterator[Sample]:
    """Samples of the random ``draws`` (indices): named analytic ``scenes`` (round robin) or, when None, a new
    random procedural scene per draw. Each draw is deterministic in ``(seed, index)``."""
    for i in draws:
        rng = np.random.default_rng([seed, i])
        mode, noise, bright = draw_settings(rng, cfg)
        if scenes is None:
            prims, name = random_scene(rng), f"random-{seed}-{i}"
        else:
            name = scenes[i % len(scenes)]
            prims = analytic.SCENES[name][1]
        size = cfg.size * (2 if mode == "bayer" else 1)
        ss = 1 if mode == "bayer" else cfg.supersample
        poses, info = motion_poses(rng, cfg.window, cfg.max_speed)
        frames = render_window(PrimitiveRenderer(prims, size, ss), poses) * np.float32(bright)
        info.update(scene=name, brightness=round(bright, 4))
        yield from simulate_samples(frames, mode, noise, cfg, int(rng.integers(2**31)), info)


def source_pairs(source: FrameSource, draws: range, cfg: PairConfig, seed: int) -> Iterator[Sample]:
    """Samples from windows of a FrameSource's own trajectory (a Blender scene, an image sequence): each
    draw takes a random window on its path and a random P × P crop (2P for Bayer)."""
    steps = np.asarray(source.trajectory.steps)
    h, w = source.intrinsics.height, source.intrinsics.width
    for i in draws:
        rng = np.random.default_rng([seed, i])
        mode, noise, bright = draw_settings(rng, cfg)
        size = cfg.size * (2 if mode == "bayer" else 1)
        if len(steps) < cfg.window or min(h, w) < size:
            return
        start = int(rng.integers(0, len(steps) - cfg.window + 1))
        y, x = int(rng.integers(0, h - size + 1)), int(rng.integers(0, w - size + 1))
        frames = np.stack(
            [
                to_camera_layout(f[y : y + size, x : x + size], frame=True)
                for f in source.frames(steps[start : start + cfg.window])
            ]
        )
        info = {"scene": source.name, "motion": "path", "speed": -1.0, "brightness": round(bright, 4)}
        yield from simulate_samples(
            frames * np.float32(bright), mode, noise, cfg, int(rng.integers(2**31)), info
        )

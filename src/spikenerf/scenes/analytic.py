"""Analytic scenes: a few textured spheres and boxes ray-cast in vectorised numpy (no Blender needed).

The scenes are deterministic, sit inside the box ``[-1, 1]^3``, use Lambertian shading under one fixed
directional light plus an ambient term (a white surface facing the light has radiance 1.0) and a white
background (radiance 1.0). They let tests, CI and users without ``bpy`` run the whole pipeline.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np

from spikenerf.core.errors import InputError, is_integer
from spikenerf.core.limits import check_memory
from spikenerf.scenes.distortion import Distortion
from spikenerf.scenes.trajectory import Intrinsics, Trajectory
from spikenerf.scenes.transforms import rigid_poses

#: horizontal field of view of the NeRF synthetic scenes (radians), used by the analytic scenes too
CAMERA_ANGLE_X = 0.6911112070083618
#: direction *towards* the light (world, +Z up) and the ambient share of the shading
LIGHT_DIR = np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84])
AMBIENT = 0.3
BACKGROUND = 1.0


@dataclass(frozen=True)
class Texture:
    """A procedural albedo: ``kind`` in ``solid | checker | stripes | rings``; linear RGB colours."""

    kind: str
    a: tuple[float, float, float]
    b: tuple[float, float, float] = (0.9, 0.9, 0.9)
    frequency: float = 4.0


@dataclass(frozen=True)
class Sphere:
    center: tuple[float, float, float]
    radius: float
    texture: Texture


@dataclass(frozen=True)
class Box:
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    texture: Texture


Primitive = Sphere | Box

ORANGE, RED, GREEN = (0.9, 0.35, 0.05), (0.8, 0.08, 0.06), (0.1, 0.6, 0.15)
BLUE, YELLOW, DARK = (0.08, 0.2, 0.8), (0.85, 0.75, 0.1), (0.08, 0.08, 0.08)

#: name -> (description, primitives)
SCENES: dict[str, tuple[str, tuple[Primitive, ...]]] = {
    "analytic-orbs": (
        "analytic (no Blender): striped and checkered spheres on a checker slab, colourful",
        (
            Box((-0.9, -0.9, -0.65), (0.9, 0.9, -0.5), Texture("checker", DARK, (0.85, 0.85, 0.85), 2.5)),
            Sphere((0.0, 0.0, 0.05), 0.5, Texture("stripes", ORANGE, (0.9, 0.9, 0.9), 12.0)),
            Sphere((0.6, 0.45, -0.25), 0.25, Texture("checker", RED, (0.9, 0.9, 0.9), 8.0)),
            Sphere((-0.55, 0.5, -0.3), 0.2, Texture("rings", BLUE, YELLOW, 10.0)),
            Sphere((0.0, -0.62, -0.28), 0.22, Texture("solid", GREEN)),
            Box((-0.75, -0.6, -0.5), (-0.4, -0.25, 0.1), Texture("checker", BLUE, (0.9, 0.9, 0.9), 8.0)),
            Sphere((0.0, 0.0, 0.75), 0.18, Texture("checker", DARK, YELLOW, 12.0)),
        ),
    ),
    "analytic-blocks": (
        "analytic (no Blender): a stack of striped and checkered boxes and a ringed sphere, high contrast",
        (
            Box((-0.8, -0.8, -0.7), (0.8, 0.8, -0.4), Texture("checker", DARK, (0.9, 0.9, 0.9), 3.0)),
            Box((-0.45, -0.45, -0.4), (0.45, 0.45, 0.1), Texture("stripes", RED, (0.9, 0.9, 0.9), 10.0)),
            Box((-0.25, -0.25, 0.1), (0.25, 0.25, 0.7), Texture("checker", BLUE, YELLOW, 8.0)),
            Sphere((0.55, -0.55, -0.2), 0.2, Texture("rings", GREEN, (0.9, 0.9, 0.9), 8.0)),
        ),
    ),
}


def camera_directions(intrinsics: Intrinsics, supersample: int = 1) -> np.ndarray:
    """Camera-space unit directions (H·s, W·s, 3) through ``s × s`` stratified points per pixel.

    OpenGL camera axes (+X right, +Y up, looking down −Z); with ``s = 1`` rays go through pixel centres.
    A lens (``intrinsics.distortion``) bends each ray as :func:`spikenerf.data.rays.camera_directions` does.
    """
    s = supersample
    uu, vv = np.meshgrid(
        (np.arange(intrinsics.width * s) + 0.5) / s, (np.arange(intrinsics.height * s) + 0.5) / s
    )
    x, y = (uu - intrinsics.cx) / intrinsics.fl_x, (vv - intrinsics.cy) / intrinsics.fl_y
    if intrinsics.distortion is not None:
        x, y = intrinsics.distortion.undistort(x, y)
    dirs = np.stack([x, -y, -np.ones_like(uu)], -1)
    return dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)


def bounding_sphere(prim: Primitive) -> tuple[np.ndarray, float]:
    """Centre (3,) and radius of a sphere enclosing ``prim``."""
    if isinstance(prim, Sphere):
        return np.asarray(prim.center, dtype=np.float64), prim.radius
    lo, hi = np.asarray(prim.lo, dtype=np.float64), np.asarray(prim.hi, dtype=np.float64)
    return (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)


def ray_hit(prim: Primitive, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Nearest hit distance beyond the origin along each ray, ``inf`` on a miss.

    Args:
        o: (3,) or (3, N) origins. d: (3, N) or (3,) unit directions (component-major for speed).
    Returns:
        (N,) distances.
    """
    eps = 1e-4
    if isinstance(prim, Sphere):
        ox, oy, oz = (o[i] - prim.center[i] for i in range(3))
        b = d[0] * ox + d[1] * oy + d[2] * oz
        disc = b * b - (ox * ox + oy * oy + oz * oz - prim.radius**2)
        root = np.sqrt(np.maximum(disc, 0.0))
        t = np.where(-b - root > eps, -b - root, -b + root)
        return np.where((disc >= 0) & (t > eps), t, np.inf)
    near, far = -np.inf, np.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(3):
            t0, t1 = (prim.lo[i] - o[i]) / d[i], (prim.hi[i] - o[i]) / d[i]
            near = np.fmax(near, np.fmin(t0, t1))  # fmin/fmax skip the NaN of 0/0 (ray in a slab plane)
            far = np.fmin(far, np.fmax(t0, t1))
    t = np.where(near > eps, near, far)
    return np.where((far >= near) & (t > eps), t, np.inf)


def _normal(prim: Primitive, p: np.ndarray) -> np.ndarray:
    """Outward unit normals (N, 3) at surface points ``p`` (N, 3)."""
    if isinstance(prim, Sphere):
        return (p - np.asarray(prim.center)) / prim.radius
    lo, hi = np.asarray(prim.lo), np.asarray(prim.hi)
    q = (p - (lo + hi) / 2) / ((hi - lo) / 2)
    axis = np.abs(q).argmax(-1)
    rows = np.arange(len(p))
    n = np.zeros_like(p)
    n[rows, axis] = np.sign(q[rows, axis])
    return n


def _albedo(prim: Primitive, p: np.ndarray) -> np.ndarray:
    """Linear RGB albedo (N, 3) of the procedural texture at surface points ``p`` (N, 3)."""
    tex = prim.texture
    a, b = np.asarray(tex.a), np.asarray(tex.b)
    if tex.kind == "solid":
        return np.broadcast_to(a, p.shape).copy()
    center = bounding_sphere(prim)[0]
    if tex.kind == "checker":
        origin = center if isinstance(prim, Sphere) else np.zeros(3)
        pick = np.floor((p - origin) * tex.frequency + 1e-4).astype(np.int64).sum(-1) % 2 == 0
    else:  # stripes: along the azimuth about +Z; rings: along the height
        q = p - center
        coord = np.arctan2(q[:, 1], q[:, 0]) / math.pi if tex.kind == "stripes" else q[:, 2] * 2
        pick = np.floor(coord * tex.frequency / 2).astype(np.int64) % 2 == 0
    return np.where(pick[:, None], a, b)


def render_primitives(
    primitives: Sequence[Primitive],
    origin: np.ndarray,
    dirs: np.ndarray,
    supersample: int = 1,
) -> np.ndarray:
    """Ray-cast ``primitives`` along world rays; linear radiance (H, W, 3) float32 on a white background.

    Shading is ``albedo · (AMBIENT + (1 − AMBIENT) · max(0, n·l))`` with hard shadows towards the light.

    Args:
        origin: (3,) camera centre. dirs: (H·s, W·s, 3) unit world directions (see :func:`camera_directions`).
        supersample: ``s``; each ``s × s`` block of rays is averaged into one pixel.
    """
    d = np.ascontiguousarray(dirs.reshape(-1, 3).T, dtype=np.float32)
    return _render(primitives, origin, d, dirs.shape[:2], supersample)


def _render(
    primitives: Sequence[Primitive], origin: np.ndarray, d: np.ndarray, shape: tuple[int, int], s: int
) -> np.ndarray:
    """:func:`render_primitives` on component-major directions ``d`` (3, N), N = H·s · W·s, row-major."""
    origin = np.asarray(origin, dtype=d.dtype)
    t = np.full(d.shape[1], np.inf, dtype=d.dtype)
    which = np.full(d.shape[1], -1)
    for k, prim in enumerate(primitives):  # exact tests only on rays that meet the bounding sphere
        c, r = bounding_sphere(prim)
        oc = (origin - c).astype(d.dtype)
        b = oc @ d
        cand = np.nonzero(b * b >= oc @ oc - r * r)[0]
        tk = ray_hit(prim, origin, d[:, cand])
        closer = tk < t[cand]
        t[cand[closer]], which[cand[closer]] = tk[closer], k
    color = np.full((d.shape[1], 3), BACKGROUND, dtype=np.float32)
    for k, prim in enumerate(primitives):
        sel = np.nonzero(which == k)[0]
        if len(sel) == 0:
            continue
        p = origin + t[sel, None] * d[:, sel].T
        n = _normal(prim, p)
        lambert = np.maximum(n @ LIGHT_DIR, 0.0)
        lit = np.nonzero(lambert > 0)[0]
        if len(lit):  # shadow rays from just above the surface towards the light
            q = (p[lit] + 1e-3 * n[lit]).T
            blocked = np.zeros(len(lit), dtype=bool)
            for other in primitives:
                blocked |= np.isfinite(ray_hit(other, q, LIGHT_DIR))
            lambert[lit[blocked]] = 0.0
        color[sel] = _albedo(prim, p) * (AMBIENT + (1 - AMBIENT) * lambert)[:, None]
    img = color.reshape(*shape, 3)
    if s > 1:  # average each s × s block (strided sums are much faster than a reshape-mean)
        img = sum(img[i::s, j::s] for i in range(s) for j in range(s)) / np.float32(s * s)
    return np.ascontiguousarray(img, dtype=np.float32)


#: memory a supersampled ray needs while a frame is rendered, with its intermediates (bytes; upper-ish)
RAY_BYTES = 256


def check_size(width: int, height: int, supersample: int, params: str = "width/height/supersample") -> None:
    """InputError naming ``width``, ``height`` or ``supersample`` unless each is a positive integer, and
    naming ``params`` (``core.limits.check_memory``) when a frame's ``width·height·supersample²`` rays
    (:data:`RAY_BYTES` each) need more memory than this machine has."""
    for name, value in (("width", width), ("height", height), ("supersample", supersample)):
        if not is_integer(value) or value < 1:
            raise InputError(f"{name} must be an integer ≥ 1, got {value!r}", param=name)
    check_memory(float(width) * float(height) * float(supersample) ** 2 * RAY_BYTES, params)


class AnalyticSource:
    """A :class:`~spikenerf.scenes.base.FrameSource` for a named analytic scene.

    Args:
        name: a key of :data:`SCENES` (e.g. ``"analytic-orbs"``).
        width, height: output size in pixels; the field of view is the NeRF synthetic one.
        trajectory: the per-step training path.
        test_poses: (N, 4, 4) held-out camera-to-world poses (N may be 0).
        supersample: ``s`` renders ``s × s`` stratified rays per pixel and averages them (antialiasing).
        distortion: the camera's lens (:class:`~spikenerf.scenes.distortion.Distortion`); None: a pinhole.
    """

    #: frames depend on the step alone and the source pickles: ``simulate --jobs`` renders in processes
    parallel_render = True

    def __init__(
        self,
        name: str,
        width: int,
        height: int,
        trajectory: Trajectory,
        test_poses: np.ndarray | None = None,
        supersample: int = 2,
        distortion: Distortion | None = None,
    ) -> None:
        if name not in SCENES:
            raise InputError(f"unknown analytic scene {name!r}; expected one of {', '.join(SCENES)}")
        check_size(width, height, supersample)
        if not isinstance(trajectory, Trajectory):
            raise InputError(f"trajectory must be a Trajectory, found {trajectory!r:.60}", param="trajectory")
        rigid_poses(trajectory.poses, "trajectory")  # (once: :meth:`frames` renders them unchecked)
        self.name = name
        self.description, self.primitives = SCENES[name]
        self.intrinsics = replace(Intrinsics.from_fov(width, height, CAMERA_ANGLE_X), distortion=distortion)
        self.trajectory = trajectory
        self.test_poses = rigid_poses(np.zeros((0, 4, 4)) if test_poses is None else test_poses, "test_poses")
        self.scene_box = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
        self.supersample = supersample
        dirs = camera_directions(self.intrinsics, supersample)
        self._shape = dirs.shape[:2]
        self._dirs = np.ascontiguousarray(dirs.reshape(-1, 3).T, dtype=np.float32)  # (3, N) camera space

    def render(self, c2w: np.ndarray) -> np.ndarray:
        """Linear radiance (H, W, 3) float32 seen from camera-to-world ``c2w`` (4, 4), or its top (3, 4):
        finite, a rotation, last row 0 0 0 1 (else InputError naming ``c2w``)."""
        if np.shape(c2w) == (3, 4):  # the top rows only, as a NeRF pose often is
            c2w = np.vstack([np.asarray(c2w, dtype=np.float64), [0.0, 0.0, 0.0, 1.0]])
        return self._render_pose(rigid_poses(c2w, "c2w", one=True))

    def _render_pose(self, c2w: np.ndarray) -> np.ndarray:
        """:meth:`render` of a checked (4, 4) pose."""
        c2w = np.asarray(c2w, dtype=np.float64)
        dirs = c2w[:3, :3].astype(np.float32) @ self._dirs
        return _render(self.primitives, c2w[:3, 3], dirs, self._shape, self.supersample)

    def frames(self, steps: Sequence[int]) -> Iterator[np.ndarray]:
        """Yield the frame (H, W, 3) float32 of each trajectory step index in ``steps``, in order."""
        index = {int(s): i for i, s in enumerate(self.trajectory.steps)}
        for step in steps:
            if int(step) not in index:
                raise InputError(f"step {step} is not on the trajectory of {self.name}")
            yield self._render_pose(self.trajectory.poses[index[int(step)]])

    def test_views(self) -> tuple[np.ndarray, np.ndarray]:
        """Held-out poses (N, 4, 4) and linear frames (N, H, W, 3) float32."""
        h, w = self.intrinsics.height, self.intrinsics.width
        frames = [self._render_pose(p) for p in self.test_poses]
        return self.test_poses.copy(), np.stack(frames) if frames else np.zeros((0, h, w, 3), np.float32)

"""``BlenderSource``: a :class:`~spikenerf.scenes.base.FrameSource` rendered by Cycles (lazy ``bpy``).

Typical use (what ``spikenerf simulate --scene NAME`` does)::

    box = scene_extent("bricks")                                  # (2, 3), before the trajectory exists
    radius = default_orbit_radius(box, DEFAULT_CAMERA_ANGLE_X)
    center = tuple(box.mean(0))
    traj = orbit(radius, elevation_deg=30.0, center=center)       # 1000 steps in 0.025 s
    src = BlenderSource("bricks", 200, 200, traj, novel_views(radius, 8, center=center))
    for frame in src.frames(range(1000)): ...                     # (H, W, 3) float32 linear

Blender holds one scene per process; each source reloads its scene when another source used Blender in
between (a cache keyed by scene and seed avoids rebuilding otherwise).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.core.progress import bar as progress_bar
from spikenerf.scenes.blender._bpy import import_bpy, quiet
from spikenerf.scenes.blender.catalog import BUILTIN_SCENES, DEFAULT_CAMERA_ANGLE_X, DEFAULT_SPP
from spikenerf.scenes.trajectory import Intrinsics, Trajectory

_STATE: dict[str, Any] = {}  # what Blender holds now: key, box, owner
_MARKER = "spikenerf_scene_key"


def resolve_scene(scene: str | Path) -> tuple[str, str, Path | None]:
    """Classify ``scene``: ``("builtin", name, None)`` or ``("blend", file stem, path)``; no ``bpy`` needed.

    Raises:
        InputError: neither a built-in name nor an existing ``.blend`` path.
    """
    if isinstance(scene, str) and scene in BUILTIN_SCENES:
        return "builtin", scene, None
    path = Path(scene)
    if path.suffix.lower() == ".blend" or path.exists():
        if not path.is_file():
            raise InputError("no such .blend file", path=path)
        return "blend", path.stem, path.resolve()
    raise InputError(
        f"unknown scene {str(scene)!r}: expected a built-in ({', '.join(BUILTIN_SCENES)}) "
        "or a path to a .blend file"
    )


def _load(scene: str | Path, seed: int) -> np.ndarray:
    """Make ``scene`` Blender's current scene (cached); return its geometry box (2, 3)."""
    bpy = import_bpy()
    kind, name, path = resolve_scene(scene)
    key = repr((kind, name, seed) if path is None else (kind, str(path), path.stat().st_mtime_ns))
    # the marker on the scene catches anyone else having replaced Blender's data since we loaded
    if _STATE.get("key") != key or bpy.context.scene.get(_MARKER) != key:
        _STATE.clear()
        from spikenerf.scenes.blender.render import geometry_box

        if path is None:
            from spikenerf.scenes.blender.builtin import build

            with quiet(stderr=True):
                bpy.ops.wm.read_factory_settings(use_empty=True)
            build(name, seed)
        else:
            from spikenerf.scenes.blender.blendfile import load_blend

            load_blend(path)
        bpy.context.scene[_MARKER] = key
        _STATE.update(key=key, box=geometry_box(bpy.context.scene))
    return _STATE["box"].copy()


def scene_extent(scene: str | Path, seed: int = 0) -> np.ndarray:
    """(2, 3) float64 world bounds [min, max] of the scene's rendered geometry (builds/loads it in Blender).

    Use it with :func:`~spikenerf.scenes.blender.catalog.default_orbit_radius` to place the orbit around
    ``box.mean(0)`` before constructing the trajectory.
    """
    return _load(scene, seed)


class BlenderSource:
    """Linear radiance frames of a built-in scene or a user ``.blend``, rendered by Cycles.

    Args:
        scene: a name from ``BUILTIN_SCENES`` or a path to a ``.blend`` file.
        width, height: frame size in pixels.
        trajectory: training path; ``frames(steps)`` takes values of ``trajectory.steps``.
        test_poses: (N, 4, 4) camera-to-world held-out poses (N may be 0).
        spp: Cycles samples per pixel. seed: scene layout and sampling seed.
        camera_angle_x: horizontal field of view, radians. denoise: FAST | BALANCED | HIGH | NONE.
        device: auto | cpu | gpu. progress: show a tqdm bar while rendering.
    Raises:
        InputError: Blender is not installed, the scene is unknown or unreadable, or a pose is malformed.
    """

    def __init__(
        self,
        scene: str | Path,
        width: int,
        height: int,
        trajectory: Trajectory,
        test_poses: np.ndarray | None = None,
        spp: int = DEFAULT_SPP,
        seed: int = 0,
        *,
        camera_angle_x: float = DEFAULT_CAMERA_ANGLE_X,
        denoise: str = "FAST",
        device: str = "auto",
        progress: bool = True,
    ) -> None:
        import_bpy()
        from spikenerf.scenes.blender.render import RenderSettings

        self.settings = RenderSettings(
            width=width,
            height=height,
            camera_angle_x=camera_angle_x,
            spp=spp,
            seed=seed,
            denoise=denoise,
            device=device,
        )
        _, self.name, _ = resolve_scene(scene)
        self._scene, self._seed = scene, seed
        self.intrinsics = Intrinsics.from_fov(width, height, camera_angle_x)
        self.trajectory = trajectory
        poses = np.zeros((0, 4, 4)) if test_poses is None else np.asarray(test_poses, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise InputError(f"test_poses must have shape (N, 4, 4), got {poses.shape}")
        if trajectory.poses.ndim != 3 or trajectory.poses.shape[1:] != (4, 4):
            raise InputError(f"trajectory poses must have shape (N, 4, 4), got {trajectory.poses.shape}")
        self.test_poses = poses
        self.progress = progress
        self.scene_box = _load(scene, seed)
        self._index = {int(s): i for i, s in enumerate(trajectory.steps)}
        self._token = object()
        self._renderer: Any = None

    @property
    def device(self) -> str:
        """The Cycles device in use (``CPU`` or a GPU backend)."""
        return self._activate().device

    def _activate(self) -> Any:
        """Make Blender hold this source's scene and render settings; return the frame renderer."""
        _load(self._scene, self._seed)
        if _STATE.get("owner") is not self._token or self._renderer is None:
            from spikenerf.scenes.blender.render import FrameRenderer

            if self._renderer is not None:
                self._renderer.close()
            self._renderer = FrameRenderer(self.settings)
            _STATE["owner"] = self._token
        return self._renderer

    def render_pose(self, c2w: np.ndarray) -> np.ndarray:
        """One (H, W, 3) float32 linear frame from a camera-to-world pose (4, 4)."""
        return self._activate().render(c2w)

    def frames(self, steps: Sequence[int]) -> Iterator[np.ndarray]:
        """Yield the (H, W, 3) float32 linear frame of each step in ``steps`` (any subset, any order).

        Values: 1.0 = white diffuse under the default light; the background is white (1.0).
        """
        steps = [int(s) for s in steps]
        missing = [s for s in steps if s not in self._index]
        if missing:
            raise InputError(
                f"steps {missing[:5]} are not on the trajectory (steps "
                f"{int(self.trajectory.steps.min())}..{int(self.trajectory.steps.max())})"
            )
        with progress_bar(
            total=len(steps), desc=f"blender {self.name}", unit="frame", show=self.progress, leave=False
        ) as bar:
            for s in steps:
                frame = self.render_pose(self.trajectory.poses[self._index[s]])
                bar.update(1)
                yield frame

    def test_views(self) -> tuple[np.ndarray, np.ndarray]:
        """Held-out views: poses (N, 4, 4) and linear frames (N, H, W, 3) float32."""
        h, w = self.settings.height, self.settings.width
        images = [self.render_pose(p) for p in self.test_poses]
        return self.test_poses.copy(), (np.stack(images) if images else np.zeros((0, h, w, 3), np.float32))

"""Scene registry: named scenes (analytic ones always, Blender ones when ``bpy`` is installed) → FrameSource.

The Blender backend (``spikenerf.scenes.blender``) is imported lazily, only when a Blender scene is listed or
asked for, so everything else works without ``bpy``.
"""

from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError, is_integer
from spikenerf.scenes import analytic
from spikenerf.scenes.base import FrameSource
from spikenerf.scenes.trajectory import Trajectory, check_trajectory
from spikenerf.scenes.transforms import rigid_poses

BLENDER_MISSING = "Blender is not installed: pip install 'spikenerf[blender]'"
#: default orbit of the built-in scenes (content inside [-1, 1]^3): radius (scene units), elevation (degrees)
DEFAULT_RADIUS = 4.0
DEFAULT_ELEVATION = 30.0
#: the analytic scenes' default samples per pixel (2 × 2 supersampling)
ANALYTIC_SPP = 4


@dataclass(frozen=True)
class SceneInfo:
    """A named scene: ``needs_blender`` is True for the procedural Blender scenes."""

    name: str
    description: str
    needs_blender: bool


def blender_available() -> bool:
    """Whether ``bpy`` can be imported (without importing it)."""
    return importlib.util.find_spec("bpy") is not None


def _blender_scenes() -> dict[str, str]:
    """The Blender backend's built-in scene names and descriptions ({} if the backend is absent)."""
    try:
        module = importlib.import_module("spikenerf.scenes.blender")
    except ImportError:
        return {}
    return dict(getattr(module, "BUILTIN_SCENES", {}))


def list_scenes() -> list[SceneInfo]:
    """Every named scene: the analytic ones, then the Blender ones."""
    scenes = [SceneInfo(name, desc, False) for name, (desc, _) in analytic.SCENES.items()]
    scenes += [SceneInfo(name, desc, True) for name, desc in _blender_scenes().items()]
    return scenes


def format_scene_list() -> str:
    """One line per scene: name, description and "(needs Blender)" where so (for ``--list-scenes``)."""
    scenes = list_scenes()
    width = max(len(s.name) for s in scenes)
    have_bpy = blender_available()
    lines = []
    for s in scenes:
        note = "  (needs Blender" + (")" if have_bpy else ", not installed)") if s.needs_blender else ""
        lines.append(f"{s.name:<{width}}  {s.description}{note}")
    return "\n".join(lines)


def supersample_for(spp: int) -> int:
    """Analytic supersampling factor ``s`` (``s × s`` rays per pixel) closest to ``spp`` samples per pixel."""
    if not is_integer(spp) or spp < 1:
        raise InputError(f"spp must be an integer ≥ 1, got {spp!r}", param="spp")
    return max(1, round(int(spp) ** 0.5))


def _is_blend(scene: str | Path) -> bool:
    return Path(str(scene)).suffix.lower() == ".blend"


def _require_blender(scene: str | Path) -> None:
    """InputError unless ``scene`` is a Blender scene (built-in or existing .blend) and ``bpy`` is present."""
    name = str(scene)
    if _is_blend(name) and not Path(name).is_file():
        raise InputError("Blender scene file not found (expected an existing .blend file)", path=name)
    if not _is_blend(name) and name not in _blender_scenes():
        known = ", ".join(s.name for s in list_scenes())
        raise InputError(
            f"scene: unknown scene {name!r}; expected one of: {known} (see list_scenes)",
            param=("scene", "list_scenes"),
        )
    if not blender_available():
        raise InputError(BLENDER_MISSING)


def default_orbit(scene: str | Path, seed: int = 0) -> tuple[float, tuple[float, float, float]]:
    """Default orbit radius (scene units) and centre of a scene.

    Analytic scenes: radius :data:`DEFAULT_RADIUS` around the origin. Blender scenes: the radius at which
    the geometry's bounding sphere fits the field of view, around the geometry's centre (loads the scene).
    """
    if str(scene) in analytic.SCENES:
        return DEFAULT_RADIUS, (0.0, 0.0, 0.0)
    _require_blender(scene)
    from spikenerf.scenes.blender import default_orbit_radius, scene_extent

    box = scene_extent(Path(str(scene)) if _is_blend(scene) else str(scene), seed)
    center = box.mean(0)
    return float(default_orbit_radius(box)), (float(center[0]), float(center[1]), float(center[2]))


def make_scene_source(
    scene: str | Path,
    width: int,
    height: int,
    trajectory: Trajectory,
    test_poses: np.ndarray | None,
    spp: int | None = None,
    seed: int = 0,
) -> FrameSource:
    """The FrameSource of a named scene (analytic or Blender built-in) or of a ``.blend`` file.

    Args:
        scene: a name from :func:`list_scenes` or a path to a ``.blend`` file.
        width, height: output size in pixels. trajectory: the training path. test_poses: (N, 4, 4) held-out
            (None: none).
        spp: samples per pixel (default: 4 for analytic scenes, the Blender backend's default otherwise).
        seed: render seed (Blender's sampler).
    Raises:
        InputError: unknown scene, missing ``.blend`` file, Blender needed but not installed, a size beyond
            the memory at hand (analytic scenes), or ``trajectory`` poses or ``test_poses`` that are not
            rigid camera-to-world (N, 4, 4) (finite, a rotation, last row 0 0 0 1, as the dataset loader
            checks them; here, before anything is rendered).
    """
    check_trajectory(trajectory)
    name = str(scene)
    if name in analytic.SCENES:  # (its source checks the poses, as below)
        ss = supersample_for(ANALYTIC_SPP if spp is None else spp)
        analytic.check_size(width, height, ss, "width/height/spp")
        return analytic.AnalyticSource(name, width, height, trajectory, test_poses, supersample=ss)
    rigid_poses(trajectory.poses, "trajectory")  # as the dataset loader will check them (transforms.json)
    test_poses = rigid_poses(np.zeros((0, 4, 4)) if test_poses is None else test_poses, "test_poses")
    _require_blender(name)
    try:
        from spikenerf.scenes.blender import BlenderSource
    except ImportError as err:
        raise InputError(f"{BLENDER_MISSING} ({err})") from err
    kwargs = {} if spp is None else {"spp": spp}
    scene_arg = Path(name) if _is_blend(name) else name
    return BlenderSource(
        scene_arg, width, height, trajectory, test_poses, seed=seed, progress=False, **kwargs
    )

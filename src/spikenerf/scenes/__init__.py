"""Scenes: camera trajectories, the optional Blender backend, image-sequence import."""

from spikenerf.core.exports import lazy_exports

#: public name -> defining module (imported on first use)
_EXPORTS = {
    "Intrinsics": "spikenerf.scenes.trajectory",
    "Trajectory": "spikenerf.scenes.trajectory",
    "orbit": "spikenerf.scenes.trajectory",
    "novel_views": "spikenerf.scenes.trajectory",
    "list_scenes": "spikenerf.scenes.registry",
    "make_scene_source": "spikenerf.scenes.registry",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

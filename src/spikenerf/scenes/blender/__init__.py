"""The Blender backend (optional extra ``spikenerf[blender]``): Cycles renders of built-in procedural scenes
or a user's ``.blend`` file. Importing this package never imports ``bpy``; constructing a
:class:`BlenderSource` without it raises :class:`~spikenerf.core.errors.InputError`.
"""

from spikenerf.scenes.blender.catalog import (
    BUILTIN_SCENES,
    DEFAULT_CAMERA_ANGLE_X,
    DEFAULT_SIZE,
    DEFAULT_SPP,
    PAPER_SIZE,
    SUN_DIRECTION,
    default_orbit_radius,
)
from spikenerf.scenes.blender.source import BlenderSource, resolve_scene, scene_extent

__all__ = [
    "BUILTIN_SCENES",
    "DEFAULT_CAMERA_ANGLE_X",
    "DEFAULT_SIZE",
    "DEFAULT_SPP",
    "PAPER_SIZE",
    "SUN_DIRECTION",
    "BlenderSource",
    "default_orbit_radius",
    "resolve_scene",
    "scene_extent",
]

"""Load a user's ``.blend`` file as a scene (needs ``bpy``).

Rules: the file's active scene is used with its objects, materials and world; its cameras are dropped (the
trajectory provides the camera); when no light object renders, the default sun + white world light of
:func:`~spikenerf.scenes.blender.render.add_default_light` replaces the file's world. Render settings are
always spikenerf's (Cycles, linear output), whatever the file says.
"""

from __future__ import annotations

from pathlib import Path

import bpy

from spikenerf.core.errors import InputError
from spikenerf.scenes.blender._bpy import quiet
from spikenerf.scenes.blender.render import add_default_light, geometry_box, has_lights, remove_cameras


def load_blend(path: str | Path) -> bpy.types.Scene:
    """Open ``path`` as the current Blender file and prepare its active scene for rendering.

    Raises:
        InputError: the file is missing, not a .blend Blender can read, or has no visible geometry.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such .blend file (expected a Blender file saved with Blender ≤ 5.0)", path=path)
    with path.open("rb") as handle:
        magic = handle.read(7)
    # plain files start with "BLENDER"; compressed ones with the gzip or zstd magic
    if not (magic.startswith(b"BLENDER") or magic[:2] == b"\x1f\x8b" or magic[:4] == b"\x28\xb5\x2f\xfd"):
        raise InputError(f"not a .blend file (expected header 'BLENDER', found {magic[:7]!r})", path=path)
    try:
        with quiet(stderr=True):
            bpy.ops.wm.open_mainfile(filepath=str(path.resolve()), load_ui=False, use_scripts=False)
    except RuntimeError as err:
        raise InputError(
            f"Blender cannot read this file: {str(err).strip().splitlines()[-1]}", path=path
        ) from err
    scene = bpy.context.scene
    remove_cameras(scene)
    if not has_lights(scene):
        add_default_light(scene)
    try:
        geometry_box(scene)
    except InputError as err:
        raise InputError(str(err), path=path) from err
    return scene

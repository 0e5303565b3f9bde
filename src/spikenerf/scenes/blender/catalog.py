"""What the Blender backend offers, importable without ``bpy``: scene names, defaults and orbit placement."""

from __future__ import annotations

import math

import numpy as np

from spikenerf.core.errors import InputError

#: Built-in procedural scenes: name -> one-line description (what each one tests).
BUILTIN_SCENES: dict[str, str] = {
    "bricks": "lego-like brick castle: fine high-frequency procedural textures (brick, checker, studs)",
    "plant": "potted plant: thin branching stems and many small leaves (ficus-like thin structures)",
    "materials": "grid of spheres: glossy plastics and metals of varying roughness (materials-like)",
    "toy": "toy bulldozer: many small parts, wheels, studs, bevelled blocks (lego/chair-like)",
    "food": "hot dogs on a plate: soft textured bread, sausages and sauce (hotdog-like)",
    "drums": "drum kit: glossy cylinders, white heads, metal cymbals and stands (drums-like)",
}

#: Horizontal field of view of the NeRF synthetic scenes (radians), the default camera.
DEFAULT_CAMERA_ANGLE_X = 0.6911112070083618
#: Fast default frame size (pixels, square).
DEFAULT_SIZE = 200
#: The paper's frame size (NeRF synthetic renders at half resolution, 400 × 400).
PAPER_SIZE = 400
#: Default Cycles samples per pixel.
DEFAULT_SPP = 16

#: Unit vector from the scene towards the default sun (world +Z up): elevation 55°, azimuth −60°.
SUN_DIRECTION: tuple[float, float, float] = (
    math.cos(math.radians(55)) * math.cos(math.radians(-60)),
    math.cos(math.radians(55)) * math.sin(math.radians(-60)),
    math.sin(math.radians(55)),
)
#: Linear radiance a white diffuse surface gets from the uniform white world light (ambient part).
WORLD_LIGHT = 0.2
#: Linear radiance a white diffuse surface facing the sun gets from the sun alone. Cycles' sun strength is
#: irradiance in W/m²; a Lambertian white surface reflects ``strength / π``, so strength = π · SUN_LIGHT.
SUN_LIGHT = 0.8


def default_orbit_radius(
    scene_box: np.ndarray, camera_angle_x: float = DEFAULT_CAMERA_ANGLE_X, margin: float = 1.05
) -> float:
    """Orbit radius at which the scene's bounding sphere fits the horizontal field of view.

    The sphere around ``scene_box`` (centre = box centre, radius = half the diagonal) subtends at most
    ``camera_angle_x`` from any direction, so the content stays in frame on any orbit around the centre.
    Orbit around ``scene_box.mean(0)`` with this radius.

    Args:
        scene_box: (2, 3) min and max corners, world units.
        camera_angle_x: horizontal field of view in radians (the vertical one is assumed not smaller).
        margin: extra factor (> 1 leaves a white border).
    Returns:
        The distance from the box centre to the camera, world units.
    """
    box = np.asarray(scene_box, dtype=np.float64)
    if box.shape != (2, 3) or not np.all(np.isfinite(box)) or np.any(box[1] < box[0]):
        raise InputError(f"scene_box must be finite (2, 3) [min, max] corners, got {box.tolist()}")
    if not 0 < camera_angle_x < math.pi:
        raise InputError(f"camera_angle_x must be in (0, π) radians, got {camera_angle_x}")
    half_diagonal = max(0.5 * float(np.linalg.norm(box[1] - box[0])), 1e-3)
    return margin * half_diagonal / math.sin(0.5 * camera_angle_x)

"""The built-in ``drums`` scene (needs ``bpy``): shells, hoops, stands and cymbals from primitives."""

from __future__ import annotations

import math

import bpy
import numpy as np
from mathutils import Euler, Vector

from spikenerf.scenes.blender.materials import CHROME, bump, coords, material
from spikenerf.scenes.blender.shapes import Parts, Vec3

Mat = bpy.types.Material


def _drum(
    p: Parts,
    shell: Mat,
    head: Mat,
    metal: Mat,
    center: Vec3,
    radius: float,
    depth: float,
    rot: Vec3 = (0, 0, 0),
) -> None:
    """A drum along local Z: shell, two heads, two hoops, eight lugs."""
    axis = Euler(rot, "XYZ").to_matrix()
    c = Vector(center)
    p.cylinder(shell, center, radius, depth, rot=rot, segments=48)
    p.cylinder(head, center, radius * 0.97, depth + 0.008, rot=rot, segments=48)
    for end in (-0.5, 0.5):
        p.torus(metal, tuple(c + axis @ Vector((0, 0, end * depth))), radius * 1.005, 0.012, rot=rot)
    for k in range(8):
        a = 2 * math.pi * k / 8
        pos = c + axis @ Vector((radius * math.cos(a), radius * math.sin(a), 0))
        p.cube(metal, tuple(pos), (0.03, 0.03, min(0.06, 0.5 * depth)), rot=(rot[0], rot[1], rot[2] + a))


def _stand(p: Parts, metal: Mat, base: tuple[float, float], top_z: float, floor: float = -0.82) -> None:
    """A vertical pole on a tripod."""
    x, y = base
    p.cylinder(metal, (x, y, 0.5 * (top_z + floor)), 0.012, top_z - floor, segments=12)
    for k in range(3):
        a = 2 * math.pi * k / 3 + 0.3
        p.tube(
            metal,
            np.array([[x, y, floor + 0.22], [x + 0.2 * math.cos(a), y + 0.2 * math.sin(a), floor]]),
            0.008,
            segments=6,
        )


def _cymbal(p: Parts, brass: Mat, center: Vec3, radius: float, tilt: float) -> None:
    """A thin cone with a bell, tilted about X."""
    p.cylinder(brass, center, radius, 0.012, radius2=0.06, rot=(tilt, 0, 0), segments=64)
    p.sphere(brass, center, 0.06, scale=(1, 1, 0.55), rot=(tilt, 0, 0), segments=24)


def build_drums(rng: np.random.Generator) -> None:
    """A drum kit: glossy clear-coated shells, white heads, chrome hoops and lugs, brass cymbals on stands."""
    shell = material("drum_shell", (0.45, 0.02, 0.02), roughness=0.2, coat=1.0)
    head = material("drum_head", (0.85, 0.84, 0.8), roughness=0.55)
    metal = material("drum_chrome", **CHROME)
    brass = material("cymbal_brass", (0.85, 0.6, 0.25), roughness=0.22, metallic=1.0)
    wave = brass.node_tree.nodes.new("ShaderNodeTexWave")
    wave.wave_type = "RINGS"
    wave.rings_direction = "SPHERICAL"
    wave.inputs["Scale"].default_value = 40.0
    brass.node_tree.links.new(coords(brass), wave.inputs["Vector"])
    bump(brass, wave.outputs["Factor"], 0.08, 0.005)
    p = Parts("drums")
    _drum(p, shell, head, metal, (0, 0, -0.45), 0.36, 0.34, rot=(0, math.pi / 2, 0))
    for y in (-0.2, 0.2):
        _drum(p, shell, head, metal, (0.05, y, 0.08), 0.15, 0.15, rot=(0.35 * np.sign(y), 0.25, 0))
    p.cylinder(metal, (0.03, 0, -0.05), 0.015, 0.2, segments=12)
    _drum(p, shell, head, metal, (-0.2, -0.62, -0.32), 0.22, 0.28)
    for k in range(3):
        a = 2 * math.pi * k / 3
        x, y = -0.2 + 0.24 * math.cos(a), -0.62 + 0.24 * math.sin(a)
        p.cylinder(metal, (x, y, -0.57), 0.01, 0.5, segments=8)
    _drum(p, shell, head, metal, (0.38, 0.5, -0.2), 0.18, 0.12, rot=(0.1, 0, 0))
    _stand(p, metal, (0.38, 0.5), -0.26)
    _stand(p, metal, (0.05, 0.85), 0.1)
    _cymbal(p, brass, (0.05, 0.85, 0.08), 0.17, 0.0)
    _cymbal(p, brass, (0.05, 0.85, 0.11), 0.17, 0.0)
    tilt = rng.uniform(-0.05, 0.05)
    _stand(p, metal, (-0.4, 0.45), 0.5)
    _cymbal(p, brass, (-0.4, 0.45, 0.52), 0.27, 0.3 + tilt)
    _stand(p, metal, (-0.35, -0.62), 0.38)
    _cymbal(p, brass, (-0.35, -0.62, 0.4), 0.3, -0.25 - tilt)
    for side in (-1, 1):  # bass drum spurs
        p.tube(metal, np.array([[0.1, side * 0.3, -0.55], [0.2, side * 0.45, -0.82]]), 0.01, segments=6)
    p.finish()

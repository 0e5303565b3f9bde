"""The built-in procedural scenes (needs ``bpy``): primitives, modifiers and node materials, no assets.

Each builder fills the current (empty) scene, deterministic given ``seed``, inside roughly [-1, 1]³ with world
+Z up; :func:`build` then moves the bounding-box centre to the origin. Colours are linear. See
``catalog.BUILTIN_SCENES`` for what each tests.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import bpy
import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.scenes.blender.catalog import BUILTIN_SCENES
from spikenerf.scenes.blender.drums import build_drums
from spikenerf.scenes.blender.materials import (
    CHROME,
    brick_material,
    bsdf_input,
    bump,
    checker_material,
    coords,
    material,
    noisy_material,
    ramp,
)
from spikenerf.scenes.blender.render import add_default_light, geometry_box
from spikenerf.scenes.blender.shapes import Parts, add_modifier, stud_grid


# ------------------------------------------------------------------------------------------------ scenes
def build_bricks(rng: np.random.Generator) -> None:
    """A toy castle: brick walls and towers, checker-tiled roofs, a studded base plate."""
    red = brick_material("brick_red", (0.30, 0.06, 0.03), (0.75, 0.72, 0.65), 6.0, rng)
    stone = brick_material("brick_stone", (0.35, 0.33, 0.30), (0.08, 0.08, 0.08), 8.0, rng)
    roof = checker_material("roof_tiles", (0.02, 0.08, 0.45), (0.6, 0.65, 0.8), 22.0, roughness=0.3)
    green = material("plate_green", (0.02, 0.30, 0.05), roughness=0.25)
    wood = noisy_material("door_wood", [(0.3, (0.10, 0.04, 0.01)), (0.7, (0.25, 0.12, 0.04))], 12.0, rng)
    dark = material("window_dark", (0.01, 0.01, 0.015), roughness=0.2)
    flag = material("flag_yellow", (0.9, 0.6, 0.02), roughness=0.5)
    p = Parts("bricks")
    p.cube(green, (0, 0, -0.74), (1.8, 1.8, 0.08))
    h, z0, s = 0.62, -0.70, 0.65
    for rot, sign in ((0, -1), (0, 1), (math.pi / 2, -1), (math.pi / 2, 1)):
        pos = (0, sign * s, 0) if rot == 0 else (sign * s, 0, 0)
        if rot == 0 and sign == -1:  # front wall with a gate
            for dx in (-0.4, 0.4):
                p.cube(red, (dx, pos[1], z0 + h / 2), (0.5, 0.16, h))
            p.cube(red, (0, pos[1], z0 + h - 0.12), (0.3, 0.16, 0.24))
            p.cube(wood, (0, pos[1] + 0.02, z0 + 0.19), (0.3, 0.1, 0.38))
        else:
            p.cube(red, (pos[0], pos[1], z0 + h / 2), (1.3, 0.16, h), rot=(0, 0, rot))
        for k in range(-2, 3):  # battlements
            off = (k * 0.22, 0, 0) if rot == 0 else (0, k * 0.22, 0)
            p.cube(red, (pos[0] + off[0], pos[1] + off[1], z0 + h + 0.05), (0.1, 0.16, 0.1), rot=(0, 0, rot))
    for x in (-s, s):
        for y in (-s, s):
            p.cylinder(red, (x, y, z0 + 0.47), 0.2, 0.94)
            p.cylinder(roof, (x, y, 0.46), 0.27, 0.46, radius2=0.0)
            for a in range(8):
                ang = a * math.pi / 4
                p.cube(
                    dark,
                    (x + 0.195 * math.cos(ang), y + 0.195 * math.sin(ang), 0.08),
                    (0.03, 0.03, 0.08),
                    rot=(0, 0, ang),
                )
    p.cube(stone, (0, 0, z0 + 0.57), (0.55, 0.55, 1.14))
    p.cylinder(roof, (0, 0, 0.64), 0.42, 0.4, radius2=0.0, rot=(0, 0, math.pi / 4), segments=4)
    for ang in (0, math.pi / 2, math.pi, 1.5 * math.pi):
        for z in (0.05, 0.3):
            p.cube(dark, (0.28 * math.cos(ang), 0.28 * math.sin(ang), z), (0.05, 0.09, 0.14), rot=(0, 0, ang))
    p.cylinder(dark, (0, 0, 0.88), 0.012, 0.2)
    p.cube(flag, (0.08, 0, 0.93), (0.15, 0.01, 0.09))
    p.finish()
    stud_grid("studs", green, (-0.825, -0.825, -0.685), 0.045, 0.03, pitch=0.15, count=12)


def build_plant(rng: np.random.Generator) -> None:
    """A potted ficus-like plant: a recursive tree of thin stems with many small leaves."""
    pot = noisy_material(
        "pot_terracotta",
        [(0.3, (0.45, 0.12, 0.04)), (0.8, (0.6, 0.2, 0.08))],
        6.0,
        rng,
        roughness=0.8,
        bump_strength=0.1,
    )
    soil = noisy_material(
        "soil",
        [(0.3, (0.02, 0.012, 0.006)), (0.7, (0.08, 0.05, 0.03))],
        40.0,
        rng,
        roughness=1.0,
        bump_strength=0.6,
    )
    bark = material("bark", (0.12, 0.07, 0.03), roughness=0.8)
    leaf = noisy_material(
        "leaf",
        [(0.35, (0.02, 0.12, 0.01)), (0.65, (0.10, 0.35, 0.03))],
        3.0,
        rng,
        roughness=0.4,
        bump_strength=0.0,
    )
    p = Parts("plant")
    p.cylinder(pot, (0, 0, -0.62), 0.2, 0.40, radius2=0.28, segments=48)
    p.torus(pot, (0, 0, -0.42), 0.28, 0.025)
    p.cylinder(soil, (0, 0, -0.45), 0.265, 0.02, segments=48)
    leaves = Parts("leaves")

    def grow(start: np.ndarray, direction: np.ndarray, length: float, radius: float, depth: int) -> None:
        n = 7
        pts = [start]
        d = direction / np.linalg.norm(direction)
        for _ in range(n - 1):
            d = d + rng.normal(0, 0.12, 3) + np.array([0, 0, 0.05 if depth > 0 else -0.05])
            d /= np.linalg.norm(d)
            nxt = pts[-1] + d * length / (n - 1)
            nxt[2] = min(nxt[2], 0.9)
            pts.append(nxt)
        pts = np.array(pts)
        r = np.linspace(radius, radius * 0.55, n)
        p.tube(bark, pts, r, segments=6)
        for i in range(2, n):
            for _ in range(2 if i < n - 1 else 3):
                side = rng.normal(0, 1, 3)
                side -= side.dot(d) * d
                leaf_dir = 0.6 * side / (np.linalg.norm(side) + 1e-9) + 0.5 * d + np.array([0, 0, -0.25])
                leaves.leaf(
                    leaf,
                    tuple(pts[i]),
                    tuple(leaf_dir),
                    rng.uniform(0.09, 0.13),
                    rng.uniform(0.05, 0.07),
                    roll=rng.uniform(-0.6, 0.6),
                )
        if depth > 0:
            for _ in range(rng.integers(2, 4)):
                i = int(rng.integers(2, n - 1))
                axis = rng.normal(0, 1, 3)
                child = d + 0.9 * np.cross(d, axis / np.linalg.norm(axis))
                grow(pts[i], child, length * 0.6, r[i] * 0.8, depth - 1)

    trunk = np.array([[0, 0, -0.45], [0.02, 0.01, -0.25], [0.0, -0.02, -0.05], [0.03, 0.0, 0.12]])
    p.tube(bark, trunk, np.linspace(0.035, 0.022, len(trunk)), segments=8)
    for k in range(5):
        az = 2 * math.pi * k / 5 + rng.uniform(-0.3, 0.3)
        el = rng.uniform(0.35, 0.8)
        direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        grow(trunk[-1] + np.array([0, 0, -0.08 * (k % 2)]), direction, rng.uniform(0.5, 0.62), 0.018, 2)
    p.finish()
    add_modifier(leaves.finish()[leaf.name], "SOLIDIFY", thickness=0.004)


def build_materials(rng: np.random.Generator) -> None:
    """Nine spheres on pedestals: metals, glossy and matte plastics, clear-coated and anisotropic finishes."""
    plate = checker_material("plate_checker", (0.03, 0.03, 0.03), (0.5, 0.5, 0.5), 5.0, roughness=0.35)
    pedestal = material("pedestal", (0.2, 0.2, 0.22), roughness=0.5)
    specs = [
        ("gold", dict(color=(1.0, 0.71, 0.29), roughness=0.15, metallic=1.0)),
        ("copper", dict(color=(0.95, 0.64, 0.54), roughness=0.35, metallic=1.0)),
        ("chrome", dict(color=(0.95, 0.93, 0.88), roughness=0.03, metallic=1.0)),
        ("red_gloss", dict(color=(0.6, 0.03, 0.02), roughness=0.08, coat=1.0)),
        ("blue_plastic", dict(color=(0.02, 0.1, 0.55), roughness=0.3)),
        ("green_rubber", dict(color=(0.05, 0.35, 0.06), roughness=0.75, specular=0.2)),
        ("white_matte", dict(color=(0.8, 0.8, 0.8), roughness=1.0, specular=0.0)),
        ("black_gloss", dict(color=(0.01, 0.01, 0.01), roughness=0.02, coat=1.0)),
        ("brushed_steel", dict(color=(0.6, 0.6, 0.62), roughness=0.4, metallic=1.0)),
    ]
    p = Parts("materials")
    p.cube(plate, (0, 0, -0.5), (1.9, 1.9, 0.06))
    for slot, (name, kw) in enumerate(specs):
        mat = material(name, **kw)
        if name == "brushed_steel":
            mat.node_tree.nodes["Principled BSDF"].inputs["Anisotropic"].default_value = 0.8
        x, y = 0.62 * (slot % 3 - 1), 0.62 * (slot // 3 - 1)
        p.cylinder(pedestal, (x, y, -0.41), 0.13, 0.12, segments=32)
        p.sphere(mat, (x, y, -0.35 + 0.25), 0.26, segments=48)
    p.finish()  # a fixed layout: the seed only drives Cycles' sampling here


def build_toy(rng: np.random.Generator) -> None:
    """A toy bulldozer: tracks of many cleats, wheels, cab with windows, blade, studs (bevelled blocks)."""
    yellow = material("toy_yellow", (0.85, 0.45, 0.0), roughness=0.25, coat=0.3)
    rubber = material("toy_rubber", (0.012, 0.012, 0.012), roughness=0.6)
    steel = material("toy_steel", **CHROME)
    glass = material("toy_glass", (0.01, 0.02, 0.04), roughness=0.03, coat=1.0)
    grey = material("toy_grey", (0.08, 0.08, 0.09), roughness=0.4)
    orange = material("toy_beacon", (0.9, 0.12, 0.0), roughness=0.2)
    p = Parts("toy")
    straight, radius = 1.1, 0.16
    for side in (-1, 1):
        y = side * 0.37
        for x in np.linspace(-0.44, 0.44, 5):
            p.cylinder(grey, (x, y, -0.56), 0.1, 0.18, rot=(math.pi / 2, 0, 0))
            p.cylinder(steel, (x, y + side * 0.092, -0.56), 0.05, 0.01, rot=(math.pi / 2, 0, 0))
        for x in (-0.55, 0.55):
            p.cylinder(grey, (x, y, -0.56), 0.14, 0.19, rot=(math.pi / 2, 0, 0))
            p.cylinder(steel, (x, y + side * 0.1, -0.56), 0.06, 0.01, rot=(math.pi / 2, 0, 0))
        perimeter = 2 * straight + 2 * math.pi * radius
        for s in np.arange(0, perimeter, 0.055):  # the track's cleats around a stadium loop
            if s < straight:
                x, z, ang = -0.55 + s, -0.56 - radius, 0.0
            elif s < straight + math.pi * radius:
                a = (s - straight) / radius
                x, z, ang = 0.55 + radius * math.sin(a), -0.56 - radius * math.cos(a), -a
            elif s < 2 * straight + math.pi * radius:
                x, z, ang = 0.55 - (s - straight - math.pi * radius), -0.56 + radius, math.pi
            else:
                a = (s - 2 * straight - math.pi * radius) / radius
                x, z, ang = -0.55 - radius * math.sin(a), -0.56 + radius * math.cos(a), math.pi - a
            p.cube(rubber, (x, y, z), (0.04, 0.21, 0.035), rot=(0, ang, 0))
        p.cube(yellow, (0, y, -0.37), (1.3, 0.24, 0.03))
    p.cube(yellow, (0, 0, -0.42), (1.1, 0.5, 0.2))
    p.cube(yellow, (-0.27, 0, -0.2), (0.5, 0.48, 0.24))
    for k in range(7):
        p.cube(grey, (-0.525, -0.18 + 0.06 * k, -0.2), (0.02, 0.025, 0.18))
    p.cube(yellow, (0.2, 0, -0.12), (0.4, 0.46, 0.4))
    p.cube(glass, (0.4, 0, -0.07), (0.02, 0.38, 0.22))
    for side in (-1, 1):
        p.cube(glass, (0.2, side * 0.23, -0.07), (0.32, 0.02, 0.22))
    p.cube(yellow, (0.2, 0, 0.1), (0.48, 0.52, 0.04))
    p.sphere(orange, (0.2, 0.15, 0.15), 0.04, segments=16)
    p.cylinder(grey, (-0.2, 0.15, 0.0), 0.03, 0.36, segments=16)
    p.cylinder(steel, (-0.2, 0.15, 0.19), 0.036, 0.02, segments=16)
    p.cube(yellow, (0.86, 0, -0.52), (0.06, 1.05, 0.3), rot=(0, -0.2, 0))
    p.cube(steel, (0.895, 0, -0.68), (0.03, 1.05, 0.04), rot=(0, -0.2, 0))
    for side in (-1, 1):
        p.cylinder(grey, (0.65, side * 0.32, -0.45), 0.03, 0.45, rot=(0, math.pi / 2 + 0.35, 0), segments=16)
    for y in (-0.15, 0.0, 0.15):
        p.cube(steel, (-0.72, y, -0.55), (0.05, 0.04, 0.22), rot=(0, 0.3, 0))
    p.cube(grey, (-0.62, 0, -0.42), (0.2, 0.4, 0.05))
    for obj in p.finish().values():
        add_modifier(obj, "BEVEL", width=0.008, segments=2, limit_method="ANGLE")
    stud_grid("toy_studs", yellow, (-0.45, -0.18, -0.065), 0.04, 0.03, pitch=0.12, count=4)


def build_food(rng: np.random.Generator) -> None:
    """Two hot dogs on a plate: bumpy bread (displaced), grilled sausages, sauce, pickles."""
    plate = material("plate_ceramic", (0.8, 0.8, 0.78), roughness=0.15, coat=1.0)
    rim = material("plate_rim", (0.02, 0.08, 0.4), roughness=0.2, coat=1.0)
    bread = noisy_material(
        "bread",
        [(0.35, (0.55, 0.25, 0.05)), (0.55, (0.75, 0.45, 0.15)), (0.75, (0.85, 0.65, 0.35))],
        9.0,
        rng,
        roughness=0.7,
        bump_strength=0.3,
    )
    sausage = material("sausage", (0.3, 0.06, 0.02), roughness=0.3, coat=0.5)
    nodes, links = sausage.node_tree.nodes, sausage.node_tree.links
    wave = nodes.new("ShaderNodeTexWave")
    wave.inputs["Scale"].default_value = 3.0
    wave.inputs["Distortion"].default_value = 2.0
    links.new(coords(sausage, offset=tuple(rng.uniform(-1, 1, 3))), wave.inputs["Vector"])
    bsdf_input(
        sausage,
        "Base Color",
        ramp(
            sausage,
            wave.outputs["Factor"],
            [(0.0, (0.05, 0.01, 0.005)), (0.35, (0.35, 0.08, 0.03)), (1.0, (0.45, 0.12, 0.05))],
        ),
    )
    bump(sausage, wave.outputs["Factor"], 0.15)
    mustard = material("mustard", (0.8, 0.5, 0.01), roughness=0.25)
    ketchup = material("ketchup", (0.45, 0.01, 0.005), roughness=0.15, coat=0.5)
    pickle = noisy_material(
        "pickle", [(0.3, (0.05, 0.15, 0.01)), (0.7, (0.2, 0.35, 0.05))], 30.0, rng, roughness=0.3
    )
    p, buns = Parts("food"), Parts("buns")
    p.cylinder(plate, (0, 0, -0.5), 0.6, 0.08, radius2=0.95, segments=64)
    p.torus(rim, (0, 0, -0.455), 0.93, 0.025, segments=(64, 10))
    for k, (y, sauce) in enumerate(((-0.27, mustard), (0.27, ketchup))):
        turn = rng.uniform(-0.1, 0.1) + (0.06 if k else -0.06)
        rot, c, s = (0, 0, turn), math.cos(turn), math.sin(turn)
        for side in (-1, 1):
            dx, dy = -s * side * 0.1, c * side * 0.1
            buns.capsule(bread, (dx, y + dy, -0.34), 1.25, 0.13, scale=(1, 1, 0.9), rot=rot)
        p.capsule(sausage, (0, y, -0.24), 1.38, 0.085, rot=rot)
        t = np.linspace(-0.55, 0.55, 120)
        off = 0.055 * np.sin(t * 2 * math.pi * 5.5)
        z = -0.24 + np.sqrt(np.maximum(0.085**2 - off**2, 0)) + 0.008
        pts = np.stack([t * c - off * s, y + t * s + off * c, z], axis=1)
        p.tube(sauce, pts, 0.018, segments=8)
    for _ in range(3):
        a, r = rng.uniform(0, 2 * math.pi), rng.uniform(0.65, 0.75)
        p.cylinder(pickle, (r * math.cos(a), r * math.sin(a), -0.445), 0.09, 0.02, segments=24)
    p.finish()
    obj = buns.finish()[bread.name]
    add_modifier(obj, "SUBSURF", levels=1, render_levels=1)
    tex = bpy.data.textures.new("bread_bumps", "CLOUDS")
    tex.noise_scale = 0.08
    add_modifier(obj, "DISPLACE", texture=tex, strength=0.015, mid_level=0.5, texture_coords="GLOBAL")


BUILDERS: dict[str, Callable[[np.random.Generator], None]] = {
    "bricks": build_bricks,
    "plant": build_plant,
    "materials": build_materials,
    "toy": build_toy,
    "food": build_food,
    "drums": build_drums,
}


def build(name: str, seed: int = 0) -> None:
    """Fill the current empty scene with the built-in scene ``name``, centred on the origin, and the light."""
    if name not in BUILDERS:
        raise InputError(f"unknown built-in scene {name!r}; expected one of {', '.join(BUILTIN_SCENES)}")
    BUILDERS[name](np.random.default_rng(seed))
    scene = bpy.context.scene
    shift = -geometry_box(scene).mean(0)  # the box centre goes to the origin
    for obj in scene.objects:
        obj.location = tuple(np.asarray(obj.location) + shift)
    bpy.context.view_layer.update()
    add_default_light(scene)

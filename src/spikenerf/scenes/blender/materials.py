"""Node materials for the procedural scenes (needs ``bpy``): Principled BSDF plus procedural textures.

Texture vectors are object-space positions (scene objects sit at the origin with identity transforms), so a
pattern is continuous across all parts that share a material. Colours are linear RGB.
"""

from __future__ import annotations

from collections.abc import Sequence

import bpy
import numpy as np

Vec3 = Sequence[float]


def material(
    name: str,
    color: Vec3 = (0.8, 0.8, 0.8),
    roughness: float = 0.5,
    metallic: float = 0.0,
    coat: float = 0.0,
    specular: float = 0.5,
) -> bpy.types.Material:
    """A Principled BSDF material with linear base ``color``."""
    mat = bpy.data.materials.new(name)
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Coat Weight"].default_value = coat
    bsdf.inputs["Specular IOR Level"].default_value = specular
    return mat


def coords(
    mat: bpy.types.Material, offset: Vec3 = (0, 0, 0), scale: Vec3 = (1, 1, 1)
) -> bpy.types.NodeSocket:
    """Object-space coordinates shifted by ``offset`` and scaled (the texture vector of a material)."""
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    tex = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Location"].default_value = offset
    mapping.inputs["Scale"].default_value = scale
    links.new(tex.outputs["Object"], mapping.inputs["Vector"])
    return mapping.outputs["Vector"]


def ramp(
    mat: bpy.types.Material, fac: bpy.types.NodeSocket, stops: Sequence[tuple[float, Vec3]]
) -> bpy.types.NodeSocket:
    """A colour ramp of (position, linear RGB) ``stops`` driven by ``fac``."""
    node = mat.node_tree.nodes.new("ShaderNodeValToRGB")
    elements = node.color_ramp.elements
    elements[0].position, elements[0].color = stops[0][0], (*stops[0][1], 1.0)
    elements[1].position, elements[1].color = stops[-1][0], (*stops[-1][1], 1.0)
    for pos, col in stops[1:-1]:
        elements.new(pos).color = (*col, 1.0)
    mat.node_tree.links.new(fac, node.inputs["Factor"])
    return node.outputs["Color"]


def noise(
    mat: bpy.types.Material,
    vector: bpy.types.NodeSocket,
    scale: float,
    detail: float = 4.0,
    roughness: float = 0.5,
) -> bpy.types.NodeSocket:
    """fBm noise factor in [0, 1]."""
    node = mat.node_tree.nodes.new("ShaderNodeTexNoise")
    node.inputs["Scale"].default_value = scale
    node.inputs["Detail"].default_value = detail
    node.inputs["Roughness"].default_value = roughness
    mat.node_tree.links.new(vector, node.inputs["Vector"])
    return node.outputs["Factor"]


def bsdf_input(mat: bpy.types.Material, name: str, socket: bpy.types.NodeSocket) -> None:
    """Link ``socket`` into the Principled BSDF input ``name``."""
    mat.node_tree.links.new(socket, mat.node_tree.nodes["Principled BSDF"].inputs[name])


def bump(
    mat: bpy.types.Material, height: bpy.types.NodeSocket, strength: float, distance: float = 0.02
) -> None:
    """Perturb the BSDF normal by ``height`` (a bump map)."""
    node = mat.node_tree.nodes.new("ShaderNodeBump")
    node.inputs["Strength"].default_value = strength
    node.inputs["Distance"].default_value = distance
    mat.node_tree.links.new(height, node.inputs["Height"])
    bsdf_input(mat, "Normal", node.outputs["Normal"])


#: Keyword arguments of :func:`material` for polished chrome.
CHROME = dict(color=(0.9, 0.9, 0.9), roughness=0.08, metallic=1.0)


def brick_material(
    name: str, brick: Vec3, mortar: Vec3, scale: float, rng: np.random.Generator
) -> bpy.types.Material:
    """Bricks laid on vertical walls: texture vector (x + y, z) so both wall directions get courses."""
    mat = material(name, roughness=0.7)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(coords(mat, offset=tuple(rng.uniform(-5, 5, 3))), sep.inputs["Vector"])
    add = nodes.new("ShaderNodeMath")
    links.new(sep.outputs["X"], add.inputs[0])
    links.new(sep.outputs["Y"], add.inputs[1])
    vec = nodes.new("ShaderNodeCombineXYZ")
    links.new(add.outputs[0], vec.inputs["X"])
    links.new(sep.outputs["Z"], vec.inputs["Y"])
    tex = nodes.new("ShaderNodeTexBrick")
    tex.offset = 0.5
    tex.inputs["Color1"].default_value = (*brick, 1.0)
    tex.inputs["Color2"].default_value = (*(0.55 * np.asarray(brick)), 1.0)
    tex.inputs["Mortar"].default_value = (*mortar, 1.0)
    tex.inputs["Scale"].default_value = scale
    tex.inputs["Mortar Size"].default_value = 0.06
    tex.inputs["Bias"].default_value = 0.2
    links.new(vec.outputs["Vector"], tex.inputs["Vector"])
    bsdf_input(mat, "Base Color", tex.outputs["Color"])
    bump(mat, tex.outputs["Factor"], 0.4, 0.01)
    return mat


def checker_material(name: str, a: Vec3, b: Vec3, scale: float, roughness: float = 0.5) -> bpy.types.Material:
    """A 3D checker of colours ``a`` and ``b``, ``scale`` cells per unit."""
    mat = material(name, roughness=roughness)
    tex = mat.node_tree.nodes.new("ShaderNodeTexChecker")
    tex.inputs["Color1"].default_value = (*a, 1.0)
    tex.inputs["Color2"].default_value = (*b, 1.0)
    tex.inputs["Scale"].default_value = scale
    mat.node_tree.links.new(coords(mat), tex.inputs["Vector"])
    bsdf_input(mat, "Base Color", tex.outputs["Color"])
    return mat


def noisy_material(
    name: str,
    stops: Sequence[tuple[float, Vec3]],
    scale: float,
    rng: np.random.Generator,
    roughness: float = 0.5,
    bump_strength: float = 0.2,
    **kw: float,
) -> bpy.types.Material:
    """fBm noise (``scale`` cells per unit, seeded offset) through a colour ramp, optionally as a bump too."""
    mat = material(name, roughness=roughness, **kw)
    fac = noise(mat, coords(mat, offset=tuple(rng.uniform(-10, 10, 3))), scale, detail=6.0, roughness=0.6)
    bsdf_input(mat, "Base Color", ramp(mat, fac, stops))
    if bump_strength > 0:
        bump(mat, fac, bump_strength, 0.02)
    return mat

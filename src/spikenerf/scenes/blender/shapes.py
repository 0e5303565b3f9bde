"""Geometry building blocks for the procedural scenes (needs ``bpy``): primitives merged per material.

Every primitive is added to one ``bmesh`` per material, so a scene with hundreds of parts becomes a handful
of objects at the origin with identity transforms (fast scene sync, continuous object-space textures).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import bmesh
import bpy
import numpy as np
from mathutils import Euler, Matrix, Vector

Vec3 = Sequence[float]


def xform(loc: Vec3 = (0, 0, 0), rot: Vec3 = (0, 0, 0), scale: Vec3 = (1, 1, 1)) -> Matrix:
    """4 × 4 transform: scale, then XYZ Euler rotation (radians), then translation."""
    return Matrix.LocRotScale(Vector(loc), Euler(rot, "XYZ"), Vector(scale))


class Parts:
    """Accumulates primitives into one mesh per material; :meth:`finish` links one object per material."""

    def __init__(self, prefix: str) -> None:
        self.prefix = prefix
        self._meshes: dict[str, tuple[bmesh.types.BMesh, bpy.types.Material]] = {}

    def _bm(self, material: bpy.types.Material) -> bmesh.types.BMesh:
        if material.name not in self._meshes:
            self._meshes[material.name] = (bmesh.new(), material)
        return self._meshes[material.name][0]

    def cube(self, mat: bpy.types.Material, loc: Vec3, size: Vec3, rot: Vec3 = (0, 0, 0)) -> None:
        """An axis-aligned box of edge lengths ``size`` centred at ``loc`` (then rotated)."""
        bmesh.ops.create_cube(self._bm(mat), size=1.0, matrix=xform(loc, rot, size))

    def cylinder(
        self,
        mat: bpy.types.Material,
        loc: Vec3,
        radius: float,
        depth: float,
        rot: Vec3 = (0, 0, 0),
        radius2: float | None = None,
        segments: int = 32,
    ) -> None:
        """A (truncated) cone along local Z: ``radius`` at the bottom, ``radius2`` at the top."""
        r2 = radius if radius2 is None else radius2
        bmesh.ops.create_cone(
            self._bm(mat),
            cap_ends=True,
            segments=segments,
            radius1=radius,
            radius2=r2,
            depth=depth,
            matrix=xform(loc, rot),
        )

    def sphere(
        self,
        mat: bpy.types.Material,
        loc: Vec3,
        radius: float,
        scale: Vec3 = (1, 1, 1),
        rot: Vec3 = (0, 0, 0),
        segments: int = 32,
    ) -> None:
        """A UV sphere (an ellipsoid with ``scale``)."""
        bmesh.ops.create_uvsphere(
            self._bm(mat),
            u_segments=segments,
            v_segments=segments // 2,
            radius=radius,
            matrix=xform(loc, rot, scale),
        )

    def capsule(
        self,
        mat: bpy.types.Material,
        loc: Vec3,
        length: float,
        radius: float,
        scale: Vec3 = (1, 1, 1),
        rot: Vec3 = (0, 0, 0),
        segments: int = 32,
    ) -> None:
        """A capsule along local X: total length ``length``, end radius ``radius``."""
        bm = self._bm(mat)
        verts = bmesh.ops.create_uvsphere(
            bm,
            u_segments=segments,
            v_segments=segments // 2,
            radius=radius,
            matrix=Matrix.Rotation(math.pi / 2, 4, "Y"),
        )["verts"]
        half = max(0.5 * length - radius, 0.0)
        for v in verts:
            v.co.x += half if v.co.x > 1e-6 else -half if v.co.x < -1e-6 else 0.0
        bmesh.ops.transform(bm, matrix=xform(loc, rot, scale), verts=verts)

    def torus(
        self,
        mat: bpy.types.Material,
        loc: Vec3,
        major: float,
        minor: float,
        rot: Vec3 = (0, 0, 0),
        segments: tuple[int, int] = (48, 12),
    ) -> None:
        """A ring around local Z."""
        bm, m = self._bm(mat), xform(loc, rot)
        nu, nv = segments
        rings = []
        for i in range(nu):
            a = 2 * math.pi * i / nu
            ring = []
            for j in range(nv):
                b = 2 * math.pi * j / nv
                r = major + minor * math.cos(b)
                ring.append(bm.verts.new(m @ Vector((r * math.cos(a), r * math.sin(a), minor * math.sin(b)))))
            rings.append(ring)
        for i in range(nu):
            for j in range(nv):
                a, b = rings[i], rings[(i + 1) % nu]
                bm.faces.new((a[j], b[j], b[(j + 1) % nv], a[(j + 1) % nv]))

    def tube(
        self,
        mat: bpy.types.Material,
        points: np.ndarray,
        radii: float | np.ndarray,
        segments: int = 8,
        caps: bool = True,
    ) -> None:
        """A tube along the polyline ``points`` (N, 3) with per-point ``radii`` (transported frames)."""
        pts = np.asarray(points, dtype=np.float64)
        rad = np.broadcast_to(np.asarray(radii, dtype=np.float64), (len(pts),))
        bm = self._bm(mat)
        tangents = np.gradient(pts, axis=0)
        tangents /= np.linalg.norm(tangents, axis=1, keepdims=True) + 1e-12
        ref = np.array([0.0, 0.0, 1.0]) if abs(tangents[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        normal = np.cross(tangents[0], ref)
        normal /= np.linalg.norm(normal)
        rings = []
        for p, t, r in zip(pts, tangents, rad, strict=True):
            normal = normal - t * normal.dot(t)  # transport the frame along the curve
            normal /= np.linalg.norm(normal) + 1e-12
            binormal = np.cross(t, normal)
            angles = 2 * np.pi * np.arange(segments) / segments
            ring_pts = p + r * (np.cos(angles)[:, None] * normal + np.sin(angles)[:, None] * binormal)
            rings.append([bm.verts.new(tuple(q)) for q in ring_pts])
        for a, b in itertools.pairwise(rings):
            for j in range(segments):
                bm.faces.new((a[j], a[(j + 1) % segments], b[(j + 1) % segments], b[j]))
        if caps:
            bm.faces.new(list(reversed(rings[0])))
            bm.faces.new(rings[-1])

    def leaf(
        self,
        mat: bpy.types.Material,
        base: Vec3,
        direction: Vec3,
        length: float,
        width: float,
        roll: float = 0.0,
    ) -> None:
        """A flat pointed leaf (10-vertex outline with a midrib fold) from ``base`` along ``direction``."""
        d = Vector(direction).normalized()
        side = d.cross(Vector((0, 0, 1)))
        if side.length < 1e-6:
            side = Vector((1, 0, 0))
        side = (Matrix.Rotation(roll, 3, d) @ side).normalized()
        up = side.cross(d).normalized()
        b = Vector(base)
        ts = (0.0, 0.2, 0.45, 0.7, 0.9)
        ws = (0.0, 0.8, 1.0, 0.75, 0.3)
        bm = self._bm(mat)
        mid = [bm.verts.new(b + d * (t * length) + up * (0.08 * width)) for t in ts] + [
            bm.verts.new(b + d * length)
        ]
        left = [
            bm.verts.new(b + d * (t * length) + side * (0.5 * width * w)) for t, w in zip(ts, ws, strict=True)
        ]
        right = [
            bm.verts.new(b + d * (t * length) - side * (0.5 * width * w)) for t, w in zip(ts, ws, strict=True)
        ]
        for k in range(len(ts) - 1):
            bm.faces.new((mid[k], left[k], left[k + 1], mid[k + 1]))
            bm.faces.new((mid[k], mid[k + 1], right[k + 1], right[k]))
        bm.faces.new((mid[-2], left[-1], mid[-1]))
        bm.faces.new((mid[-2], mid[-1], right[-1]))

    def finish(self, smooth_angle_deg: float = 40.0) -> dict[str, bpy.types.Object]:
        """Link one object per material to the current scene; smooth shading below ``smooth_angle_deg``."""
        objects = {}
        for name, (bm, mat) in self._meshes.items():
            mesh = bpy.data.meshes.new(f"{self.prefix}_{name}")
            bm.normal_update()
            bm.to_mesh(mesh)
            bm.free()
            mesh.materials.append(mat)
            mesh.shade_smooth()
            mesh.set_sharp_from_angle(angle=math.radians(smooth_angle_deg))
            obj = bpy.data.objects.new(mesh.name, mesh)
            bpy.context.scene.collection.objects.link(obj)
            objects[name] = obj
        self._meshes.clear()
        return objects


def add_modifier(obj: bpy.types.Object, kind: str, **props: object) -> bpy.types.Modifier:
    """Add a modifier of type ``kind`` (e.g. ``BEVEL``, ``ARRAY``) with attribute values ``props``."""
    mod = obj.modifiers.new(kind.lower(), kind)
    for key, value in props.items():
        setattr(mod, key, value)
    return mod


def stud_grid(
    prefix: str, mat: bpy.types.Material, loc: Vec3, radius: float, depth: float, pitch: float, count: int
) -> None:
    """A ``count × count`` grid of studs (cylinders, 16 segments) from ``loc``, ``pitch`` apart along x and y.

    One stud mesh (object ``{prefix}_{mat.name}``) repeated by two ARRAY modifiers: along x, then along y.
    """
    studs = Parts(prefix)
    studs.cylinder(mat, loc, radius, depth, segments=16)
    obj = studs.finish()[mat.name]
    for offset in ((pitch, 0, 0), (0, pitch, 0)):
        add_modifier(
            obj,
            "ARRAY",
            count=count,
            use_relative_offset=False,
            use_constant_offset=True,
            constant_offset_displace=offset,
        )

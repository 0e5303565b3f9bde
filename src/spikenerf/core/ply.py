"""Binary little-endian PLY: points or a triangle mesh with 8-bit vertex colours (``spikenerf export``).

The one PLY codec: :func:`ply_bytes` encodes vertices as ``float x, y, z``, optionally ``float nx, ny, nz``
(unit normals, for smooth shading) and ``uchar red, green, blue`` and, for a mesh, faces as
``list uchar int vertex_indices`` (triangles), the layout MeshLab, CloudCompare, Open3D and Blender read.
:func:`read_ply` reads that layout back (any vertex properties of the standard scalar types, a face list of
any index type): the tests' check of what ``export`` wrote.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spikenerf.core.atomic import write_bytes_atomic
from spikenerf.core.errors import InputError

#: PLY scalar type names → little-endian numpy dtypes
_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "<i2", "int16": "<i2",
    "ushort": "<u2", "uint16": "<u2", "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}  # fmt: skip
_XYZ, _NORMAL, _RGB = ("x", "y", "z"), ("nx", "ny", "nz"), ("red", "green", "blue")
_FACE = np.dtype([("n", "u1"), ("v", "<i4", (3,))])


@dataclass
class Ply:
    """What a PLY file holds: ``points`` float32 (N, 3), ``colors`` uint8 (N, 3) (None without colour
    properties), ``faces`` int64 (F, 3) triangles (None for a point cloud), ``normals`` float32 (N, 3)
    (None without ``nx, ny, nz``)."""

    points: np.ndarray
    colors: np.ndarray | None
    faces: np.ndarray | None
    normals: np.ndarray | None = None


def ply_bytes(
    points: np.ndarray, colors: np.ndarray, faces: np.ndarray | None = None, normals: np.ndarray | None = None
) -> bytes:
    """The PLY file of ``points`` (N, 3) (written as float32), ``colors`` uint8 (N, 3), for a mesh
    triangle ``faces`` (F, 3) of vertex indices in [0, N), and per-vertex ``normals`` (N, 3) (written as
    float32 ``nx, ny, nz``; None: none)."""
    points, colors = np.asarray(points), np.asarray(colors)
    n = len(points)
    if points.shape != (n, 3) or colors.shape != (n, 3) or colors.dtype != np.uint8:
        raise ValueError(
            f"points (N, 3) and uint8 colors (N, 3) expected, got {points.shape}, {colors.shape}"
        )
    if normals is not None and np.shape(normals) != (n, 3):
        raise ValueError(f"normals (N, 3) expected, got {np.shape(normals)}")
    columns = [*_XYZ, *(_NORMAL if normals is not None else ()), *_RGB]
    vertices = np.empty(n, np.dtype([(c, "u1" if c in _RGB else "<f4") for c in columns]))
    for i in range(3):
        vertices[_XYZ[i]], vertices[_RGB[i]] = points[:, i], colors[:, i]
        if normals is not None:
            vertices[_NORMAL[i]] = np.asarray(normals)[:, i]
    header = ["ply", "format binary_little_endian 1.0", "comment written by spikenerf export",
              f"element vertex {n}",
              *(f"property {'uchar' if c in _RGB else 'float'} {c}" for c in columns)]  # fmt: skip
    body = vertices.tobytes()
    if faces is not None:
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or (faces.size and not 0 <= faces.min() <= faces.max() < n):
            raise ValueError(f"faces (F, 3) of indices in [0, {n}) expected, got shape {faces.shape}")
        rows = np.empty(len(faces), _FACE)
        rows["n"], rows["v"] = 3, faces
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
        body += rows.tobytes()
    return ("\n".join([*header, "end_header"]) + "\n").encode("ascii") + body


def write_ply(
    path: str | Path,
    points: np.ndarray,
    colors: np.ndarray,
    faces: np.ndarray | None = None,
    normals: np.ndarray | None = None,
) -> None:
    """:func:`ply_bytes` of ``points`` (N, 3), ``colors`` (N, 3) uint8, ``faces`` (F, 3) and ``normals``
    (N, 3) (each of the last two or None) written to ``path`` atomically."""
    write_bytes_atomic(path, ply_bytes(points, colors, faces, normals))


def _parse_header(data: bytes, path: Path) -> tuple[list[tuple[str, int, list[tuple[str, ...]]]], int]:
    """The elements ``(name, count, properties)`` of a binary little-endian PLY and where its body starts."""
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise InputError("not a PLY file (no 'ply' magic or no end_header)", path=path)
    elements: list[tuple[str, int, list[tuple[str, ...]]]] = []
    for line in data[:end].decode("ascii", "replace").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and words[1:2] != ["binary_little_endian"]:
            raise InputError(f"only binary_little_endian PLY is read, found format {words[1:2]}", path=path)
        if words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            elements[-1][2].append(tuple(words[1:]))
    return elements, end + len(b"end_header\n")


def read_ply(path: str | Path) -> Ply:
    """Read a binary little-endian PLY's vertices (``x, y, z`` and, where present, ``nx, ny, nz`` and
    ``red, green, blue``) and triangle faces; an InputError naming ``path`` for another format or a
    truncated file."""
    path = Path(path)
    data = path.read_bytes()
    elements, pos = _parse_header(data, path)
    points, colors, faces, normals = None, None, None, None
    for name, count, props in elements:
        if props and props[0][0] == "list":  # (a list property: the face element, one triangle a row)
            _, count_type, index_type, _ = props[0]
            dtype = np.dtype([("n", _TYPES[count_type]), ("v", _TYPES[index_type], (3,))])
        else:
            dtype = np.dtype([(p[1], _TYPES[p[0]]) for p in props])
        size = dtype.itemsize * count
        if pos + size > len(data):
            raise InputError(f"truncated: element {name} needs {size} bytes past the header", path=path)
        rows = np.frombuffer(data, dtype, count, pos)
        pos += size
        if name == "vertex":
            points = np.stack([rows[a] for a in _XYZ], -1).astype(np.float32)
            if all(c in dtype.names for c in ("red", "green", "blue")):
                colors = np.stack([rows[c] for c in _RGB], -1).astype(np.uint8)
            if all(c in dtype.names for c in _NORMAL):
                normals = np.stack([rows[c] for c in _NORMAL], -1).astype(np.float32)
        elif name == "face":
            if count and not (rows["n"] == 3).all():
                raise InputError("only triangle faces are read", path=path)
            faces = rows["v"].astype(np.int64)
    if points is None:
        raise InputError("no vertex element", path=path)
    return Ply(points, colors, faces, normals)

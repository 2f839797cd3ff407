"""PLY in memory: point clouds out (binary little-endian) and triangle meshes in.

Stages never open files, so PLY is built into bytes (by `plyfile`) and parsed from
bytes here with numpy structured arrays. The reader supports what the simulator writes
(`sonarmap.sim.world.World.to_ply_bytes`: binary little-endian vertex x y z + per-vertex ids,
faces as uchar-count int index lists) and ASCII PLY with the same elements; list
properties are read for triangles (count 3) only.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Mesh", "decode_mesh_ply", "encode_points_ply"]

_PLY_TYPES: dict[str, str] = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh: vertices (v, 3) float64 [m], triangles (t, 3) int64 vertex
    indices, and the other per-vertex properties by name (e.g. object_id, class_id)."""

    vertices: np.ndarray
    triangles: np.ndarray
    vertex_properties: dict[str, np.ndarray] = field(default_factory=dict)


def encode_points_ply(
    xyz_m: np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray],
    rgb: np.ndarray,
    comment: str = "sonarmap",
    properties: Mapping[str, np.ndarray] | None = None,
) -> bytes:
    """Binary little-endian PLY of a coloured point cloud, written by `plyfile`.

    Args:
        xyz_m: (n, 3) points [m], or their three (n,) coordinate arrays (no (n, 3) copy of
            a dense map is then made), written as float32 x y z.
        rgb: (n, 3) uint8 colours, written as uchar red green blue.
        comment: one header comment line (no newlines).
        properties: further per-vertex properties by name, in order, each (n,) with the
            dtype it is written as (e.g. uint8 -> uchar, int32 -> int).

    Returns:
        The PLY bytes (same inputs, same bytes).
    """
    from plyfile import PlyData, PlyElement

    if isinstance(xyz_m, tuple):
        coords = [np.asarray(c, dtype=np.float64).reshape(-1) for c in xyz_m]
    else:
        xyz = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
        coords = [xyz[:, i] for i in range(3)]
    n = len(coords[0])
    colours = np.asarray(rgb, dtype=np.uint8).reshape(-1, 3)
    extra = {k: np.asarray(v).reshape(-1) for k, v in (properties or {}).items()}
    if any(len(c) != n for c in coords) or len(colours) != n:
        raise ValueError(f"{n} points but {len(colours)} colours")
    if any(len(v) != n for v in extra.values()):
        raise ValueError(f"{n} points but a property of another length")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1")]
    fields += [("blue", "u1"), *((k, v.dtype.newbyteorder("<").str) for k, v in extra.items())]
    rows = np.empty(n, dtype=np.dtype(fields))
    for name, c in zip(("x", "y", "z"), coords, strict=True):
        rows[name] = c
    for i, name in enumerate(("red", "green", "blue")):
        rows[name] = colours[:, i]
    for name, v in extra.items():
        rows[name] = v
    out = io.BytesIO()
    vertex = PlyElement.describe(rows, "vertex")
    PlyData([vertex], text=False, byte_order="<", comments=[comment]).write(out)
    return out.getvalue()


@dataclass
class _Element:
    name: str
    count: int
    scalars: list[tuple[str, str]] = field(default_factory=list)
    list_prop: tuple[str, str, str] | None = None  # (name, count type, index type)


def _parse_header(data: bytes) -> tuple[str, list[_Element], int]:
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError("not a PLY file (missing 'ply' magic or 'end_header')")
    body_start = data.index(b"\n", end) + 1
    fmt = ""
    elements: list[_Element] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines():
        words = line.split()
        if not words or words[0] in ("comment", "obj_info", "ply"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append(_Element(words[1], int(words[2])))
        elif words[0] == "property" and words[1] == "list":
            elements[-1].list_prop = (words[4], _PLY_TYPES[words[2]], _PLY_TYPES[words[3]])
        elif words[0] == "property":
            elements[-1].scalars.append((words[2], _PLY_TYPES[words[1]]))
    if fmt not in ("binary_little_endian", "ascii"):
        raise ValueError(f"PLY format {fmt!r} not supported (binary_little_endian, ascii)")
    return fmt, elements, body_start


def _element_dtype(el: _Element) -> np.dtype:
    fields = [(n, "<" + t) for n, t in el.scalars]
    if el.list_prop is not None:
        name, count_t, index_t = el.list_prop
        fields += [("__n", "<" + count_t), (name, "<" + index_t, (3,))]
    return np.dtype(fields)


def _read_binary(data: bytes, elements: list[_Element], offset: int) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for el in elements:
        dt = _element_dtype(el)
        arr = np.frombuffer(data, dtype=dt, count=el.count, offset=offset)
        if el.list_prop is not None and el.count and np.any(arr["__n"] != 3):
            raise ValueError(f"PLY element {el.name!r}: only triangles are supported")
        out[el.name] = arr
        offset += dt.itemsize * el.count
    return out


def _read_ascii(data: bytes, elements: list[_Element], offset: int) -> dict[str, np.ndarray]:
    lines = data[offset:].decode("ascii").split("\n")
    out: dict[str, np.ndarray] = {}
    start = 0
    for el in elements:
        block = " ".join(lines[start : start + el.count])
        start += el.count
        width = len(el.scalars) + (4 if el.list_prop is not None else 0)
        values = np.array(block.split(), dtype=np.float64).reshape(el.count, width)
        dt = _element_dtype(el)
        arr = np.empty(el.count, dtype=dt)
        for i, (name, _) in enumerate(el.scalars):
            arr[name] = values[:, i]
        if el.list_prop is not None:
            if el.count and np.any(values[:, len(el.scalars)] != 3):
                raise ValueError(f"PLY element {el.name!r}: only triangles are supported")
            arr[el.list_prop[0]] = values[:, len(el.scalars) + 1 :]
        out[el.name] = arr
    return out


def decode_mesh_ply(data: bytes) -> Mesh:
    """Parse a triangle-mesh PLY (binary little-endian or ASCII) from bytes.

    Returns:
        `Mesh` with vertices from the vertex element's x y z, triangles from the face
        element's list property (vertex_indices or vertex_index), and every other
        vertex property by name.
    """
    fmt, elements, offset = _parse_header(bytes(data))
    arrays = (_read_binary if fmt == "binary_little_endian" else _read_ascii)(
        bytes(data), elements, offset
    )
    if "vertex" not in arrays:
        raise ValueError("PLY has no vertex element")
    vertex = arrays["vertex"]
    xyz = np.stack([vertex[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
    props = {
        n: np.asarray(vertex[n]).copy()
        for n in vertex.dtype.names or ()
        if n not in ("x", "y", "z")
    }
    faces = arrays.get("face")
    tris = np.empty((0, 3), dtype=np.int64)
    if faces is not None and faces.dtype.names:
        name = next(n for n in faces.dtype.names if n != "__n")
        tris = np.asarray(faces[name], dtype=np.int64).reshape(-1, 3)
    if tris.size and (tris.min() < 0 or tris.max() >= len(xyz)):
        raise ValueError("PLY face indices outside the vertex table")
    return Mesh(xyz, tris, props)

"""PLY files of geometry: writing a coloured triangle mesh, reading a point set or a mesh.

The written layout is the one ``shared/CONVENTIONS.md`` asks of a mesh for Blender, MeshLab and
trimesh: binary little-endian, vertex ``x y z`` (float) and ``red green blue`` (uchar), faces as
``list uchar int vertex_indices``. The reader takes what other tools write too (ASCII or binary of
either byte order, doubles, extra properties, polygons with more than three corners).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from nerf_core.contract.paths import file_problem
from nerf_core.utils.atomic import atomic_file

_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
          "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


class GeometryFileError(ValueError):
    """A geometry file that is not a point set or a mesh this reader understands (the message names it)."""


@dataclass
class Geometry:
    """What a PLY file holds: points (n, 3) float64, normals (n, 3) or None, colours (n, 3) uint8 or
    None, triangles (f, 3) int64 or None (a point set)."""

    points: np.ndarray
    normals: Optional[np.ndarray] = None
    colors: Optional[np.ndarray] = None
    faces: Optional[np.ndarray] = None


def write_mesh_ply(path: Path | str, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray) -> None:
    """Write a coloured triangle mesh as binary little-endian PLY, atomically (a partial file never
    replaces ``path``).

    Args:
        path: the file to write.
        vertices: (n, 3) positions (written as float32).
        faces: (f, 3) vertex indices (written as int32).
        colors: (n, 3) uint8 vertex colours.
    """
    vertices, faces = np.asarray(vertices), np.asarray(faces)
    n, f = len(vertices), len(faces)
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by nerf_core export mesh\n"
              f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\n"
              f"element face {f}\nproperty list uchar int vertex_indices\nend_header\n").encode("ascii")
    vrec = np.empty(n, dtype=[("p", "<f4", 3), ("c", "u1", 3)])
    vrec["p"], vrec["c"] = vertices, colors
    frec = np.empty(f, dtype=[("k", "u1"), ("i", "<i4", 3)])
    frec["k"], frec["i"] = 3, faces
    with atomic_file(path) as fh:
        fh.write(header)
        fh.write(vrec.tobytes())
        fh.write(frec.tobytes())


def _header(fh, where: str) -> tuple[str, list]:
    """(format, [(element name, count, [(property name, dtype | (count dtype, item dtype))])])."""
    if fh.readline().strip() != b"ply":
        raise GeometryFileError(f"{where}: not a PLY file (it does not start with 'ply')")
    fmt, elements = None, []
    while True:
        line = fh.readline()
        if not line:
            raise GeometryFileError(f"{where}: the PLY header has no 'end_header'")
        words = line.decode("ascii", "replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                elements.append((words[1], int(words[2]), []))
            elif words[0] == "property" and words[1] == "list":
                elements[-1][2].append((words[4], (_TYPES[words[2]], _TYPES[words[3]])))
            elif words[0] == "property":
                elements[-1][2].append((words[2], _TYPES[words[1]]))
        except (IndexError, KeyError, ValueError):
            raise GeometryFileError(f"{where}: unreadable PLY header line {line.strip()[:80]!r}") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise GeometryFileError(f"{where}: unknown PLY format {fmt!r}")
    return fmt, elements


def _read_binary(fh, count: int, props: list, order: str, where: str, name: str):
    """One element's rows: a structured array, or for a single list property an object list."""
    if all(isinstance(t, str) for _, t in props):
        dt = np.dtype([(p, order + t) for p, t in props])
        data = np.frombuffer(fh.read(dt.itemsize * count), dtype=dt)
        if len(data) != count:
            raise GeometryFileError(f"{where}: the file ends inside element {name!r}")
        return data
    if len(props) == 1:  # faces: try the common all-triangles layout in one read, else row by row
        cnt_t, item_t = props[0][1]
        start = fh.tell()
        dt = np.dtype([("k", order + cnt_t), ("i", order + item_t, 3)])
        data = np.frombuffer(fh.read(dt.itemsize * count), dtype=dt)
        if len(data) == count and np.all(data["k"] == 3):
            return [row for row in data["i"]]
        fh.seek(start)
        rows = []
        cs, isz = np.dtype(order + cnt_t), np.dtype(order + item_t)
        for _ in range(count):
            raw = fh.read(cs.itemsize)
            if len(raw) != cs.itemsize:
                raise GeometryFileError(f"{where}: the file ends inside element {name!r}")
            k = int(np.frombuffer(raw, cs)[0])
            rows.append(np.frombuffer(fh.read(isz.itemsize * k), isz))
        return rows
    raise GeometryFileError(f"{where}: element {name!r} mixes list and scalar properties, which this reader skips")


def _triangles(rows, n_points: int, where: str) -> np.ndarray:
    """Polygons (lists of indices) -> (f, 3) int64 triangles (fans), indices checked."""
    tris = []
    for r in rows:
        r = np.asarray(r, dtype=np.int64)
        for k in range(1, len(r) - 1):
            tris.append((r[0], r[k], r[k + 1]))
    faces = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= n_points):
        raise GeometryFileError(f"{where}: a face names a vertex outside 0..{n_points - 1}")
    return faces


def read_geometry(path: Path | str) -> Geometry:
    """A point set or a mesh from a PLY file (``points3d.ply`` of a capture, or a mesh).

    Raises:
        GeometryFileError: a missing or unreadable file, not a PLY, no vertex element with x y z,
            no points, or non-finite positions (the message names the file).
    """
    where = str(path)
    problem = file_problem(path)
    if problem:
        raise GeometryFileError(f"{where}: {problem}")
    if os.path.getsize(path) == 0:
        raise GeometryFileError(f"{where}: the file is empty; expected a PLY point set or mesh")
    with open(path, "rb") as fh:
        fmt, elements = _header(fh, where)
        data = {}
        if fmt == "ascii":
            rest = fh.read().decode("ascii", "replace").split("\n")
            pos = 0
            for name, count, props in elements:
                rows = [ln.split() for ln in rest[pos:pos + count]]
                pos += count
                data[name] = rows
        else:
            order = "<" if fmt == "binary_little_endian" else ">"
            for name, count, props in elements:
                data[name] = _read_binary(fh, count, props, order, where, name)
    vertex = next(((c, p) for n, c, p in elements if n == "vertex"), None)
    names = [p for p, _ in vertex[1]] if vertex else []
    if vertex is None or not {"x", "y", "z"} <= set(names):
        raise GeometryFileError(f"{where}: no 'vertex' element with x, y, z: not a point set or a mesh")
    if vertex[0] == 0:
        raise GeometryFileError(f"{where}: the file holds no points")
    if fmt == "ascii":
        try:
            table = np.asarray([[float(v) for v in r[:len(names)]] for r in data["vertex"]], dtype=np.float64)
            cols = {p: table[:, i] for i, p in enumerate(names)}
        except (ValueError, IndexError):
            raise GeometryFileError(f"{where}: unreadable ASCII vertex rows") from None
        face_rows = [[int(v) for v in r[1:1 + int(r[0])]] for r in data.get("face", []) if r]
    else:
        cols = {p: data["vertex"][p].astype(np.float64) for p in names}
        face_rows = data.get("face", None)
    points = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
    if not np.isfinite(points).all():
        raise GeometryFileError(f"{where}: some vertex positions are not finite numbers")
    normals = np.stack([cols[k] for k in ("nx", "ny", "nz")], axis=1) if {"nx", "ny", "nz"} <= set(cols) else None
    colors = None
    if {"red", "green", "blue"} <= set(cols):
        colors = np.clip(np.stack([cols[k] for k in ("red", "green", "blue")], axis=1), 0, 255).astype(np.uint8)
    faces = _triangles(face_rows, len(points), where) if face_rows is not None and len(face_rows) else None
    return Geometry(points, normals, colors, faces)

"""PLY files of geometry: writing a coloured triangle mesh, reading a point set or a mesh.

The written layout is the one ``shared/CONVENTIONS.md`` asks of a mesh for Blender, MeshLab and
trimesh: binary little-endian, vertex ``x y z`` (float) and ``red green blue`` (uchar), faces as
``list uchar int vertex_indices``. The reader takes what other tools write too (ASCII or binary of
either byte order, doubles, extra properties, polygons with more than three corners, MeshLab's per-face
colours); the format's own checks are ``ply_format``'s.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from nerf_core.contract.paths import file_problem
from nerf_core.export.ply_format import GeometryFileError, parse_header, read_elements
from nerf_core.utils.atomic import atomic_file

__all__ = ["Geometry", "GeometryFileError", "read_geometry", "write_mesh_ply"]


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


def _column(table: dict, name: str, where: str, element: str) -> np.ndarray:
    """A scalar property's values as float64 (a list where a number belongs is refused)."""
    col = table[name]
    if isinstance(col, list) or (isinstance(col, np.ndarray) and col.ndim != 1):
        raise GeometryFileError(f"{where}: property {name!r} of element {element!r} is a list; expected one number")
    return np.asarray(col, dtype=np.float64)


def _face_lists(faces: dict, where: str):
    """The vertex index lists of a ``face`` element (``vertex_indices``, or ``vertex_index`` as some tools
    name it); its other properties (MeshLab's per-face colours) are not read."""
    name = next((n for n in ("vertex_indices", "vertex_index") if n in faces), None)
    if name is None:
        raise GeometryFileError(f"{where}: element 'face' has no 'vertex_indices' list")
    rows = faces[name]
    if isinstance(rows, np.ndarray) and rows.ndim == 1:
        raise GeometryFileError(f"{where}: property {name!r} of element 'face' is one number; expected a list")
    return rows


def _triangles(rows, n_points: int, where: str) -> np.ndarray:
    """Polygons (a (f, k) array or a list of index arrays) -> (f', 3) int64 triangles (fans), checked:
    whole indices of existing vertices."""
    if isinstance(rows, np.ndarray):  # (f, k): every polygon of k corners
        lens, flat = np.full(len(rows), rows.shape[1] if rows.ndim == 2 else 0), rows.reshape(-1)
    else:
        lens = np.asarray([len(r) for r in rows], dtype=np.int64)
        flat = np.concatenate([np.asarray(r).reshape(-1) for r in rows]) if len(rows) else np.empty(0)
    # polygon r of k corners -> (c0, c1, c2), (c0, c2, c3), ...: in file order, as a fan per polygon
    starts = np.cumsum(lens) - lens
    per = np.clip(lens - 2, 0, None)
    owner = np.repeat(np.arange(len(lens)), per)
    j = np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per) + 1
    first = starts[owner]
    faces = np.stack([flat[first], flat[first + j], flat[first + j + 1]], axis=1) if len(owner) else np.empty((0, 3))
    if faces.size and not np.all(np.isfinite(faces) & (faces == np.round(faces))):
        raise GeometryFileError(f"{where}: element 'face' holds vertex indices that are not whole numbers")
    if faces.size and (faces.min() < 0 or faces.max() >= n_points):
        raise GeometryFileError(f"{where}: a face names a vertex outside 0..{n_points - 1} "
                                f"(it names {int(faces.min() if faces.min() < 0 else faces.max())})")
    return faces.astype(np.int64).reshape(-1, 3)


def read_geometry(path: Path | str) -> Geometry:
    """A point set or a mesh from a PLY file (``points3d.ply`` of a capture, or a mesh), ASCII or binary
    of either byte order; every claim of its header is checked against the file (``ply_format``).

    Raises:
        GeometryFileError: a missing or unreadable file, not a PLY, a header the file does not bear out,
            no vertex element with x y z, no points, or non-finite positions (one line naming the file
            and the element, row or header line).
    """
    where = str(path)
    problem = file_problem(path)
    if problem:
        raise GeometryFileError(f"{where}: {problem}")
    if os.path.getsize(path) == 0:
        raise GeometryFileError(f"{where}: the file is empty; expected a PLY point set or mesh")
    try:
        with open(path, "rb") as fh:
            header = parse_header(fh, where)
            body = fh.read()
    except OSError as exc:
        raise GeometryFileError(f"{where}: cannot be read ({exc.strerror or exc})") from None
    vertex = next((e for e in header.elements if e.name == "vertex"), None)
    names = [p.name for p in vertex.properties] if vertex else []
    if vertex is None or not {"x", "y", "z"} <= set(names):
        raise GeometryFileError(f"{where}: no 'vertex' element with x, y, z: not a point set or a mesh")
    if vertex.count == 0:
        raise GeometryFileError(f"{where}: the file holds no points")
    data = read_elements(body, header, where)
    table = data["vertex"]
    points = np.stack([_column(table, k, where, "vertex") for k in ("x", "y", "z")], axis=1)
    if not np.isfinite(points).all():
        raise GeometryFileError(f"{where}: some vertex positions are not finite numbers")
    normals = None
    if {"nx", "ny", "nz"} <= set(names):
        normals = np.stack([_column(table, k, where, "vertex") for k in ("nx", "ny", "nz")], axis=1)
    colors = None
    if {"red", "green", "blue"} <= set(names):
        rgb = np.stack([_column(table, k, where, "vertex") for k in ("red", "green", "blue")], axis=1)
        colors = np.clip(np.nan_to_num(rgb), 0, 255).astype(np.uint8)
    faces = None
    if "face" in data and next(e for e in header.elements if e.name == "face").count:
        faces = _triangles(_face_lists(data["face"], where), len(points), where)
        faces = faces if len(faces) else None
    return Geometry(points, normals, colors, faces)

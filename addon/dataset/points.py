"""The dataset's point cloud: pixels back-projected through depth, written as ``points3d.ply``."""
from __future__ import annotations

import numpy as np

from ..file_writes import write_atomic


def write_ply(path: str, points: np.ndarray, colors: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Binary little-endian PLY: float x y z, float nx ny nz (when ``normals`` is given), uchar red green blue.

    points, normals: (n, 3) float32; colors: (n, 3) uint8. The property order is the one 3D Gaussian
    Splatting's ``fetchPly`` reads (it needs the normals).
    """
    n = len(points)
    props = "property float x\nproperty float y\nproperty float z\n"
    fields = [("p", "<f4", 3)]
    if normals is not None:
        props += "property float nx\nproperty float ny\nproperty float nz\n"
        fields.append(("n", "<f4", 3))
    fields.append(("c", "u1", 3))
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {n}\n" + props +
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    ).encode("ascii")
    rec = np.empty(n, dtype=fields)
    rec["p"] = points
    if normals is not None:
        rec["n"] = normals
    rec["c"] = colors
    write_atomic(path, header + rec.tobytes())


def backproject(depth: np.ndarray, rgb: np.ndarray, intr: dict, c2w, stride: int = 1):
    """World points and colours of the pixels with finite depth.

    depth: (h, w) planar z (inf = none); rgb: (h, w, 3) uint8; c2w: 4x4 rows. Returns (n, 3) float32, (n, 3) uint8.
    """
    h, w = depth.shape
    j, i = np.mgrid[0:h:stride, 0:w:stride]
    z = depth[j, i]
    ok = np.isfinite(z) & (z > 0)
    i, j, z = i[ok], j[ok], z[ok]
    x = (i + 0.5 - intr["cx"]) / intr["fl_x"] * z
    y = -(j + 0.5 - intr["cy"]) / intr["fl_y"] * z
    cam = np.stack([x, y, -z, np.ones_like(z)], axis=1)
    world = cam @ np.asarray(c2w, float).T
    return world[:, :3].astype(np.float32), rgb[j, i]

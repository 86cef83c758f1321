"""A coloured triangle mesh of a trained field: marching cubes, culling, decimation, colours.

The rules, each stated once:

- **Surface level.** Where the training cameras' rays first meet the surface (transmittance 0.95
  over the few grid steps before each ray's surface, ``level.rendered_surface_level``), else where
  one grid step is 5 % opaque (``grid.iso_level``); ``level`` says why and compares. A lower level
  wraps the geometry in the faint haze a field keeps around surfaces; a higher one sinks it into the
  object. ``--level`` overrides it.
- **Enclosed space.** Empty space that no camera can reach (walled in by surface) is filled first
  (``fill_unseen_inside``), so a field that is a shell gives its outer face only.
- **Culling.** A vertex is kept when at least one training camera sees it: in its image, in front of
  it, and not behind the mesh's own nearer surface (``seen_by_cameras``). The field was never
  supervised anywhere else, and its density there is a guess. A face is kept
  when its three vertices are. Floaters: a connected piece whose area is under ``min_component`` (a
  share, default 0.5 %) of the whole mesh's area is dropped: haze that the training left in the air
  forms small closed blobs, the objects of a scene form large pieces.
- **Colour.** Each vertex takes the field's colour at its position seen head-on, along its inward
  normal: one query per vertex, no camera needed, and the view that shows a surface's own colour
  with the least of a highlight's grazing-angle shift. View-dependent effects are not baked in.
- **Decimation** (``--faces N``) runs before the colours, which are then read at the kept vertices.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np
import torch

from nerf_core.cameras.rays import Cameras, project_points
from nerf_core.contract.exports import MESH, option
from nerf_core.export import extra, grid
from nerf_core.export import level as surface_level
from nerf_core.utils.memory import available_memory, size_text

DEFAULT_MIN_COMPONENT = option(MESH, "min_component").default  # --min-component's, declared once
# Memory, measured with tracemalloc on foggy fields (nerf_core/tests/test_export_memory.py holds the
# budgets to it). Before sampling: the density grid (4 B a sample) and the filling of enclosed space
# (labels, masks and the sort inside ``np.isin``: 30 B at peak). Per cell that the surface crosses,
# known once the density is sampled: up to 3.4 faces on a white-noise fog, each about 300 B at the
# peak of floater removal and vertex normals (face corners in float64, the adjacency's indices).
BYTES_PER_SAMPLE = 4 + 32
BYTES_PER_CROSSED_CELL = 1200


class NoSurface(ValueError):
    """The density never crosses the surface level inside the box (the message names both)."""


@dataclass
class Mesh:
    """vertices (n, 3) float64 world positions, faces (f, 3) int64, colors (n, 3) uint8,
    normals (n, 3) float64 unit outward normals; ``info``: what was done (counts, level, resolution)."""

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    info: dict = field(default_factory=dict)


def marching_cubes(density: np.ndarray, box: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """The level set of a density grid (``grid`` layout) as world vertices (n, 3) and faces (f, 3),
    wound so that ``cross(v1 - v0, v2 - v0)`` points out of the dense side.

    Raises NoSurface when no sample pair straddles ``level``.
    """
    lo, hi = float(density.min()), float(density.max())
    if not lo < level < hi:
        raise NoSurface(f"no surface at density level {level:.4g} per scene unit: the density inside the box "
                        f"ranges over [{lo:.4g}, {hi:.4g}]" + ("; the run may not have trained yet, or pass a "
                                                               "lower --level" if hi <= level else ""))
    measure = extra.load("skimage.measure", "marching cubes (export mesh)")
    res = density.shape[0]
    verts, faces, _, _ = measure.marching_cubes(density, level=level, spacing=tuple(grid.spacing(box, res)),
                                                gradient_direction="descent", allow_degenerate=False)
    verts = verts.astype(np.float64) + box[0]
    faces = faces.astype(np.int64)
    # scikit-image winds its faces for the normal that points up the gradient's descent; check the
    # winding against the density instead of trusting a convention: outward = towards lower density.
    if len(faces) and _inward_share(verts, faces, density, box) > 0.5:
        faces = faces[:, ::-1].copy()
    return verts, faces


def crossing_cells(density: np.ndarray, level: float) -> int:
    """How many grid cells (8 neighbouring samples) straddle ``level``: the cells marching cubes puts
    faces in (at most 5 each, about 2 on a fog), counted slab by slab so that the count itself needs
    no grid-sized array."""
    res = density.shape[0]
    per_slab = max(2, (1 << 22) // max(1, density.shape[1] * density.shape[2]))
    n = 0
    for i0 in range(0, res - 1, per_slab - 1):
        above = density[i0:min(res, i0 + per_slab)] >= level
        every = above[:-1, :-1, :-1] & above[1:, :-1, :-1] & above[:-1, 1:, :-1] & above[:-1, :-1, 1:]
        some = above[:-1, :-1, :-1] | above[1:, :-1, :-1] | above[:-1, 1:, :-1] | above[:-1, :-1, 1:]
        for corner in ((1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1)):
            c = above[corner[0]:, corner[1]:, corner[2]:][:above.shape[0] - 1, :above.shape[1] - 1,
                                                         :above.shape[2] - 1]
            every &= c
            some |= c
        n += int(np.count_nonzero(some & ~every))
    return n


def check_surface_fits(cells: int, resolution: int, level: float, flag: str = "--resolution") -> None:
    """Refuse (ValueError naming ``flag``) a surface of ``cells`` crossed cells whose faces would not fit
    in the memory available (``BYTES_PER_CROSSED_CELL`` each, besides the grid), before marching cubes."""
    need = cells * BYTES_PER_CROSSED_CELL + float(resolution) ** 3 * 4
    avail = available_memory()
    if avail is not None and need > avail:
        raise ValueError(f"{flag} {resolution}: the surface at density level {level:.4g} crosses {cells} cells of "
                         f"the grid ({cells / (resolution - 1) ** 3:.0%}: a fog more than a surface), whose faces "
                         f"need about {size_text(need)} of memory and {size_text(avail)} is available; lower "
                         "the resolution, or pass a higher --level")


def _inward_share(verts, faces, density, box) -> float:
    """Share of faces whose geometric normal points towards higher density (sampled one voxel out)."""
    idx = np.linspace(0, len(faces) - 1, min(len(faces), 2000)).astype(np.int64)
    tri = verts[faces[idx]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)
    step = grid.spacing(box, density.shape[0])
    c = tri.mean(axis=1)

    def at(p):
        ijk = np.clip(np.rint((p - box[0]) / step).astype(np.int64), 0, density.shape[0] - 1)
        return density[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
    return float(np.mean(at(c + n * step) > at(c - n * step)))


def fill_unseen_inside(density: np.ndarray, box: np.ndarray, level: float,
                       viewpoints: Optional[np.ndarray] = None) -> tuple[np.ndarray, int]:
    """The density with every pocket of empty space that no viewpoint reaches raised above ``level``:
    (filled grid, samples raised).

    Empty space (below ``level``) is split into connected pieces; the pieces that touch the box's
    faces or hold a viewpoint (a training camera inside the box: a room seen from within) are the air
    the cameras look through. Every other piece is enclosed by surface, so no camera sees into it.
    A trained field is often a shell with a faint inside: without this, marching cubes would give the
    shell's inner face too, a second surface where nothing is seen.
    """
    ndimage = extra.load("scipy.ndimage", "export mesh (finding enclosed empty space)")
    empty = density < level
    labels, count = ndimage.label(empty)
    if count == 0:
        return density, 0
    outside = set(np.unique(np.concatenate([labels[0].ravel(), labels[-1].ravel(), labels[:, 0].ravel(),
                                            labels[:, -1].ravel(), labels[:, :, 0].ravel(),
                                            labels[:, :, -1].ravel()])).tolist())
    if viewpoints is not None and len(viewpoints):
        step = grid.spacing(box, density.shape[0])
        ijk = np.rint((np.asarray(viewpoints) - box[0]) / step).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < density.shape[0]), axis=1)
        outside |= set(labels[ijk[inside, 0], ijk[inside, 1], ijk[inside, 2]].tolist())
    outside.discard(0)
    enclosed = empty & ~np.isin(labels, sorted(outside))
    n = int(np.count_nonzero(enclosed))
    if n:
        density = density.copy()
        density[enclosed] = 2.0 * level
    return density, n


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals (n, 3): the area-weighted mean of the adjacent faces' normals."""
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area: area-weighted
    vn = np.zeros_like(verts)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    return vn / np.linalg.norm(vn, axis=1, keepdims=True).clip(1e-12)


def _pixels_and_depth(cameras: Cameras, view: int, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``pts`` (n, 3) float32 seen from ``view``: u (n,), v (n,) in pixels and the z-depth (n,), float32
    (``project_points``'s convention; u and v are only meaningful where the depth is > 0).

    A pinhole view is one (n, 3) x (3, 3) product into (u z, v z, z) and two divisions, in float32
    numpy: at 256^3 (a million vertices, 100 cameras) this is most of the culling's time, and
    ``project_points``' torch path costs three times as much. Views with lens distortion take it.
    """
    if cameras.dist is not None:
        uv, depth = project_points(cameras, view, torch.from_numpy(pts))
        return uv[:, 0].numpy(), uv[:, 1].numpy(), depth.numpy()
    c2w = cameras.c2w[view].double().numpy()
    rot, origin = c2w[:3, :3], c2w[:3, 3]
    fx, fy, cx, cy = (float(k[view]) for k in (cameras.fx, cameras.fy, cameras.cx, cameras.cy))
    # camera coordinates are rot^T (X - origin); OpenGL looks down -z, and image v grows downwards
    to_pixels = np.stack([fx * rot[:, 0] - cx * rot[:, 2], -fy * rot[:, 1] - cy * rot[:, 2], -rot[:, 2]], axis=1)
    p = pts @ to_pixels.astype(np.float32) + (-(origin @ to_pixels)).astype(np.float32)
    depth = p[:, 2]
    safe = np.where(depth > 0, depth, np.float32(1.0))
    return p[:, 0] / safe, p[:, 1] / safe, depth


def seen_by_cameras(points: np.ndarray, cameras: Cameras, voxel: Optional[float] = None) -> np.ndarray:
    """(n,) bool: the points (n, 3) that at least one camera has inside its image, in front of it and,
    with ``voxel`` (the grid step, scene units), not hidden behind other points.

    Occlusion is a z-buffer of the points themselves, in cells of about two point spacings on the
    image (``2 f voxel / depth`` pixels at the median depth, at least one), so that a surface's own
    points leave no gaps for the points behind it; a point is seen when it lies within three voxels
    of its cell's nearest point. Without ``voxel``: the frustum alone. Float32 throughout.
    """
    pts = np.ascontiguousarray(points, dtype=np.float32)
    seen = np.zeros(len(points), dtype=bool)
    for v in range(len(cameras)):
        u, row, depth = _pixels_and_depth(cameras, v, pts)
        w, h = float(cameras.width[v]), float(cameras.height[v])
        inside = (depth > 0) & (u >= 0) & (u < w) & (row >= 0) & (row < h)
        if voxel is None:
            seen |= inside
            continue
        idx = np.flatnonzero(inside)
        if not len(idx):
            continue
        z = depth[idx]
        # every 16th point's depth is median enough for a cell size (and a tenth of the work)
        cell = max(1.0, 2.0 * float(cameras.fx[v]) * voxel / float(np.median(z[::16])))
        cols = int(math.ceil(w / cell))
        inv = np.float32(1.0 / cell)  # u, row >= 0 here, so truncation is the floor, and far cheaper than //
        key = (row[idx] * inv).astype(np.int64) * cols + (u[idx] * inv).astype(np.int64)
        zbuf = np.full(int(math.ceil(h / cell)) * cols, np.inf, dtype=np.float32)
        np.minimum.at(zbuf, key, z)
        seen[idx[z <= zbuf[key] + np.float32(3.0 * voxel)]] = True
    return seen


def keep_vertices(verts: np.ndarray, faces: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The faces whose three vertices are all in ``keep`` (n,) bool, and only the vertices they use."""
    faces = faces[keep[faces].all(axis=1)]
    used = np.zeros(len(verts), dtype=bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    return verts[used], remap[faces]


def face_areas(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = verts[faces]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def drop_small_pieces(verts: np.ndarray, faces: np.ndarray, min_share: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Remove connected pieces whose area is under ``min_share`` of the total: (verts, faces, pieces dropped)."""
    if min_share <= 0 or not len(faces):
        return verts, faces, 0
    csgraph = extra.load("scipy.sparse.csgraph", "floater removal (export mesh)")
    sparse = extra.load("scipy.sparse", "floater removal (export mesh)")
    a, b = np.concatenate([faces[:, 0], faces[:, 1]]), np.concatenate([faces[:, 1], faces[:, 2]])
    adj = sparse.coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(len(verts), len(verts)))
    n_pieces, label = csgraph.connected_components(adj, directed=False)
    piece_area = np.bincount(label[faces[:, 0]], weights=face_areas(verts, faces), minlength=n_pieces)
    small = piece_area < min_share * piece_area.sum()
    keep = ~small[label]
    v, f = keep_vertices(verts, faces, keep)
    return v, f, int(np.count_nonzero(small & (piece_area > 0)))


def decimate(verts: np.ndarray, faces: np.ndarray, n_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """About ``n_faces`` faces by quadric edge collapse (fast-simplification); unchanged when already fewer."""
    if len(faces) <= n_faces:
        return verts, faces
    fs = extra.load("fast_simplification", "--faces (decimation)")
    v, f = fs.simplify(verts.astype(np.float32), faces.astype(np.int64), target_reduction=1.0 - n_faces / len(faces))
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def extract_mesh(model, box: np.ndarray, resolution: int, level: Optional[float] = None,
                 n_faces: Optional[int] = None, cameras: Optional[Cameras] = None,
                 min_component: float = DEFAULT_MIN_COMPONENT, fill_inside: bool = True,
                 on_progress: Optional[Callable[[str, float], None]] = None) -> Mesh:
    """The coloured mesh of ``model`` inside ``box`` (2, 3), by the rules of this module.

    Args:
        model: a trained RadianceModel (read through ``export.field``).
        box: (2, 3) float64 [min corner, max corner] in scene units.
        resolution: samples per axis of the density grid.
        level: surface density per scene unit; None: ``level.rendered_surface_level`` through
            ``cameras``, else ``grid.iso_level``.
        n_faces: decimate to about this many faces; None: keep all.
        cameras: the training cameras for culling; None: no camera culling.
        min_component: floater rule, a share of the total area (0: keep every piece).
        fill_inside: raise enclosed empty space above the level first (``fill_unseen_inside``).
        on_progress: called with (stage, share done in [0, 1]).

    Raises:
        NoSurface: nothing crosses the level; extra.MissingExtra: the mesh extra is missing.
    """
    say = on_progress or (lambda stage, share: None)
    rule = "given"
    if level is None and cameras is not None:
        say("level", 0.0)
        level, rule = surface_level.rendered_surface_level(model, cameras, box), "first contact of training rays"
    if level is None:
        level, rule = grid.iso_level(box, resolution), "one grid step 5 % opaque"
    level = float(level)
    density = grid.sample_density(model, box, resolution, lambda s: say("density", s))
    info = {
        "resolution": resolution,
        "level": level,
        "level_rule": rule,
        "density_range": [float(density.min()), float(density.max())],
    }
    lo, hi = info["density_range"]
    if fill_inside and lo < level < hi:
        say("filling", 0.0)
        viewpoints = cameras.c2w[:, :3, 3].double().numpy() if cameras is not None else None
        density, info["enclosed_samples_filled"] = fill_unseen_inside(density, box, level, viewpoints)
    if lo < level < hi:
        check_surface_fits(crossing_cells(density, level), resolution, level)
    verts, faces = marching_cubes(density, box, level)
    info["faces_extracted"] = int(len(faces))
    del density
    say("culling", 0.0)
    if cameras is not None:
        voxel = float(grid.spacing(box, resolution).mean())
        verts, faces = keep_vertices(verts, faces, seen_by_cameras(verts, cameras, voxel))
        info["faces_unseen_culled"] = info["faces_extracted"] - int(len(faces))
    before = len(faces)
    verts, faces, dropped = drop_small_pieces(verts, faces, min_component)
    info.update(floaters_dropped=dropped, floater_faces_culled=before - int(len(faces)))
    if not len(faces):
        raise NoSurface(f"no surface left at density level {level:.4g} after culling what no training camera sees "
                        "and floaters")
    if n_faces is not None:
        say("decimating", 0.0)
        verts, faces = decimate(verts, faces, n_faces)
    normals = vertex_normals(verts, faces)
    say("colour", 0.0)
    rgb = grid.colour_at(model, verts, -normals)
    colors = np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)
    info.update(vertices=int(len(verts)), faces=int(len(faces)))
    return Mesh(verts, faces, colors, normals, info)

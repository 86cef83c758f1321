"""How far a mesh lies from the scene's own surfaces, after the Tanks and Temples and DTU practice.

Both sides become point sets: a mesh is sampled on its surface (area-weighted, a fixed seed), a point
set (``points3d.ply`` of a capture) is taken as it is; each side is thinned to at most ``max_points``.
With ``d(a, B)`` the distance from a point of one side to the nearest point of the other:

- precision: share of the NeRF's points with ``d(p, truth) < tau``; recall: share of the truth's
  points with ``d(t, NeRF) < tau``; F-score ``2PR / (P + R)``;
- Chamfer-L1: the mean of the two mean distances (DTU's (accuracy + completeness) / 2);
- normal consistency, where both sides have normals: the mean ``|n . n_nearest|`` both ways.

``tau`` is a share of the truth's bounding-box diagonal (``tau_share``; 0.01 by default). Recall
counts only truth the training cameras saw: a capture's ``points3d.ply`` is back-projected from the
training views, so all of it was; a truth mesh is cut to its points in some training camera's image
when cameras are given.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from nerf_core.cameras.rays import Cameras
from nerf_core.export import extra
from nerf_core.export.mesh import face_areas, seen_by_cameras, vertex_normals
from nerf_core.export.ply import Geometry
from nerf_core.utils.arguments import integer, number

MAX_POINTS = 200_000
# The most points a side (``--max-points``): about 500 bytes a point while both sides are sampled and
# searched, so 5 GB at the limit; past a few million points the scores no longer move.
MAX_POINTS_LIMIT = 10_000_000
BYTES_PER_POINT = 500


def truth_problem(truth: Geometry) -> Optional[str]:
    """Why ``truth`` cannot be scored against, or None. ``tau`` is a share of the truth's bounding-box
    diagonal: a truth whose points all lie at one place (one point) has none, and every distance would
    count as a miss, scoring any mesh 0."""
    diag = float(np.linalg.norm(truth.points.max(axis=0) - truth.points.min(axis=0)))
    if not (np.isfinite(diag) and diag > 0):
        n = len(truth.points)
        held = "it holds one point" if n == 1 else f"its {n} points all lie at one place"
        return (f"{held}, which spans no bounding box; tau is a share of the truth's bounding-box diagonal, so "
                "there is nothing to score against (use a truth of the scene's surfaces, such as a capture's "
                "points3d.ply)")
    return None


def surface_points(geo: Geometry, n: int, seed: int = 0) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """Points (m, 3) and unit normals (m, 3) or None standing for a geometry: ``n`` area-weighted samples
    of a mesh's surface (face normals), or at most ``n`` of a point set's points (their normals if any)."""
    rng = np.random.default_rng(seed)
    if geo.faces is not None and len(geo.faces):
        areas = face_areas(geo.points, geo.faces)
        if areas.sum() > 0:
            f = rng.choice(len(geo.faces), size=n, p=areas / areas.sum())
            r1, r2 = rng.random(n), rng.random(n)
            s = np.sqrt(r1)
            tri = geo.points[geo.faces[f]]
            pts = (1 - s)[:, None] * tri[:, 0] + (s * (1 - r2))[:, None] * tri[:, 1] + (s * r2)[:, None] * tri[:, 2]
            fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            return pts, fn / np.linalg.norm(fn, axis=1, keepdims=True).clip(1e-12)
    pts, normals = geo.points, geo.normals
    if normals is None and geo.faces is not None and len(geo.faces):
        normals = vertex_normals(pts, geo.faces)
    if len(pts) > n:
        pick = rng.choice(len(pts), size=n, replace=False)
        pts, normals = pts[pick], (normals[pick] if normals is not None else None)
    if normals is not None:
        norm = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.where(norm > 1e-12, normals / norm.clip(1e-12), np.nan)
    return pts, normals


def score(pred: Geometry, truth: Geometry, tau_share: float = 0.01, cameras: Optional[Cameras] = None,
          max_points: int = MAX_POINTS, seed: int = 0) -> dict:
    """Precision, recall, F-score, Chamfer-L1 and normal consistency of ``pred`` against ``truth``.

    Raises:
        ValueError: ``max_points`` outside 1..MAX_POINTS_LIMIT, ``tau_share`` outside (0, 1], a truth that
            spans no bounding box (``truth_problem``), or one that no camera sees.

    Returns a dict: ``precision``, ``recall``, ``fscore`` (shares in [0, 1]), ``chamfer`` (scene units),
    ``tau`` (scene units), ``tau_share``, ``accuracy`` and ``completeness`` (the two mean distances),
    ``normal_consistency`` (None without normals on both sides), ``n_pred``, ``n_truth``.
    """
    max_points = integer("score", "max_points", max_points, low=1, high=MAX_POINTS_LIMIT)
    tau_share = number("score", "tau_share", tau_share, above=0, high=1)
    problem = truth_problem(truth)
    if problem:
        raise ValueError(f"the truth: {problem}")
    spatial = extra.load("scipy.spatial", "score-mesh (nearest neighbours)")
    p, pn = surface_points(pred, max_points, seed)
    t, tn = surface_points(truth, max_points, seed + 1)
    if cameras is not None:
        seen = seen_by_cameras(t, cameras)  # the frustum: a truth's points need no z-buffer of a guess
        t, tn = t[seen], (tn[seen] if tn is not None else None)
        if not len(t):
            raise ValueError("no point of the truth lies in any training camera's image")
    diag = float(np.linalg.norm(truth.points.max(axis=0) - truth.points.min(axis=0)))
    tau = tau_share * diag
    d_pt, i_pt = spatial.cKDTree(t).query(p, workers=-1)
    d_tp, i_tp = spatial.cKDTree(p).query(t, workers=-1)
    precision, recall = float(np.mean(d_pt < tau)), float(np.mean(d_tp < tau))
    fscore = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    nc = None
    if pn is not None and tn is not None:
        both = np.concatenate([np.abs(np.sum(pn * tn[i_pt], axis=1)), np.abs(np.sum(tn * pn[i_tp], axis=1))])
        both = both[np.isfinite(both)]
        nc = float(both.mean()) if len(both) else None
    acc, comp = float(d_pt.mean()), float(d_tp.mean())
    return {"precision": precision, "recall": recall, "fscore": fscore, "chamfer": 0.5 * (acc + comp),
            "tau": tau, "tau_share": tau_share, "accuracy": acc, "completeness": comp,
            "normal_consistency": nc, "n_pred": int(len(p)), "n_truth": int(len(t)), "truth_diagonal": diag}

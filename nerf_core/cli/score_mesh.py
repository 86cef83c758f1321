"""``python -m nerf_core score-mesh MESH --truth points3d.ply``: precision, recall, F-score and
Chamfer-L1 of a mesh against the scene's own surfaces (``nerf_core.export.score``); the last line of
stdout is JSON."""
from __future__ import annotations

import json
import math

from nerf_core.cli.options import checked_number
from nerf_core.data.loading import load_cameras
from nerf_core.export.ply import read_geometry
from nerf_core.export.score import BYTES_PER_POINT, MAX_POINTS, MAX_POINTS_LIMIT, score, truth_problem

tau_share = checked_number(float, "a number", lambda v: 0 < v < 1, "must lie in (0, 1)")


def _whole(text: str) -> int:
    """An integer written as one (``200000``) or as a whole number in exponent form (``2e5``)."""
    try:
        return int(text)
    except ValueError:
        v = float(text)  # a ValueError here is the flag's "expected ..." message
        if not (math.isfinite(v) and v == int(v)):
            raise ValueError(text) from None
        return int(v)


max_points = checked_number(_whole, "a whole number of points", lambda v: 1 <= v <= MAX_POINTS_LIMIT,
                            f"must lie in 1..{MAX_POINTS_LIMIT} (about {BYTES_PER_POINT} bytes of memory a point: "
                            f"{MAX_POINTS_LIMIT * BYTES_PER_POINT / 1e9:.0f} GB at the limit; the scores stop moving "
                            "long before)")


def add_parser(sub, fmt) -> None:
    """Add the subcommand to ``sub`` (argparse subparsers); ``fmt``: the help formatter class."""
    s = sub.add_parser("score-mesh", help="how far a mesh lies from the truth (F-score, Chamfer)", formatter_class=fmt,
                       description="Precision (mesh -> truth), recall (truth -> mesh) at tau, their F-score, "
                                   "Chamfer-L1 and normal consistency. The last line of stdout is JSON.")
    s.add_argument("mesh", metavar="MESH", help="the mesh (or point set) to score, a PLY file")
    s.add_argument("--truth", required=True, metavar="PLY",
                   help="the truth: a capture's points3d.ply or a mesh (PLY)")
    s.add_argument("--tau", type=tau_share, action="append", metavar="SHARE",
                   help="distance threshold as a share of the truth's bounding-box diagonal (default 0.01); "
                        "repeat for several: the first one's scores are the top-level keys")
    s.add_argument("--cameras", metavar="DATASET",
                   help="count only truth inside some training camera's image (a dataset folder or transforms file)")
    s.add_argument("--max-points", type=max_points, default=MAX_POINTS, metavar="N",
                   help=f"points sampled per side (at most {MAX_POINTS_LIMIT})")
    s.set_defaults(handler=run)


def run(a) -> int:
    pred = read_geometry(a.mesh)
    truth = read_geometry(a.truth)
    problem = truth_problem(truth)
    if problem:  # before the cameras are loaded: named by the file
        raise ValueError(f"--truth {a.truth}: {problem}")
    cams = load_cameras(a.cameras, "train")[0] if a.cameras else None
    taus = a.tau or [0.01]
    try:
        results = [score(pred, truth, tau_share=t, cameras=cams, max_points=a.max_points) for t in taus]
    except ValueError as exc:  # what the truth cannot give (no point in any camera's image): named by the file
        raise ValueError(f"--truth {a.truth}: {exc}") from None
    out = dict(results[0])
    if len(results) > 1:
        out["by_tau"] = [{k: r[k] for k in ("tau_share", "tau", "precision", "recall", "fscore")} for r in results]
    print(json.dumps({"mesh": a.mesh, "truth": a.truth, **out}))
    return 0

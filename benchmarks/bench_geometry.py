"""Geometry benchmark: how far the exported mesh lies from the scene's own surfaces, against training time.

    python benchmarks/bench_geometry.py run --dataset DS --method vmgrid --seconds 300 --out DIR [--every 250]
    python benchmarks/bench_geometry.py report DIR
    python benchmarks/bench_geometry.py picture --mesh MESH.ply --truth DS/points3d.ply --out PICTURE.png

``run`` trains ``METHOD`` on dataset DS (a capture made with ``--points``: its ``points3d.ply`` is the
truth) for ``--seconds`` of training time, one thread, keeping a checkpoint every ``--every`` steps.
Then, for each checkpoint, ``export mesh`` (default flags) and ``score-mesh`` at tau = 0.5 % and 1 % of
the truth's diagonal; on the last checkpoint also the surface level against alternatives (x 1/4, x 4,
x 16 the default), the mesh without culling (``--no-variants`` skips these), a 256^3 extraction's time
(``--no-256`` skips it; minutes for nerf), and ``eval`` on 5 test views (PSNR, depth_mae, depth_rel).
The last checkpoint's mesh is the final one. Writes DIR/<scene>_<method>.json.

``report`` draws DIR/geometry.png (F-score against training time: one panel per scene, four a row, one
colour per method) and prints Markdown tables of the results. Two ``run``s can go side by side (one core
each). ``picture`` draws a mesh beside the captured surface, its faces coloured by their distance to it.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.join(os.path.dirname(HERE), "scripts")]  # _bootstrap in scripts/
import _bootstrap  # noqa: E402,F401  (puts the checkout on sys.path)

TAUS = (0.005, 0.01)


def _elapsed_at(progress: str) -> dict:
    """step -> training seconds, from the run's step events (interpolated between them)."""
    pts = [(0, 0.0)]
    with open(progress, encoding="utf-8") as fh:
        for line in fh:
            try:
                ev = json.loads(line)
            except ValueError:
                continue
            if ev.get("event") == "step" and isinstance(ev.get("elapsed"), (int, float)):
                pts.append((int(ev["step"]), float(ev["elapsed"])))
    return pts


def _time_of(step: int, pts) -> float:
    for (s0, t0), (s1, t1) in zip(pts, pts[1:]):
        if s0 <= step <= s1:
            return t0 + (t1 - t0) * (step - s0) / max(1, s1 - s0)
    (s0, t0), (s1, t1) = pts[-2], pts[-1]
    return t1 + (t1 - t0) * (step - s1) / max(1, s1 - s0)


def _score(mesh_path: str, truth) -> dict:
    from nerf_core.export.ply import read_geometry
    from nerf_core.export.score import score

    pred = read_geometry(mesh_path)
    out = {}
    for tau in TAUS:
        s = score(pred, truth, tau_share=tau)
        out[f"{tau:g}"] = {k: s[k] for k in ("precision", "recall", "fscore", "chamfer", "normal_consistency")}
    return out


def _export(run, out, **kw) -> dict:
    from nerf_core.export import mesh
    from nerf_core.export.run_export import export_mesh

    try:
        return export_mesh(run, out, overwrite=True, **kw)
    except mesh.NoSurface as exc:
        return {"error": str(exc)}


def cmd_run(a) -> int:
    import torch

    from nerf_core.engine.config import TrainConfig
    from nerf_core.engine.trainer import train
    from nerf_core.evaluation.evaluate import evaluate_run
    from nerf_core.export.ply import read_geometry

    # one thread, as the docstring says: two runs side by side each starting a thread per core fought
    # over the cores (635 steps in 5 minutes on glossy with depth, where one thread each makes thousands)
    torch.set_num_threads(1)
    scene = os.path.basename(os.path.normpath(a.dataset)).split("-")[0]
    os.makedirs(a.out, exist_ok=True)
    # A run with depth is its own series: a score with depth is never put beside a colours-only one as if
    # they were the same (issue 56).
    label = a.method + ("+depth" if a.depth else "")
    run = os.path.join(a.out, f"{scene}_{label}")
    truth = read_geometry(os.path.join(a.dataset, "points3d.ply"))
    started = time.time()
    if not os.path.isfile(os.path.join(run, "checkpoints", "latest.pt")):
        train(TrainConfig(dataset=a.dataset, out=run, method=a.method, max_seconds=a.seconds, seed=0,
                          checkpoint_every=a.every, keep_checkpoints=1000, eval_views=0, stdout_events=False,
                          show_bar=False, depth=a.depth))
    pts = _elapsed_at(os.path.join(run, "progress.jsonl"))
    ckpts = sorted(glob.glob(os.path.join(run, "checkpoints", "step_*.pt")))
    result = {"scene": scene, "method": label, "dataset": os.path.abspath(a.dataset), "budget_s": a.seconds,
              "truth_points": int(len(truth.points)), "checkpoints": []}
    mesh_dir = os.path.join(a.out, "meshes")
    os.makedirs(mesh_dir, exist_ok=True)
    for ck in ckpts:
        step = int(os.path.basename(ck)[5:-3])
        path = os.path.join(mesh_dir, f"{scene}_{label}_{step:07d}.ply")
        summary = _export(run, path, checkpoint=ck, resolution=a.resolution)
        exported = (path, summary)
        entry = {"step": step, "train_seconds": round(_time_of(step, pts), 1),
                 "export_seconds": summary.get("seconds"), "faces": summary.get("faces"),
                 "resolution": summary.get("resolution"), "error": summary.get("error")}
        if "error" not in summary:
            entry["scores"] = _score(path, truth)
        result["checkpoints"].append(entry)
        print(json.dumps(entry), flush=True)
    last = ckpts[-1]
    final_mesh = os.path.join(mesh_dir, f"{scene}_{label}_final.ply")
    # the last checkpoint's mesh is the final one (same checkpoint, same flags): copied, not exported twice
    base = exported[1]
    if "error" not in base:
        shutil.copyfile(exported[0], final_mesh)
    variants = {"default": {"summary": base, "scores": _score(final_mesh, truth) if "error" not in base else None}}
    for name, kw in (
        ()
        if a.no_variants
        else (
            ("level x0.25", {"level": 0.25}),
            ("level x4", {"level": 4.0}),
            ("level x16", {"level": 16.0}),
            ("fixed level", {"fixed": True}),
            ("no fill", {"fill_inside": False}),
            ("no culling", {"cull_unseen": False, "min_component": 0.0}),
        )
    ):
        if "level" in kw:
            if "level" not in base:
                continue
            kw = {"level": kw["level"] * base["level"]}
        if kw.pop("fixed", False):  # the fallback rule: one grid step 5 % opaque
            import numpy as np

            from nerf_core.export import grid
            kw = {"level": grid.iso_level(np.asarray(base["box"]), base["resolution"])}
        p = os.path.join(mesh_dir, f"{scene}_{label}_{name.replace(' ', '_')}.ply")
        s = _export(run, p, checkpoint=last, resolution=a.resolution, **kw)
        variants[name] = {"summary": {k: s.get(k) for k in ("faces", "level", "error", "seconds")},
                          "scores": _score(p, truth) if "error" not in s else None}
    if not a.no_256:
        t = time.perf_counter()
        big = _export(run, os.path.join(mesh_dir, f"{scene}_{label}_256.ply"), checkpoint=last, resolution=256)
        result["extract_256"] = {"seconds": round(time.perf_counter() - t, 2), "faces": big.get("faces"),
                                 "error": big.get("error")}
    result["final"] = variants
    ev = evaluate_run(run, split="test", max_views=5, show_progress=False, print_fn=lambda s: None)
    result["eval"] = {k: ev.get(k) for k in ("psnr", "ssim", "depth_mae", "depth_rel", "step")}
    result["wall_seconds"] = round(time.time() - started, 1)
    with open(os.path.join(a.out, f"{scene}_{label}.json"), "w", encoding="utf-8") as fh:
        json.dump(result, fh, indent=1)
    print(json.dumps({"scene": scene, "method": label, "eval": result["eval"],
                      "final": variants["default"]["scores"], "extract_256": result.get("extract_256")}))
    return 0


def _seconds_256(r) -> str:
    big = r.get("extract_256")
    return f"{big['seconds']} s" if big else "-"


def cmd_report(a) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    results = [json.load(open(p, encoding="utf-8")) for p in sorted(glob.glob(os.path.join(a.out, "*_*.json")))]
    scenes = sorted({r["scene"] for r in results})
    methods = sorted({r["method"] for r in results})
    colours = dict(zip(methods, plt.get_cmap("tab10").colors))
    ncol = min(4, len(scenes))
    nrow = -(-len(scenes) // ncol)
    # small multiples: one panel per scene, one colour per method; tau 0.5 % dashed, open markers; 1 % solid
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.3 * ncol, 2.7 * nrow + 0.6), squeeze=False, sharey=True)
    t_max = max([c["train_seconds"] / 60 for r in results for c in r["checkpoints"]] + [1.0])
    for k, ax in enumerate(axes.flat):
        if k >= len(scenes):
            ax.set_visible(False)
            continue
        scene = scenes[k]
        for r in (r for r in results if r["scene"] == scene):
            pts = [c for c in r["checkpoints"] if c.get("scores")]
            for tau, style, face in zip(TAUS, ("--", "-"), ("white", None)):  # open markers at 0.5 %
                ax.plot([c["train_seconds"] / 60 for c in pts], [c["scores"][f"{tau:g}"]["fscore"] for c in pts],
                        style, marker="o", ms=4, mfc=face, color=colours[r["method"]])
        ax.set_title(scene, fontsize=10)
        ax.set_xlim(0, t_max * 1.05)
        ax.set_ylim(0, 1)
        ax.axhline(0.9, color="grey", lw=0.6, ls=":")
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
        if k % ncol == 0:
            ax.set_ylabel("F-score", fontsize=9)
        if k >= len(scenes) - ncol:
            ax.set_xlabel("training time (min, one core)", fontsize=9)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=colours[m], marker="o", ms=3, label=m) for m in methods]
    handles += [Line2D([], [], color="black", ls=style, marker="o", ms=4, mfc=face,
                       label=f"tau {100 * tau:g} % of the diagonal")
                for tau, style, face in zip(TAUS, ("--", "-"), ("white", None))]
    handles.append(Line2D([], [], color="grey", lw=0.6, ls=":", label="F = 0.9"))
    # A row of the legend holds about 2 entries per panel; a narrow figure (few scenes) takes more rows.
    per_row = min(len(handles), max(2, 2 * ncol))
    rows = -(-len(handles) // per_row)
    fig.legend(handles=handles, loc="upper center", ncol=per_row, fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 1 - (0.2 + 0.25 * rows) / fig.get_figheight()))
    fig.savefig(os.path.join(a.out, "geometry.png"), dpi=110)
    print("| scene | method | steps | F 0.5 % | F 1 % | P / R at 1 % | Chamfer-L1 | normal cons. | PSNR |"
          " depth_mae | depth_rel | 256^3 extraction |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        s = (r["final"]["default"]["scores"] or {})
        f5, f1 = s.get("0.005", {}), s.get("0.01", {})
        ev = r.get("eval", {})
        steps = r["checkpoints"][-1]["step"] if r["checkpoints"] else "-"
        print(f"| {r['scene']} | {r['method']} | {steps} | {f5.get('fscore', 0):.3f} | {f1.get('fscore', 0):.3f} | "
              f"{f1.get('precision', 0):.3f} / {f1.get('recall', 0):.3f} | {f1.get('chamfer', 0):.4f} | "
              f"{f1.get('normal_consistency') or 0:.3f} | {ev.get('psnr') or 0:.2f} | {ev.get('depth_mae') or 0:.4f} | "
              f"{ev.get('depth_rel') or 0:.4f} | {_seconds_256(r)} |")
    print("\n| scene | method | variant | faces | F 0.5 % | F 1 % | P / R at 1 % |")
    print("|---|---|---|---|---|---|---|")
    for r in (r for r in results if len(r["final"]) > 1):  # runs made with --no-variants have only the default
        for name, v in r["final"].items():
            s = v["scores"] or {}
            f5, f1 = s.get("0.005", {}), s.get("0.01", {})
            print(f"| {r['scene']} | {r['method']} | {name} | {v['summary'].get('faces')} | "
                  f"{f5.get('fscore', 0):.3f} | {f1.get('fscore', 0):.3f} | "
                  f"{f1.get('precision', 0):.3f} / {f1.get('recall', 0):.3f} |")
    return 0


def cmd_picture(a) -> int:
    """The mesh beside the original surface, its faces coloured by their distance to it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from scipy.spatial import cKDTree

    from nerf_core.export.mesh import decimate
    from nerf_core.export.ply import read_geometry

    truth, mesh = read_geometry(a.truth), read_geometry(a.mesh)
    v, f = decimate(mesh.points, mesh.faces, a.faces)
    tri = v[f]
    diag = float(np.linalg.norm(truth.points.max(0) - truth.points.min(0)))
    dist, _ = cKDTree(truth.points).query(tri.mean(axis=1))
    share = dist / diag
    fig = plt.figure(figsize=(10, 4.6))
    lo, hi = truth.points.min(0), truth.points.max(0)
    for k, title in enumerate(("the scene (points3d.ply, as captured)", "the NeRF's mesh: distance to the scene")):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        if k == 0:
            pick = np.random.default_rng(0).choice(len(truth.points), min(len(truth.points), 60000), replace=False)
            p = truth.points[pick]
            ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=0.3, c=truth.colors[pick] / 255.0 if truth.colors is not None
                       else "grey", depthshade=False)
        else:
            cmap = plt.get_cmap("viridis")
            colors = cmap(np.clip(share / (2 * a.tau), 0, 1))
            ax.add_collection3d(Poly3DCollection(tri, facecolors=colors, edgecolor="none"))
            sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, 2 * a.tau * 100))
            fig.colorbar(sm, ax=ax, shrink=0.6, label="distance, % of the scene's diagonal")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(hi - lo)
        ax.view_init(elev=25, azim=-60)
        ax.set_title(title, fontsize=10)
        ax.set_axis_off()
    within = float(np.mean(share < a.tau))
    fig.suptitle(f"{os.path.basename(a.mesh)}: {100 * within:.1f} % of the faces lie within {100 * a.tau:g} % "
                 "of the diagonal", fontsize=10)
    fig.tight_layout()
    fig.savefig(a.out, dpi=110)
    return 0


def main(argv) -> int:
    ap = argparse.ArgumentParser(prog="bench_geometry.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--dataset", required=True)
    r.add_argument("--method", default="vmgrid")
    r.add_argument("--seconds", type=float, default=300.0)
    r.add_argument("--every", type=int, default=250, help="steps between checkpoints")
    r.add_argument("--depth", action="store_true",
                   help="train with the capture's depth maps (train --depth); the series is METHOD+depth")
    r.add_argument("--out", required=True)
    r.add_argument("--resolution", type=int, help="export resolution (default: the export's own default)")
    r.add_argument("--no-variants", action="store_true", help="skip the level and culling variants")
    r.add_argument("--no-256", action="store_true", help="skip the timed 256^3 extraction (minutes for nerf)")
    p = sub.add_parser("report")
    p.add_argument("out")
    pic = sub.add_parser("picture")
    pic.add_argument("--mesh", required=True)
    pic.add_argument("--truth", required=True)
    pic.add_argument("--out", required=True, help="PNG to write")
    pic.add_argument("--tau", type=float, default=0.01, help="the colour scale ends at 2 tau")
    pic.add_argument("--faces", type=int, default=30000, help="faces drawn (decimated)")
    a = ap.parse_args(argv)
    return {"run": cmd_run, "report": cmd_report, "picture": cmd_picture}[a.cmd](a)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

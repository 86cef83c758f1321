"""The numbers a study draws from its runs: training summaries, floaters, mean/spread, Pareto fronts.

``summarize_training`` reads one run's progress events and ``eval_at_points`` its evaluations at
checkpoints; ``floater_stats`` compares rendered with ground-truth alpha; ``mean_std`` summarises
seeds; ``pareto_front`` and ``auto_size_verdict`` judge size against accuracy; ``rows_from_results``,
``psnr_at_table``, ``pair_gap_table`` and ``size_analysis`` turn the benchmark's runs into its tables.
Only the standard library at module level (numpy/pillow on use).
"""
from __future__ import annotations

import math
import os
from typing import Optional, Sequence

from .datasets import load_json


# --------------------------------------------------------------------------------------------
# Training summaries
# --------------------------------------------------------------------------------------------


def summarize_training(events: Sequence[dict]) -> dict:
    """Numbers a study needs from one training run's events.

    Returns n_params, steps, elapsed, samples_per_s (median of step events, robust to the slow first
    steps), rollbacks, nan (a NaN/inf loss was seen or a rollback gave NaN as its reason), error
    (message of the ``error`` event or None) and final train psnr.
    """
    out = {"n_params": None, "steps": 0, "elapsed": 0.0, "samples_per_s": None, "rollbacks": 0,
           "nan": False, "error": None, "train_psnr": None, "stage_times": None, "first_lr": None}
    rates = []
    for ev in events:
        kind = ev.get("event")
        if kind == "start":
            out["n_params"] = ev.get("n_params", out["n_params"])
        elif kind == "step":
            out["steps"] = max(out["steps"], int(ev.get("step", 0)))
            out["elapsed"] = float(ev.get("elapsed", out["elapsed"]) or 0.0)
            loss = ev.get("loss")
            if loss is None or (isinstance(loss, float) and not math.isfinite(loss)):
                out["nan"] = True
            if out["first_lr"] is None and ev.get("lr") is not None:
                out["first_lr"] = float(ev["lr"])
            if ev.get("samples_per_s"):
                rates.append(float(ev["samples_per_s"]))
            if ev.get("psnr") is not None:
                out["train_psnr"] = ev["psnr"]
            if isinstance(ev.get("stage_times"), dict):
                out["stage_times"] = ev["stage_times"]
        elif kind == "rollback":
            out["rollbacks"] += 1
            if "nan" in str(ev.get("reason", "")).lower() or "inf" in str(ev.get("reason", "")).lower():
                out["nan"] = True
        elif kind == "done":
            out["steps"] = max(out["steps"], int(ev.get("step", 0) or 0))
            out["elapsed"] = float(ev.get("elapsed", out["elapsed"]) or 0.0)
        elif kind == "error":
            out["error"] = str(ev.get("message", "error"))
    if rates:
        rates.sort()
        out["samples_per_s"] = rates[len(rates) // 2]
    return out


def eval_at_points(events: Sequence[dict], marks: Sequence[float]) -> list[dict]:
    """The ``--eval-at`` evaluations among a run's ``events`` as points {seconds, budget, step, psnr, ssim}.

    The trainer evaluates once per step that crosses marks, in order; its event lists the marks it
    stands for in ``eval_at`` (several when one slow step crossed more than one), and each of them
    becomes a point. Events without ``eval_at`` (older runs, which evaluated once per mark) belong to
    the marks in order: the k-th test evaluation that carries ``eval_wall`` to the k-th of ``marks``.
    Matching by nearest time instead would give close log-spaced marks the wrong label after one slow
    step. Evaluations beyond the marks are ignored.
    """
    points = []
    todo = sorted(marks)
    for ev in events:
        if not todo:
            break
        if ev.get("event") == "eval" and ev.get("split") == "test" and "eval_wall" in ev:
            stands_for = ev.get("eval_at")
            if isinstance(stands_for, list) and stands_for:
                mine = [t for t in todo if any(abs(t - float(m)) < 1e-6 for m in stands_for)] or todo[:1]
            else:
                mine = todo[:1]
            todo = [t for t in todo if t not in mine]
            for mark in mine:
                points.append({"seconds": float(ev["elapsed"]), "budget": mark, "step": int(ev["step"]),
                               "psnr": ev.get("psnr"), "ssim": ev.get("ssim")})
    return points


def checkpoint_size(path: str) -> Optional[int]:
    try:
        return os.path.getsize(path)
    except OSError:
        return None

# --------------------------------------------------------------------------------------------
# Floaters: rendered opacity where the ground truth is empty
# --------------------------------------------------------------------------------------------


def _alpha(path: str):
    import numpy as np
    from PIL import Image

    with Image.open(path) as im:
        if im.mode not in ("RGBA", "LA"):
            return None
        return np.asarray(im.convert("RGBA"), dtype=np.float32)[..., 3] / 255.0


def floater_stats(render_dir: str, dataset: str, split: str = "test", empty_below: float = 0.02,
                  opaque_above: float = 0.5) -> dict:
    """Compare rendered alpha with ground-truth alpha on held-out views.

    Ground-truth background = pixels with dataset alpha below ``empty_below``. Returns
    ``floater_alpha`` (mean rendered alpha over background pixels) and ``floater_pixels`` (share of
    background pixels rendered more opaque than ``opaque_above``), averaged over views, and ``n_views``.
    """
    import numpy as np

    meta = load_json(os.path.join(dataset, f"transforms_{split}.json"))
    means, shares = [], []
    for k, frame in enumerate(meta["frames"]):
        stem = os.path.basename(frame["file_path"]) if frame.get("file_path") else f"view_{k:03d}"
        gt_path = os.path.join(dataset, frame["file_path"])
        if not os.path.splitext(gt_path)[1]:
            gt_path += ".png"
        pred_path = os.path.join(render_dir, stem + ".png")
        if not os.path.isfile(pred_path):
            pred_path = os.path.join(render_dir, f"view_{k:03d}.png")
        if not (os.path.isfile(gt_path) and os.path.isfile(pred_path)):
            continue
        gt, pred = _alpha(gt_path), _alpha(pred_path)
        if gt is None or pred is None or gt.shape != pred.shape:
            continue
        bg = gt < empty_below
        if not bg.any():
            continue
        means.append(float(pred[bg].mean()))
        shares.append(float((pred[bg] > opaque_above).mean()))
    if not means:
        return {"floater_alpha": None, "floater_pixels": None, "n_views": 0}
    return {"floater_alpha": float(np.mean(means)), "floater_pixels": float(np.mean(shares)), "n_views": len(means)}


# --------------------------------------------------------------------------------------------
# Spread over seeds
# --------------------------------------------------------------------------------------------


def mean_std(values: Sequence[Optional[float]]) -> tuple[Optional[float], Optional[float], int]:
    """Mean and sample standard deviation of the finite values; (None, None, 0) when there are none."""
    xs = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if not xs:
        return None, None, 0
    m = sum(xs) / len(xs)
    sd = math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1)) if len(xs) > 1 else 0.0
    return m, sd, len(xs)


# --------------------------------------------------------------------------------------------
# Speed against accuracy
# --------------------------------------------------------------------------------------------


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points not dominated when size (x) should be small and quality (y) high.

    A point is dominated when another is no larger and no worse and strictly better in one of the two.
    Points with a missing or non-finite coordinate never belong to the front. Returned sorted by size.
    """
    valid = [i for i, (x, y) in enumerate(points)
             if x is not None and y is not None and math.isfinite(x) and math.isfinite(y)]
    front = []
    for i in valid:
        xi, yi = points[i]
        dominated = any(
            (points[j][0] <= xi and points[j][1] >= yi) and (points[j][0] < xi or points[j][1] > yi)
            for j in valid if j != i
        )
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: (points[i][0], -points[i][1]))


def auto_size_verdict(auto: tuple[float, float], fixed: Sequence[tuple[float, float]],
                      tol_db: float = 0.5, max_param_ratio: float = 0.5) -> dict:
    """Does ``--size auto`` (params, psnr) land on or near the front of the fixed sizes tried?

    ``ok``: auto is not dominated by any fixed size, or it is within ``tol_db`` of the best fixed size
    with no more parameters than it. ``within_half``: the stricter target, within ``tol_db`` of the
    best at no more than ``max_param_ratio`` of its parameters. ``gap_db`` = best PSNR - auto PSNR.
    """
    valid = [(x, y) for x, y in fixed if x is not None and y is not None and math.isfinite(y)]
    ax, ay = auto
    if not valid or ax is None or ay is None or not math.isfinite(ay):
        return {"ok": None, "within_half": None, "gap_db": None, "param_ratio": None, "best": None}
    best = max(valid, key=lambda p: (p[1], -p[0]))
    gap = best[1] - ay
    ratio = ax / best[0] if best[0] else None
    dominated = any((x <= ax and y >= ay) and (x < ax or y > ay) for x, y in valid)
    close = gap <= tol_db
    return {
        "ok": bool((close and ratio is not None and ratio <= 1.0) or not dominated),
        "within_half": bool(close and ratio is not None and ratio <= max_param_ratio),
        "on_front": not dominated,
        "gap_db": gap,
        "param_ratio": ratio,
        "best": {"params": best[0], "psnr": best[1]},
    }


# --------------------------------------------------------------------------------------------
# The benchmark's tables
# --------------------------------------------------------------------------------------------


def rows_from_results(results: list[dict]) -> tuple[list[dict], list[dict]]:
    """(one row per checkpoint, one row per run with its final numbers)."""
    rows, finals = [], []
    for r in results:
        base = {"scene": r["scene"], "series": r["series"], "method": r["method"], "n_params": r["n_params"],
                "model_bytes": r["model_bytes"], "checkpoint_bytes": r["checkpoint_bytes"],
                "samples_per_s": r["samples_per_s"], "rollbacks": r["rollbacks"]}
        for p in r["points"]:
            rows.append({**base, "train_seconds": p["seconds"], "budget_seconds": p["budget"], "step": p["step"],
                         "psnr": p["psnr"], "ssim": p["ssim"]})
        last = r["points"][-1] if r["points"] else {}
        finals.append({**base, "train_seconds": last.get("seconds"), "steps": last.get("step"),
                       "psnr": last.get("psnr"), "ssim": last.get("ssim"), "error": r.get("error")})
    return rows, finals


def size_analysis(finals: list[dict], fast: str) -> list[dict]:
    """Per scene: is the auto-sized fast method on/near the front of the fixed sizes tried?"""
    out = []
    for scene in sorted({f["scene"] for f in finals}):
        runs = [f for f in finals if f["scene"] == scene and f["method"] == fast]
        auto = [f for f in runs if f["series"].endswith(" auto")]
        fixed = [f for f in runs if not f["series"].endswith(" auto")]
        if not auto or not fixed:
            continue
        v = auto_size_verdict((auto[0]["n_params"], auto[0]["psnr"]), [(f["n_params"], f["psnr"]) for f in fixed])
        front = pareto_front([(f["n_params"], f["psnr"]) for f in runs])
        out.append({"scene": scene, "auto_params": auto[0]["n_params"], "auto_psnr": auto[0]["psnr"],
                    "best_params": (v["best"] or {}).get("params"), "best_psnr": (v["best"] or {}).get("psnr"),
                    "gap_db": v["gap_db"], "param_ratio": v["param_ratio"], "on_front": v.get("on_front"),
                    "near_front": v["ok"], "within_0.5dB_at_half": v["within_half"],
                    "front": ", ".join(runs[i]["series"] for i in front)})
    return out


def psnr_at_table(rows: list[dict], checkpoints: list[float]) -> list[dict]:
    """One row per (scene, series) with the PSNR at each checkpoint budget."""
    table: dict = {}
    for r in rows:
        key = (r["scene"], r["series"])
        entry = table.setdefault(key, {"scene": r["scene"], "series": r["series"], "n_params": r["n_params"],
                                       "samples_per_s": r["samples_per_s"]})
        entry[f"psnr@{r['budget_seconds']:g}s"] = r["psnr"]
        entry["ssim"] = r["ssim"]
    return [table[k] for k in sorted(table)]


def pair_gap_table(table: list[dict], checkpoints: list[float], first: str = "nerf",
                   second: str = "nerf-nope") -> list[dict]:
    """Per scene that has both series, ``first`` minus ``second`` test PSNR (dB) at each checkpoint.

    ``table``: ``psnr_at_table`` rows. Returns [{"scene", "<c>s": gap or None, ...}] with one
    ``"<c>s"`` key per checkpoint (None where either run has no PSNR there), sorted by scene.
    """
    by = {(r["scene"], r["series"]): r for r in table}
    out = []
    for scene in sorted({r["scene"] for r in table}):
        a, b = by.get((scene, first)), by.get((scene, second))
        if a is None or b is None:
            continue
        row = {"scene": scene}
        for c in checkpoints:
            key = f"psnr@{c:g}s"
            pa, pb = a.get(key), b.get(key)
            ok = pa is not None and pb is not None and math.isfinite(pa) and math.isfinite(pb)
            row[f"{c:g}s"] = pa - pb if ok else None
        out.append(row)
    return out

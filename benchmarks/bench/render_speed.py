"""The numbers and tables of ``benchmarks/bench_render.py``: training against rendering rays/s.

- ``parse_methods`` / ``parse_runs``: the ``--methods`` and ``--runs`` arguments;
- ``training_rate``: rays/s of a run's training from its progress events, over the second half of
  the training time (after growth, so it is the grown model's speed);
- ``render_rate``: rays/s of a ``render`` from its ``renders.json`` (the model's time only);
- ``camera_at_size``: a JSON camera list (``nerf_core render --cameras``) of one test view at W x H;
- ``speed_rows`` / ``markdown``: the table and its page.

Standard library and ``nerf_core.contract`` only: importing it must not start torch.
"""
from __future__ import annotations

import math
import os
from typing import Iterable, Optional, Sequence

import _bootstrap  # noqa: F401  (puts the repository on sys.path, for nerf_core; as in runner)
from nerf_core.contract.intrinsics import resolve_intrinsics
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.transforms import frame_infos

from . import runner
from .report import fmt, markdown_table


class SpeedInputError(ValueError):
    """A bad argument or input file of the render-speed benchmark; the message names it."""


def parse_methods(text: str) -> list[str]:
    """``"vmgrid, nerf"`` -> ``["vmgrid", "nerf"]`` (order kept, duplicates and blanks refused)."""
    names = [m.strip() for m in text.split(",")]
    if not names or any(not m for m in names):
        raise SpeedInputError(f"--methods {text!r}: expected comma-separated method names like vmgrid,nerf")
    dup = sorted({m for m in names if names.count(m) > 1})
    if dup:
        raise SpeedInputError(f"--methods {text!r}: {', '.join(dup)} given twice")
    return names


def parse_runs(text: Optional[str], methods: Sequence[str]) -> dict[str, str]:
    """``"vmgrid=runs/a,nerf=runs/b"`` -> {method: run folder}; every method named must be in ``methods``."""
    out: dict[str, str] = {}
    for item in filter(None, (s.strip() for s in (text or "").split(","))):
        method, sep, path = item.partition("=")
        method, path = method.strip(), path.strip()
        if not sep or not method or not path:
            raise SpeedInputError(f"--runs {item!r}: expected METHOD=RUN_FOLDER")
        if method not in methods:
            raise SpeedInputError(f"--runs {item!r}: method {method!r} is not in --methods ({', '.join(methods)})")
        if method in out:
            raise SpeedInputError(f"--runs: method {method!r} given twice")
        out[method] = path
    return out


def run_method(run: str) -> Optional[str]:
    """The method a run folder was trained with (its config.json), or None when that cannot be read."""
    import json

    try:
        with open(os.path.join(run, "config.json"), encoding="utf-8") as fh:
            cfg = json.load(fh)
    except (OSError, ValueError):
        return None
    method = cfg.get("method") if isinstance(cfg, dict) else None
    return method if isinstance(method, str) else None


def training_rate(events: Iterable[dict], rays_per_step: int) -> dict:
    """Training rays/s over the second half of a run's training time, from its progress events.

    Uses the ``step`` and ``done`` events' ``step`` and ``elapsed`` (training seconds: previews,
    checkpoints and evaluation not counted): from the last event at or before half the final
    ``elapsed`` (so the span always covers the second half, even when a short or slow run logged
    no step inside it) to the last one, rays/s = steps x ``rays_per_step`` / seconds. Returns
    ``rays_per_s`` (None when there are fewer than two events with progress between them),
    ``from_step``, ``to_step``, ``seconds`` and ``rollbacks`` (a rollback repeats steps, so a rate with
    rollbacks in it is low).
    """
    points, rollbacks = [], 0
    for ev in events:
        kind = ev.get("event")
        if kind == "rollback":
            rollbacks += 1
        if kind in ("step", "done") and isinstance(ev.get("step"), (int, float)) \
                and isinstance(ev.get("elapsed"), (int, float)) and math.isfinite(ev["elapsed"]):
            points.append((int(ev["step"]), float(ev["elapsed"])))
    out = {"rays_per_s": None, "from_step": None, "to_step": None, "seconds": None, "rollbacks": rollbacks}
    if not points:
        return out
    end = max(e for _, e in points)
    before = [p for p in points if p[1] <= end / 2]
    (s0, e0), (s1, e1) = (before[-1] if before else points[0]), points[-1]
    out.update(from_step=s0, to_step=s1, seconds=e1 - e0)
    if s1 > s0 and e1 > e0:
        out["rays_per_s"] = (s1 - s0) * int(rays_per_step) / (e1 - e0)
    return out


def render_rate(renders: dict, skip_first: bool = True) -> dict:
    """Rendering rays/s from a ``renders.json`` (its frames' ``render_seconds`` and ``rays``: one a pixel
    plus the pixel filter's at edges; ``w`` x ``h`` for files written before frames counted them).

    ``skip_first``: leave out the first frame when there are more, since it also pays one-time costs
    (the allocator growing, lazy initialisation) that a long render does not. Returns ``rays_per_s``,
    ``rays``, ``seconds`` and ``frames`` (how many counted).
    """
    frames = renders.get("frames") or []
    if any("render_seconds" not in f for f in frames):
        raise SpeedInputError("renders.json has frames without 'render_seconds' (rendered by an older nerf_core?)")
    counted = frames[1:] if skip_first and len(frames) > 1 else frames
    rays = sum(int(f.get("rays", int(f["w"]) * int(f["h"]))) for f in counted)
    seconds = sum(float(f["render_seconds"]) for f in counted)
    return {"rays_per_s": rays / seconds if seconds > 0 else None, "rays": rays, "seconds": seconds,
            "frames": len(counted)}


def camera_at_size(dataset: str, width: int, height: int, split: str = "test", index: int = 0,
                   copies: int = 1, size_of=None) -> list[dict]:
    """``copies`` cameras (a JSON list for ``render --cameras``) at the pose of view ``index`` of
    ``split``, rendered at ``width`` x ``height`` with the view's field of view over its longer side
    (square pixels, principal point at the centre). ``size_of(path) -> (w, h)`` reads an image's size
    when the transforms file gives none."""
    try:
        _, _, frames, _ = frame_infos(dataset, (split,))
        views = frames.get(split) or []
        if not views:
            raise SpeedInputError(f"{dataset}: no {split!r} views to time a {width}x{height} frame on")
        fr = views[min(index, len(views) - 1)]
        size = size_of(fr.image) if size_of is not None and not {"w", "h"} <= set(fr.intrinsics) else None
        fx, fy, _, _, w, h = resolve_intrinsics(None, fr.intrinsics, size, fr.where)
    except (DatasetError, OSError) as exc:
        raise SpeedInputError(str(exc)) from None
    scale = max(width, height) / max(w, h)
    cam = {"transform_matrix": fr.c2w.tolist(), "w": int(width), "h": int(height), "fl_x": fx * scale,
           "fl_y": fy * scale, "cx": width / 2.0, "cy": height / 2.0}
    return [dict(cam, name=f"frame{width}x{height}_{k}") for k in range(copies)]


def speed_rows(results: Sequence[dict]) -> list[dict]:
    """One table row per method: training and rendering rays/s, their ratio, seconds per big frame."""
    rows = []
    for r in results:
        train, rend = r.get("train_rays_per_s"), r.get("render_rays_per_s")
        rows.append({"method": r["method"], "train_rays_per_s": train, "render_rays_per_s": rend,
                     "ratio": rend / train if train and rend else None,
                     "frame_seconds": r.get("frame_seconds"), "steps": r.get("steps"),
                     "error": r.get("error")})
    return rows


def markdown(rows: Sequence[dict], info: dict) -> str:
    """The page ``render_speed.md``: what was run where, the table, and how to read it."""
    size = info.get("frame_size", "800x800")
    shown = [dict(r, **{k: round(r[k]) for k in ("train_rays_per_s", "render_rays_per_s") if r.get(k) is not None})
             for r in rows]  # whole rays per second: decimals there would be noise
    table = markdown_table(shown, ["method", "steps", "train_rays_per_s", "render_rays_per_s", "ratio",
                                   "frame_seconds"],
                           ["method", "training steps", "training rays/s (2nd half)", "render rays/s",
                            "render / training", f"s per {size} frame"], digits=2)
    m = info.get("machine") or {}
    lines = [f"# Rendering speed against training speed, dataset `{info.get('dataset', '?')}`", "",
             f"Machine: {m.get('cpu', '?')}, {m.get('cpus', '?')} cores, Python {m.get('python', '?')}, "
             f"torch {m.get('torch', '?')}; threads: {info.get('threads', '?')}; load average (1 min) before/after: "
             f"{fmt(info.get('load_before'))} / {fmt(info.get('load_after'))}.", ""]
    if info.get("contended"):
        lines += [runner.CONTENDED_NOTE, ""]
    lines += [table, ""]
    for r in rows:
        if r.get("error"):
            lines.append(f"- {r['method']}: {r['error']}")
    lines += ["",
              "Training rays/s: steps x rays per step / training seconds over the second half of the run's training "
              "time (`step` events of RUN/progress.jsonl). Render rays/s: the test views rendered by "
              "`python -m nerf_core render`, the model's own time from renders.json (no start-up, model loading or "
              "image files; the first view left out as warm-up). `eval` renders with the same code.", "",
              "Command:", "", f"    {info.get('command', '?')}", ""]
    cmds = info.get("commands") or []
    if cmds:
        lines += ["Commands it ran:", ""] + [f"    {c}" for c in cmds] + [""]
    return "\n".join(lines)


def existing_outputs(paths: Iterable[str]) -> list[str]:
    """The paths among ``paths`` that exist and are not empty folders (a benchmark never overwrites them)."""
    out = []
    for p in paths:
        if os.path.isdir(p) and os.listdir(p):
            out.append(p)
        elif os.path.isfile(p):
            out.append(p)
    return out

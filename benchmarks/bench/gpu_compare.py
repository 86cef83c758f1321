"""Our run against TensoRF's: test PSNR over training seconds, the headline ratios, summary.md and the chart.

``results.json`` (written by ``benchmarks/bench_gpu_tensorf.py``) holds ``machine`` (device name, torch),
``commands``, ``ours`` (``summarise_ours``) and ``tensorf`` (``bench.tensorf_launch``'s result). Each
side has ``points``: ``{"seconds", "psnr", ...}`` in training seconds (evaluation not counted), and
``final``. Standard library at module level; matplotlib only when drawing.
"""
from __future__ import annotations

import json
import os
from typing import Optional

RAYS_TARGET = 1e6  # issue 42: ours trains at >= 1 M rays/s on a GPU
SPEED_TARGET = 0.25  # issue 42: TensoRF's final PSNR in at most a quarter of its training seconds


def summarise_ours(events: list[dict], config: Optional[dict]) -> dict:
    """Our run's points, final score and speed from its JSON-line events and ``RUN/config.json``.

    Points: the ``--eval-at`` evaluations (events with ``eval_wall``) and the final one (the ``eval``
    event without it, at the ``done`` event's training seconds). ``steps_per_s`` is over the whole run;
    ``steps_per_s_late`` over its second half (after growth), from the ``step`` events.
    """
    done = next((e for e in reversed(events) if e.get("event") == "done"), None)
    points = [{"seconds": float(e["elapsed"]), "psnr": float(e["psnr"]), "step": e.get("step"),
               "n_views": e.get("n_views"), "eval_wall": e.get("eval_wall"), "final": False}
              for e in events if e.get("event") == "eval" and "eval_wall" in e and "psnr" in e]
    finals = [e for e in events if e.get("event") == "eval" and e.get("split", "test") == "test"
              and "eval_wall" not in e and "psnr" in e]
    out = {"points": points, "final": None}
    if finals and done:
        f = finals[-1]
        out["final"] = {"seconds": float(done["elapsed"]), "psnr": float(f["psnr"]), "step": f.get("step"),
                        "n_views": f.get("n_views"), "final": True}
        points.append(out["final"])
    if done and done.get("elapsed"):
        out["steps"] = int(done["step"])
        out["train_seconds"] = float(done["elapsed"])
        out["steps_per_s"] = done["step"] / done["elapsed"]
    steps = [e for e in events if e.get("event") == "step" and e.get("elapsed")]
    if len(steps) >= 4:
        mid, last = steps[len(steps) // 2], steps[-1]
        if last["elapsed"] > mid["elapsed"]:
            out["steps_per_s_late"] = (last["step"] - mid["step"]) / (last["elapsed"] - mid["elapsed"])
    rays = (config or {}).get("rays_per_step")
    if rays:
        out["rays_per_step"] = int(rays)
        for key in ("steps_per_s", "steps_per_s_late"):
            if key in out:
                out[key.replace("steps", "rays")] = out[key] * rays
    if config:
        out["method"] = (config.get("model") or {}).get("method") or config.get("method")
        out["device"] = config.get("device_used")
    return out


def first_reaching(points: list[dict], psnr: float) -> Optional[dict]:
    """The earliest point (by training seconds) whose PSNR is at least ``psnr``; None if none is."""
    hits = [p for p in points if p.get("psnr") is not None and p["psnr"] >= psnr]
    return min(hits, key=lambda p: p["seconds"]) if hits else None


def headline(results: dict) -> dict:
    """The issue's two targets, as far as ``results`` tells them."""
    ours, tf = results.get("ours") or {}, results.get("tensorf") or {}
    out: dict = {}
    final = tf.get("final")
    if final and final.get("psnr") is not None:
        out["tensorf_psnr"] = final["psnr"]
        out["tensorf_seconds"] = tf.get("train_seconds", final["seconds"])
        hit = first_reaching(ours.get("points", []), final["psnr"])
        out["ours_seconds_to_tensorf_psnr"] = hit["seconds"] if hit else None
        if hit and out["tensorf_seconds"]:
            out["time_ratio"] = hit["seconds"] / out["tensorf_seconds"]
            out["speed_target_met"] = out["time_ratio"] <= SPEED_TARGET
        else:
            out["speed_target_met"] = False
    rate = ours.get("rays_per_s_late", ours.get("rays_per_s"))
    if rate is not None:
        out["ours_rays_per_s"] = rate
        out["rays_target_met"] = rate >= RAYS_TARGET
    return out


def _fmt(x, spec=".2f", none="–"):
    return none if x is None else format(x, spec)


def summary_markdown(results: dict, chart: Optional[str], chart_note: str = "") -> str:
    """summary.md: device, versions, the headline, both curves as a table, and the commands."""
    m, ours, tf = results.get("machine", {}), results.get("ours") or {}, results.get("tensorf") or {}
    h = headline(results)
    lines = [f"# Ours against TensoRF on {m.get('device_name', '?')}", "",
             f"torch {m.get('torch', '?')}, CUDA {m.get('cuda', '–')}, Python {m.get('python', '?')}, "
             f"{m.get('date', '')}; dataset `{results.get('dataset', '?')}` "
             f"({m.get('image_size', '?')} px, {m.get('n_train', '?')} train / {m.get('n_test', '?')} test views); "
             f"commit {results.get('commit', '?')}.", ""]
    if results.get("quick"):
        lines += ["**Quick mode (plumbing test): tiny settings, the numbers mean nothing.**", ""]
    if "tensorf_psnr" in h:
        reached = h.get("ours_seconds_to_tensorf_psnr")
        lines.append(f"- TensoRF ({tf.get('iters')} iterations): **{h['tensorf_psnr']:.2f} dB after "
                     f"{h['tensorf_seconds']:.1f} s** of training.")
        if reached is None:
            lines.append("- Ours did not reach that PSNR within its budget: the quarter-time target is **not met**.")
        else:
            lines.append(f"- Ours reached it after **{reached:.1f} s** = {h['time_ratio']:.2f}x TensoRF's seconds "
                         f"(target <= {SPEED_TARGET}x): **{'met' if h['speed_target_met'] else 'not met'}**.")
    if "ours_rays_per_s" in h:
        lines.append(f"- Ours trains at {h['ours_rays_per_s']:,.0f} rays/s after growth "
                     f"({_fmt(ours.get('steps_per_s_late'), '.1f')} steps/s x {ours.get('rays_per_step')} rays; "
                     f"whole run {_fmt(ours.get('steps_per_s'), '.1f')} steps/s); target >= 1 M: "
                     f"**{'met' if h['rays_target_met'] else 'not met'}**. TensoRF: "
                     f"{_fmt(tf.get('steps_per_s'), '.1f')} it/s x {tf.get('rays_per_step', '?')} rays = "
                     f"{_fmt(tf.get('rays_per_s'), ',.0f')} rays/s.")
    lines += ["", "| who | training s | iteration / step | test PSNR (dB) | views | eval s |",
              "|---|---|---|---|---|---|"]
    for name, side, key in (("ours", ours, "step"), ("TensoRF", tf, "iteration")):
        for p in sorted(side.get("points", []), key=lambda p: (p["seconds"], p.get("final", False))):
            lines.append(f"| {name}{' (final)' if p.get('final') else ''} | {p['seconds']:.1f} | {p.get(key, '–')} | "
                         f"{_fmt(p.get('psnr'))} | {p.get('n_views', '–')} | {_fmt(p.get('eval_wall'), '.1f')} |")
    lines.append("")
    if chart:
        lines += [f"![test PSNR against training seconds]({chart})", ""]
    if chart_note:
        lines += [chart_note, ""]
    lines += ["Training seconds exclude data loading and every test evaluation on both sides. Ours is evaluated "
              "by `nerf_core` (edge pixels through the capture's pixel filter), TensoRF by its own `evaluation` "
              "(one ray a pixel); both on the test views composited on white, PSNR averaged over views."]
    if tf.get("standins"):
        lines.append(f"TensoRF ran with stand-ins for {', '.join(tf['standins'])} "
                     f"(benchmarks/bench/tensorf_standins.py).")
    for side in ("ours", "tensorf"):
        if results.get(f"{side}_error"):
            lines.append(f"**{side} failed**: {results[f'{side}_error']}")
    lines += ["", "Commands:", ""] + [f"    {c}" for c in results.get("commands", [])]
    return "\n".join(lines) + "\n"


def draw_chart(results: dict, path: str) -> str:
    """psnr_vs_seconds.png; returns '' when drawn, else why not (matplotlib missing)."""
    try:
        import matplotlib
    except ImportError:
        return ("matplotlib is not installed here, so no chart: run `python benchmarks/bench_gpu_tensorf.py "
                "--out OUT --report-only` where it is.")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
    h = headline(results)
    for name, key, colour in (("ours (default)", "ours", "tab:blue"), ("TensoRF VM-192", "tensorf", "tab:orange")):
        pts = sorted((results.get(key) or {}).get("points", []), key=lambda p: p["seconds"])
        pts = [p for p in pts if p.get("psnr") is not None]
        if pts:
            ax.plot([p["seconds"] for p in pts], [p["psnr"] for p in pts], "o-", color=colour, label=name)
    if "tensorf_psnr" in h:
        ax.axhline(h["tensorf_psnr"], color="tab:orange", ls=":", lw=1)
        ax.axvline(h["tensorf_seconds"] * SPEED_TARGET, color="grey", ls="--", lw=1,
                   label=f"{SPEED_TARGET}x TensoRF's seconds")
    ax.set_xlabel("training seconds (evaluation not counted)")
    ax.set_ylabel("test PSNR (dB)")
    ax.set_title(f"{(results.get('machine') or {}).get('device_name', '?')}: test PSNR against training time")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return ""


def write_report(out_dir: str) -> tuple[str, str]:
    """summary.md (and the chart, where matplotlib is) from ``out_dir/results.json``; returns (md path, note)."""
    with open(os.path.join(out_dir, "results.json"), encoding="utf-8") as fh:
        results = json.load(fh)
    chart = "psnr_vs_seconds.png"
    note = draw_chart(results, os.path.join(out_dir, chart))
    md = summary_markdown(results, None if note else chart, note)
    path = os.path.join(out_dir, "summary.md")
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(md)
    return path, note

"""Writing a study's results: CSV and JSON tables, markdown tables and the charts.

Matplotlib (Agg backend, no display) is imported only when a chart is drawn.
"""
from __future__ import annotations

import csv
import json
import math
from typing import Optional, Sequence

import _bootstrap  # noqa: F401  (puts the repository on sys.path, for nerf_core; as in runner)
from nerf_core import contract  # standard library + numpy: no torch

from .analysis import pareto_front


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------


def write_csv(path: str, rows: Sequence[dict], columns: Optional[Sequence[str]] = None) -> None:
    """Rows of dicts -> CSV; columns default to the union of keys in first-seen order."""
    if columns is None:
        columns = []
        for row in rows:
            for key in row:
                if key not in columns:
                    columns.append(key)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(columns), extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(row.get(k)) for k in columns})


def _cell(value):
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return "" if value is None else value


def write_json(path: str, obj) -> None:
    """``obj`` as strict JSON: NaN and inf become null (``nerf_core.contract.json_safe``)."""
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(contract.json_safe(obj), fh, indent=1)


def fmt(value, digits: int = 2) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "nan"
        return f"{value:.{digits}f}"
    return str(value)


def markdown_table(rows: Sequence[dict], columns: Sequence[str], headers: Optional[Sequence[str]] = None,
                   digits: int = 2) -> str:
    headers = list(headers or columns)
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    for row in rows:
        out.append("| " + " | ".join(fmt(row.get(c), digits) for c in columns) + " |")
    return "\n".join(out)


def human_bytes(n: Optional[float]) -> str:
    if n is None:
        return "-"
    for unit in ("B", "KB", "MB", "GB"):
        if abs(n) < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n:.1f} GB"


# --------------------------------------------------------------------------------------------
# Charts (matplotlib, Agg backend: no display needed)
# --------------------------------------------------------------------------------------------


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _panel_grid(plt, n_panels: int, width: float = 4.6):
    """(fig, axes, cols): up to 3 panels a row, one per scene or study."""
    n = max(1, n_panels)
    cols = min(3, n)
    rows = int(math.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(width * cols, 3.6 * rows), squeeze=False)
    return fig, axes, cols


def _finish_figure(plt, fig, axes, n_used: int, title: str, path: str, legend_space: float = 0.1) -> str:
    """Hide unused panels, add one legend shared by all panels (each label once), save and close."""
    for ax in list(axes.flat)[n_used:]:
        ax.axis("off")
    handles, labels = [], []
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=min(4, len(labels)), fontsize=8)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, legend_space if handles else 0, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def chart_psnr_vs_time(curves: dict, path: str, title: str) -> str:
    """``curves``: {(scene, series): [(seconds, psnr), ...]} -> one line per series, one panel per scene."""
    plt = _plt()
    scenes = sorted({scene for scene, _ in curves})
    fig, axes, cols = _panel_grid(plt, len(scenes))
    series_names = sorted({s for _, s in curves})
    colours = {s: plt.cm.tab10(i % 10) for i, s in enumerate(series_names)}
    for k, scene in enumerate(scenes):
        ax = axes[k // cols][k % cols]
        for (sc, series), pts in sorted(curves.items()):
            pts = [(t, p) for t, p in pts if t is not None and p is not None and math.isfinite(p)]
            if sc != scene or not pts:
                continue
            xs, ys = zip(*sorted(pts))
            ax.plot(xs, ys, marker="o", ms=3, label=series, color=colours[series])
        ax.set_title(scene)
        ax.set_xlabel("training time (s)")
        ax.set_ylabel("test PSNR (dB)")
        ax.grid(alpha=0.3)
    return _finish_figure(plt, fig, axes, len(scenes), title, path, legend_space=0.08)


def _draw_size_points(ax, pts: Sequence[dict], colours: dict, legend: bool) -> None:
    """Scatter (params, psnr) of ``pts`` on ``ax`` with the Pareto front as a dashed step line, members ringed."""
    for p in pts:
        star = "auto" in p["series"]
        ax.scatter([p["params"]], [p["psnr"]], color=colours[p["series"]], label=p["series"] if legend else None,
                   zorder=3, marker="*" if star else "o", s=90 if star else 30)
    front = pareto_front([(p["params"], p["psnr"]) for p in pts])
    if front:
        fx = [pts[i]["params"] for i in front]
        fy = [pts[i]["psnr"] for i in front]
        ax.step(fx, fy, where="post", ls="--", color="k", lw=1, label="Pareto front" if legend else None)
        ax.scatter(fx, fy, s=160, facecolors="none", edgecolors="k", zorder=4)
    ax.set_xscale("log")
    # Labels at 1, 2 and 5 per decade: decades alone leave a panel spanning less than one unlabelled,
    # and every minor tick overlaps into an unreadable row.
    from matplotlib.ticker import EngFormatter, LogLocator, NullFormatter
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(EngFormatter(sep=""))  # 200k, 1M
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.grid(alpha=0.3, which="both")


def chart_psnr_vs_size(points: Sequence[dict], path: str, title: str, zoom_db: float = 2.0) -> str:
    """``points``: dicts with scene, series, params, psnr. Per scene, the Pareto front is drawn as a
    dashed step line and its members ringed. When the panel spans more than 2 ``zoom_db``, an inset
    repeats the points within ``zoom_db`` of the best: the sizes of the fast method usually differ by
    tenths of a dB, invisible beside a slow method 20 dB lower."""
    plt = _plt()
    scenes = sorted({p["scene"] for p in points})
    fig, axes, cols = _panel_grid(plt, len(scenes))
    series_names = sorted({p["series"] for p in points})
    colours = {s: plt.cm.tab10(i % 10) for i, s in enumerate(series_names)}
    for k, scene in enumerate(scenes):
        ax = axes[k // cols][k % cols]
        pts = [p for p in points if p["scene"] == scene and p.get("params") is not None and p.get("psnr") is not None
               and math.isfinite(p["psnr"])]
        _draw_size_points(ax, pts, colours, legend=True)
        ax.set_title(scene)
        ax.set_xlabel("parameters")
        ax.set_ylabel("final test PSNR (dB)")
        if pts:
            best = max(p["psnr"] for p in pts)
            near = [p for p in pts if p["psnr"] >= best - zoom_db]
            if len(near) > 1 and best - min(p["psnr"] for p in pts) > 2 * zoom_db:
                inset = ax.inset_axes([0.5, 0.1, 0.47, 0.5])
                _draw_size_points(inset, near, colours, legend=False)
                # A fixed 2-dB window, so a 0.05 dB gap looks as small as it is.
                inset.set_ylim(best - zoom_db, best + 0.15 * zoom_db)
                xs = [p["params"] for p in near]
                inset.set_xlim(min(xs) / 1.5, max(xs) * 1.5)
                inset.tick_params(labelsize=6)
                inset.set_title(f"within {zoom_db:g} dB of the best", fontsize=7)
    return _finish_figure(plt, fig, axes, len(scenes), title, path)


def chart_bars(groups: dict, path: str, title: str, ylabel: str, threshold: Optional[float] = None) -> str:
    """``groups``: {panel: {series: [(x_label, mean, spread), ...]}} -> grouped bars with error bars."""
    plt = _plt()
    panels = list(groups)
    fig, axes, cols = _panel_grid(plt, len(panels), width=4.8)
    all_series = sorted({s for g in groups.values() for s in g})
    colours = {s: plt.cm.tab10(i % 10) for i, s in enumerate(all_series)}
    for k, panel in enumerate(panels):
        ax = axes[k // cols][k % cols]
        series = groups[panel]
        labels = []
        for pts in series.values():
            for lab, _, _ in pts:
                if lab not in labels:
                    labels.append(lab)
        width = 0.8 / max(1, len(series))
        for j, (name, pts) in enumerate(sorted(series.items())):
            lookup = {lab: (m, s) for lab, m, s in pts}
            xs = [i + j * width for i in range(len(labels))]
            ms = [lookup.get(lab, (None, None))[0] for lab in labels]
            ss = [lookup.get(lab, (None, None))[1] or 0.0 for lab in labels]
            ax.bar(xs, [m if m is not None else 0.0 for m in ms], width, yerr=ss, label=name,
                   color=colours[name], capsize=2)
        ax.set_xticks([i + 0.4 - width / 2 for i in range(len(labels))])
        ax.set_xticklabels(labels, fontsize=8)
        if threshold is not None:
            ax.axhline(threshold, color="r", ls="--", lw=1, label="breakdown threshold")
        ax.set_title(panel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, axis="y")
    return _finish_figure(plt, fig, axes, len(panels), title, path)

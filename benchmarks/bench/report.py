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


# The comparison behind the seed's claim: the same MLP with and without positional encoding.
PAIR = ("nerf", "nerf-nope")
PAIR_COLOUR = "tab:blue"
# tab10 without its blue (the pair's) and its grey (the grid lines'), for every other series.
OTHER_COLOURS = ("tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive",
                 "tab:cyan")
# Labelled times on a log axis: the coarse set's neighbours are 2-3x apart, so their labels never
# collide; the fine set fills in when a short axis (a quick run's 20-40 s) holds fewer than 3 of them.
TIME_TICKS = ((1, "1 s"), (3, "3 s"), (10, "10 s"), (30, "30 s"), (60, "1 min"), (120, "2 min"), (300, "5 min"),
              (600, "10 min"), (1800, "30 min"), (3600, "1 h"), (7200, "2 h"))
FINE_TIME_TICKS = ((2, "2 s"), (5, "5 s"), (15, "15 s"), (20, "20 s"), (40, "40 s"), (90, "90 s"), (180, "3 min"),
                   (900, "15 min"), (1200, "20 min"))


def time_ticks(lo: float, hi: float) -> list[tuple[float, str]]:
    """(seconds, label) ticks inside [lo, hi] for a log time axis read in s and min: ``TIME_TICKS``, or
    with ``FINE_TIME_TICKS`` added when fewer than 3 coarse ones fall inside."""
    coarse = [(t, label) for t, label in TIME_TICKS if lo <= t <= hi]
    if len(coarse) >= 3:
        return coarse
    return sorted(coarse + [(t, label) for t, label in FINE_TIME_TICKS if lo <= t <= hi])


def series_styles(names, pair: Sequence[str] = PAIR) -> dict:
    """{series: plot keywords}. The two ``pair`` series share one hue, the first solid with filled
    markers, the second dashed with open ones, so they read as one comparison; every other series gets
    its own colour from ``OTHER_COLOURS``."""
    styles = {}
    others = [n for n in sorted(names) if n not in pair]
    for n in names:
        if n == pair[0]:
            styles[n] = {"color": PAIR_COLOUR, "ls": "-", "marker": "o", "mfc": PAIR_COLOUR}
        elif n == pair[1]:
            styles[n] = {"color": PAIR_COLOUR, "ls": "--", "marker": "o", "mfc": "white"}
        else:
            colour = OTHER_COLOURS[others.index(n) % len(OTHER_COLOURS)]
            styles[n] = {"color": colour, "ls": "-", "marker": "s", "mfc": colour}
    return styles


def _pair_band(ax, a: Sequence[tuple[float, float]], b: Sequence[tuple[float, float]], label: str) -> None:
    """Shade between two curves (interpolated in log time over the times both cover); write the last gap."""
    import numpy as np

    lo, hi = max(a[0][0], b[0][0]), min(a[-1][0], b[-1][0])
    grid = sorted({t for t, _ in (*a, *b) if lo <= t <= hi})
    if len(grid) < 2:
        return
    lg = np.log(grid)
    ya = np.interp(lg, np.log([t for t, _ in a]), [p for _, p in a])
    yb = np.interp(lg, np.log([t for t, _ in b]), [p for _, p in b])
    ax.fill_between(grid, ya, yb, color=PAIR_COLOUR, alpha=0.15, lw=0, label=label)
    ax.annotate(f"{ya[-1] - yb[-1]:+.1f} dB", (grid[-1], max(ya[-1], yb[-1])), xytext=(-3, 5),
                textcoords="offset points", ha="right", fontsize=7, color=PAIR_COLOUR)


def chart_psnr_vs_time(curves: dict, path: str, title: str, pair: Sequence[str] = PAIR) -> str:
    """``curves``: {(scene, series): [(seconds, psnr), ...]} -> one line per series, one panel per scene.

    Log time axis labelled in s and min, a marker at every evaluation. The ``pair`` series (nerf and
    nerf-nope) share a hue (solid and dashed) with the gap between them shaded and its last value
    written, so the encoding's effect reads at a glance beside the grid methods."""
    plt = _plt()
    from matplotlib.ticker import FixedLocator, FixedFormatter, NullFormatter

    scenes = sorted({scene for scene, _ in curves})
    fig, axes, cols = _panel_grid(plt, len(scenes))
    styles = series_styles({s for _, s in curves}, pair)
    gap_label = f"{pair[0]} \u2212 {pair[1]} gap"
    for k, scene in enumerate(scenes):
        ax = axes[k // cols][k % cols]
        drawn = {}
        for (sc, series), pts in sorted(curves.items()):
            pts = [(t, p) for t, p in pts if t is not None and t > 0 and p is not None and math.isfinite(p)]
            if sc != scene or not pts:
                continue
            drawn[series] = sorted(pts)
            xs, ys = zip(*drawn[series])
            ax.plot(xs, ys, ms=4, lw=1.5, label=series, **styles[series])
        if pair[0] in drawn and pair[1] in drawn:
            _pair_band(ax, drawn[pair[0]], drawn[pair[1]], gap_label)
        ax.set_xscale("log")
        if drawn:
            lo = min(t for pts in drawn.values() for t, _ in pts)
            hi = max(t for pts in drawn.values() for t, _ in pts)
            ax.set_xlim(lo / 1.3, hi * 1.3)
            ticks = time_ticks(lo / 1.3, hi * 1.3)
            if ticks:
                ax.xaxis.set_major_locator(FixedLocator([t for t, _ in ticks]))
                ax.xaxis.set_major_formatter(FixedFormatter([label for _, label in ticks]))
                ax.xaxis.set_minor_formatter(NullFormatter())
                ax.tick_params(axis="x", labelsize=8)  # "5 min" and "10 min" sit 0.3 decades apart
        ax.set_title(scene)
        ax.set_xlabel("training time (log scale)")
        ax.set_ylabel("test PSNR (dB)")
        ax.grid(alpha=0.3, which="major")
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


def draw_bar_panel(ax, series: dict, colours: dict, threshold: Optional[float] = None,
                   rules: Optional[dict] = None, rule_label: str = "breakdown rule") -> None:
    """One panel of ``chart_bars`` on ``ax``: grouped bars with whiskers, the absolute ``threshold``
    (solid red), and for each series in the panel with an entry in ``rules`` ({series: dB}) a dashed
    line at that level in the series' colour. The rule lines share one dash pattern at staggered
    offsets, so two methods with the same rule (nerf, nerf-nope) show both colours in turn instead of
    one hiding the other; one grey legend entry, ``rule_label``, stands for all of them. Bars whose
    point carries a true 4th element (broken) are hatched."""
    labels = []
    for pts in series.values():
        for pt in pts:
            if pt[0] not in labels:
                labels.append(pt[0])
    from matplotlib.patches import Rectangle
    from matplotlib.patheffects import withStroke

    width = 0.8 / max(1, len(series))
    any_broken = False
    for j, (name, pts) in enumerate(sorted(series.items())):
        lookup = {pt[0]: (pt[1], pt[2], len(pt) > 3 and bool(pt[3])) for pt in pts}
        xs = [i + j * width for i in range(len(labels))]
        got = [lookup.get(lab, (None, None, False)) for lab in labels]
        bars = ax.bar(xs, [m if m is not None else 0.0 for m, _, _ in got], width, yerr=[s or 0.0 for _, s, _ in got],
                      color=colours[name], capsize=2)
        # The legend's swatch: a plain patch, since a container's swatch is its first bar, which may be hatched.
        ax.add_patch(Rectangle((0, 0), 0, 0, color=colours[name], label=name))
        for bar, (_, _, broken) in zip(bars, got):
            if broken:  # white hatching over the method's colour: still its bar, visibly broken
                bar.set_hatch("////")
                bar.set_edgecolor("white")
                bar.set_linewidth(0)
                any_broken = True
    ax.set_xticks([i + 0.4 - width / 2 for i in range(len(labels))])
    ax.set_xticklabels(labels, fontsize=8)
    if threshold is not None:
        ax.axhline(threshold, color="r", ls="-", lw=1.2, label=f"breakdown floor: {threshold:g} dB")
    ruled = [name for name in sorted(series) if rules and rules.get(name) is not None]
    dash, gap = 4.0, 4.0 * max(1, len(ruled) - 1)
    for j, name in enumerate(ruled):
        # A white halo keeps the dashes visible where they cross a bar of their own colour.
        ax.axhline(rules[name], color=colours[name], lw=1.4, ls=(j * dash, (dash, gap)),
                   path_effects=[withStroke(linewidth=3, foreground="white")])
    if ruled:
        ax.plot([], [], color="0.35", lw=1.4, ls=(0, (dash, dash)), label=rule_label)  # the legend entry
    if any_broken:
        ax.add_patch(Rectangle((0, 0), 0, 0, facecolor="0.6", edgecolor="white", hatch="////", lw=0,
                               label="broken setting (hatched)"))


def chart_bars(groups: dict, path: str, title: str, ylabel: str, threshold: Optional[float] = None,
               rules: Optional[dict] = None, rule_label: str = "breakdown rule") -> str:
    """``groups``: {panel: {series: [(x_label, mean, spread[, broken]), ...]}} -> grouped bars with error
    bars, one panel each (``draw_bar_panel``: ``threshold``, per-series ``rules`` lines, hatched broken bars)."""
    plt = _plt()
    panels = list(groups)
    fig, axes, cols = _panel_grid(plt, len(panels), width=4.8)
    all_series = sorted({s for g in groups.values() for s in g})
    colours = {s: plt.cm.tab10(i % 10) for i, s in enumerate(all_series)}
    for k, panel in enumerate(panels):
        ax = axes[k // cols][k % cols]
        draw_bar_panel(ax, groups[panel], colours, threshold, rules, rule_label)
        ax.set_title(panel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, axis="y")
    return _finish_figure(plt, fig, axes, len(panels), title, path)

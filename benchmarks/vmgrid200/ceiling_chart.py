"""Draw vmgrid's test PSNR at 1 and 5 minutes against each scene's Cycles noise ceiling.

    python benchmarks/vmgrid200/ceiling_chart.py [--out docs/benchmarks/vmgrid200/ceiling.png]

Reads, from ``docs/benchmarks/vmgrid200/`` (``--folder``):
- ``baseline.json``: {scene: [[seconds, psnr, step], ...]}: vmgrid's default at commit 21beb97, the
  curve of each scene's benchmark run (the defaults are unchanged since);
- ``ceilings/<scene>.json``: ``scripts/noise_ceiling.py`` on the same captures;
- ``tight_grid.json`` (if present, same layout as ``baseline.json``): the same benchmark after the
  occupancy grid became tight by default (commit 5f20430), run after the evaluation fix 2c017ef;
- ``pixel_filter.json`` (if present, same layout): the same benchmark once evaluation rendered edge
  pixels through the capture's pixel filter (``nerf_core/image/pixel_filter.py``).

One row per scene: the 1- and 5-minute PSNR, issue 15's target (5-minute PSNR + 3 dB), the tight
grid's 5-minute PSNR, and the ceiling band from two Cycles renders of a view (left edge) to a
noise-free model (right edge, +3 dB).
"""
from __future__ import annotations

import argparse
import json
import os

# The results this chart draws live with the other vmgrid200 results (docs keeps results, benchmarks/ programs).
RESULTS = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                       "docs", "benchmarks", "vmgrid200")
ORDER = ("diffuse", "glossy", "multi", "thin", "highfreq", "hdri", "interior")


def load(folder: str):
    with open(os.path.join(folder, "baseline.json"), encoding="utf-8") as fh:
        curves = json.load(fh)
    five = {s: pts[-1][1] for s, pts in curves.items()}
    one = {s: next(p[1] for p in pts if p[0] >= 59) for s, pts in curves.items()}
    ceil = {}
    for s in ORDER:
        p = os.path.join(folder, "ceilings", f"{s}.json")
        if os.path.isfile(p):
            with open(p, encoding="utf-8") as fh:
                c = json.load(fh)
            ceil[s] = (c["psnr_two_renders"], c["model_ceiling"])
    tight, filtered = ({}, {})
    for name, into in (("tight_grid.json", tight), ("pixel_filter.json", filtered)):
        p = os.path.join(folder, name)
        if os.path.isfile(p):
            with open(p, encoding="utf-8") as fh:
                into.update({s: pts[-1][1] for s, pts in json.load(fh).items()})
    return one, five, ceil, tight, filtered


def draw(one, five, ceil, tight, out: str, filtered=None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = [s for s in ORDER if s in five and s in one]
    fig, ax = plt.subplots(figsize=(8.5, 0.62 * len(scenes) + 1.4), dpi=130)
    for y, s in enumerate(scenes):
        if s in ceil:
            lo, hi = ceil[s]
            ax.barh(y, hi - lo, left=lo, height=0.55, color="#d9d9d9", zorder=1,
                    label="noise ceiling: two renders .. noise-free model" if y == 0 else None)
        ax.plot([five[s] + 3] * 2, [y - 0.32, y + 0.32], color="#d62728", lw=2, zorder=2,
                label="target: 5 min + 3 dB" if y == 0 else None)
        ax.annotate("", xy=(five[s], y), xytext=(one[s], y),
                    arrowprops=dict(arrowstyle="->", color="#555555", lw=1.2), zorder=3)
        ax.plot(one[s], y, "o", color="#9ecae1", ms=7, zorder=4, label="1 min, defaults of 21beb97" if y == 0 else None)
        ax.plot(five[s], y, "o", color="#1f77b4", ms=8, zorder=5,
                label="5 min, defaults of 21beb97" if y == 0 else None)
        if s in tight:
            ax.plot(tight[s], y, "D", color="#2ca02c", ms=7, zorder=6,
                    label="5 min, tight occupancy grid (5f20430)" if y == 0 else None)
        if s in (filtered or {}):
            ax.plot(filtered[s], y, "*", color="#ff7f0e", ms=12, zorder=7,
                    label="5 min, rendered through the pixel filter" if y == 0 else None)
        if s in ceil:
            best = max(five[s], tight.get(s, five[s]), (filtered or {}).get(s, five[s]))
            ax.text(max(five[s] + 3, ceil[s][1]) + 0.4, y, f"{ceil[s][1] - best:.1f} dB to the ceiling",
                    va="center", fontsize=8.5)
    ax.set_yticks(range(len(scenes)), scenes)
    ax.invert_yaxis()
    ax.set_xlabel("test PSNR (dB), 200 px captures at 16 Cycles samples, one core per run")
    ax.set_title("vmgrid at 1 and 5 minutes against the Cycles noise ceiling")
    lo = min(one.values()) - 1.5
    hi = max([v[1] for v in ceil.values()] + [five[s] + 3 for s in scenes]) + 5.5
    ax.set_xlim(lo, hi)
    ax.grid(axis="x", alpha=0.3)
    ax.legend(loc="lower right", fontsize=8, framealpha=0.95)
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--folder", default=RESULTS, help="folder with baseline.json and ceilings/")
    ap.add_argument("--out", default=os.path.join(RESULTS, "ceiling.png"))
    args = ap.parse_args()
    one, five, ceil, tight, filtered = load(args.folder)
    draw(one, five, ceil, tight, args.out, filtered)
    print(args.out)


if __name__ == "__main__":
    main()

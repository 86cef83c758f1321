"""Where a trained run's remaining test error lies, against the capture's own Cycles noise.

    python benchmarks/vmgrid200/error_breakdown.py RUN DATASET RENDERS [RUN DATASET RENDERS ...] [--chart PNG]
        [--pixel-filter auto|none]

RENDERS is the folder that ``scripts/noise_ceiling.py --keep-renders RENDERS`` wrote for the same
DATASET (vVIEW.png: the test views rendered again with another seed). Each test view found there is
rendered from RUN on white, as ``eval`` scores it, and its pixels are split into four kinds by the
ground truth:

- background: nothing there (alpha < 0.01) and no silhouette near;
- silhouette: within one pixel of an alpha step of more than 0.05;
- texture edge: within one pixel of a brightness step of more than 0.05, on the object;
- flat: the rest of the object.

For each kind it prints the share of pixels, the model's mean squared error, one render's noise
variance (half the squared difference of the two renders) and the kind's share of the model's
*excess* error (its MSE minus the noise, which no model can remove). Prints a Markdown table;
``--chart PNG`` also draws both shares as stacked bars.
"""
from __future__ import annotations

import math
import os
import sys

import numpy as np
import torch

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from nerf_core.runs.checkpoints import load_run  # noqa: E402
from nerf_core.data.loading import load_cameras, load_split  # noqa: E402
from nerf_core.image.io import read_png  # noqa: E402
from nerf_core.methods.registry import available_methods  # noqa: E402
from nerf_core.image.pixel_filter import of_run  # noqa: E402
from nerf_core.render.frame import render_view  # noqa: E402

KINDS = ("background", "silhouette", "texture edge", "flat")


def _edges(x: torch.Tensor, step: float = 0.05) -> torch.Tensor:
    """(h, w) bool: pixels within one pixel of a step larger than ``step`` in the (h, w) image ``x``."""
    gx, gy = torch.zeros_like(x), torch.zeros_like(x)
    gx[:, 1:] = (x[:, 1:] - x[:, :-1]).abs()
    gy[1:] = (x[1:] - x[:-1]).abs()
    g = torch.maximum(gx, gy)
    return torch.nn.functional.max_pool2d(g[None, None], 3, 1, 1)[0, 0] > step


def kinds(gt: torch.Tensor, alpha: torch.Tensor) -> dict:
    """gt (h, w, 3) on white, alpha (h, w) -> {kind: (h, w) bool}, disjoint, covering the image."""
    sil = _edges(alpha)
    tex = (~sil) & _edges(gt.mean(-1)) & (alpha > 0.01)
    bg = (~sil) & (alpha < 0.01)
    return {"background": bg, "silhouette": sil, "texture edge": tex, "flat": ~(sil | tex | bg)}


def breakdown(run: str, dataset: str, renders: str, pixel_filter: str = "auto") -> dict:
    """``pixel_filter``: "auto" renders through the run's film filter, as ``eval`` does since 2ec864c;
    "none" one ray a pixel, as the published breakdown (summary.md) was rendered."""
    model, config, _ = load_run(run, torch.device("cpu"))
    film = of_run(config, pixel_filter)
    cams, frames = load_cameras(dataset, "test")
    split = load_split("test", frames, load_extras=False)
    white = torch.ones(3)
    sums = {k: [0.0, 0.0, 0] for k in KINDS}  # model squared error, noise variance, pixels
    views = sorted(int(f[1:-4]) for f in os.listdir(renders) if f.startswith("v") and f.endswith(".png"))
    if not views:
        raise SystemExit(f"{renders}: no vVIEW.png files (write them with noise_ceiling.py --keep-renders)")
    for v in views:
        with torch.no_grad():
            res = render_view(model, cams, v, background=(1.0, 1.0, 1.0), pixel_filter=film)
        gt, alpha = split.image(v, white)
        if alpha is None:
            alpha = torch.ones(gt.shape[:2])
        px = read_png(os.path.join(renders, f"v{v}.png"))  # 8-bit, as the capture writes
        other = torch.from_numpy(px.astype(np.float32) / float(np.iinfo(px.dtype).max))
        if other.shape[-1] == 4:
            other = other[..., :3] * other[..., 3:] + (1.0 - other[..., 3:])
        err = (res["rgb"] - gt).square().mean(-1)
        noise = (other[..., :3] - gt).square().mean(-1) / 2.0
        for k, m in kinds(gt, alpha).items():
            sums[k][0] += err[m].sum().item()
            sums[k][1] += noise[m].sum().item()
            sums[k][2] += int(m.sum())
    return {"views": views, "sums": sums}


def table(rows) -> str:
    lines = ["| run | model PSNR (pooled) | noise-free model | kind | pixels | model MSE | noise | "
             "share of the excess |",
             "|---|---|---|---|---|---|---|---|"]
    for name, r in rows:
        s = r["sums"]
        n = sum(v[2] for v in s.values())
        e, z = sum(v[0] for v in s.values()), sum(v[1] for v in s.values())
        for i, k in enumerate(KINDS):
            ke, kz, kn = s[k]
            head = (f"{name} | {-10 * math.log10(e / n):.2f} | {-10 * math.log10(z / n):.2f}" if i == 0 else " | | ")
            lines.append(f"| {head} | {k} | {kn / n:.3f} | {ke / max(kn, 1):.2e} | {kz / max(kn, 1):.2e} | "
                         f"{(ke - kz) / (e - z):.2f} |")
    return "\n".join(lines)


def run_name(run: str) -> str:
    """The run folder's name, or its parent's where the folder is named for the method (SCENE/vmgrid)."""
    parts = os.path.normpath(os.path.abspath(run)).split(os.sep)
    return parts[-2] if parts[-1] in available_methods() and len(parts) > 1 else parts[-1]


COLOURS = {"background": "#d9d9d9", "silhouette": "#d62728", "texture edge": "#ff7f0e", "flat": "#1f77b4"}


def chart(rows, out: str) -> None:
    """Two stacked bars a run: its pixels by kind, and its excess error (model MSE - noise) by kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 0.9 * len(rows) + 1.4))
    labels = []
    for r_i, (name, r) in enumerate(rows):
        s = r["sums"]
        n = sum(v[2] for v in s.values())
        excess = {k: max(0.0, s[k][0] - s[k][1]) for k in KINDS}
        total = sum(excess.values()) or 1.0
        for b_i, shares in enumerate(({k: s[k][2] / n for k in KINDS}, {k: excess[k] / total for k in KINDS})):
            y = 2.6 * r_i + b_i
            left = 0.0
            for k in KINDS:
                ax.barh(y, shares[k], left=left, color=COLOURS[k], edgecolor="white", height=0.85,
                        label=k if (r_i, b_i) == (0, 0) else None)
                if shares[k] >= 0.08:
                    ax.text(left + shares[k] / 2, y, f"{100 * shares[k]:.0f} %", ha="center", va="center",
                            fontsize=8, color="white" if k != "background" else "black")
                left += shares[k]
            labels.append((y, f"{name}: " + ("pixels" if b_i == 0 else "excess error")))
    ax.set_yticks([y for y, _ in labels], [t for _, t in labels], fontsize=8.5)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("share")
    ax.set_title("Where the error above the capture's noise lies")
    fig.legend(loc="lower center", ncol=4, fontsize=8.5, frameon=False)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main(argv) -> int:
    chart_out = None
    mode = "auto"
    if "--pixel-filter" in argv:  # auto | none, as `eval --pixel-filter`
        i = argv.index("--pixel-filter")
        if i + 1 >= len(argv) or argv[i + 1] not in ("auto", "none"):
            print("--pixel-filter needs auto or none", file=sys.stderr)
            return 2
        mode = argv[i + 1]
        argv = argv[:i] + argv[i + 2:]
    if "--chart" in argv:
        i = argv.index("--chart")
        if i + 1 >= len(argv):
            print("--chart needs a PNG path", file=sys.stderr)
            return 2
        chart_out = argv[i + 1]
        argv = argv[:i] + argv[i + 2:]
    if len(argv) < 3 or len(argv) % 3:
        print(__doc__.strip().split("\n\n")[1], file=sys.stderr)
        return 2
    torch.set_num_threads(max(1, (os.cpu_count() or 1)))
    rows = [(run_name(argv[i]), breakdown(argv[i], argv[i + 1], argv[i + 2], mode)) for i in range(0, len(argv), 3)]
    print(table(rows))
    if chart_out:
        chart(rows, chart_out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

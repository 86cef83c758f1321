"""Writing the view-dependence study: PSNR against time, the highlight crops, and summary.md.

Takes ``view_dependence.json`` (``benchmarks/view_dependence.py``); imports matplotlib (Agg) and torch
only when drawing.
"""
from __future__ import annotations

import os
from typing import Optional

NOVIEW = "-noview"
CROP = 32  # side of the highlight crop, in pixels of the capture


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _series(results: dict) -> dict:
    """(scene, method) -> run row."""
    return {(r["scene"], r["method"]): r for r in results["runs"]}


def _xy(row: dict):
    pts = sorted(row.get("points") or [], key=lambda p: p["budget"])
    return [p["seconds"] for p in pts], [p["psnr"] for p in pts]


def draw_chart(results: dict, path: str) -> None:
    """One panel per scene (rows) and method (columns): the method (solid) and its -noview (dashed)."""
    plt = _plt()
    runs = _series(results)
    scenes = list(dict.fromkeys(r["scene"] for r in results["runs"]))
    methods = list(dict.fromkeys(r["base_method"] for r in results["runs"]))
    fig, axes = plt.subplots(len(scenes), len(methods), figsize=(4.2 * len(methods), 3.3 * len(scenes)),
                             squeeze=False)
    for i, scene in enumerate(scenes):
        for j, method in enumerate(methods):
            ax = axes[i][j]
            for name, style, label in ((method, "-", "with view direction"),
                                       (method + NOVIEW, "--", "colour ignores it")):
                row = runs.get((scene, name))
                if row and row.get("points"):
                    x, y = _xy(row)
                    ax.plot(x, y, style, marker="o", ms=3, color="C0" if style == "-" else "C3", label=label)
            a, b = runs.get((scene, method)), runs.get((scene, method + NOVIEW))
            if a and b and a.get("points") and b.get("points"):
                gap = _xy(a)[1][-1] - _xy(b)[1][-1]
                ax.set_title(f"{scene} / {method}: gap {gap:+.2f} dB at the end", fontsize=10)
            else:
                ax.set_title(f"{scene} / {method}", fontsize=10)
            ax.set_xlabel("training seconds (1 thread each, pair run side by side)", fontsize=8)
            ax.set_ylabel("test PSNR (dB)")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def highlight_window(gt, alpha, side: int = CROP):
    """(top, left) of the ``side`` x ``side`` window centred on the brightest object pixel of ``gt``
    (h, w, 3) in [0, 1], object = ``alpha`` (h, w) > 0.99 (the background is never the highlight);
    clamped to the image."""
    import torch

    lum = gt.mean(-1).masked_fill(alpha <= 0.99, -1.0)
    k = int(torch.argmax(lum))
    h, w = lum.shape
    y, x = divmod(k, w)
    return min(max(0, y - side // 2), h - side), min(max(0, x - side // 2), w - side)


def pick_view(test) -> tuple[int, float]:
    """The test view whose object holds the brightest pixel (the strongest highlight), and its value."""
    import torch

    best, best_v = 0, -1.0
    for v in range(len(test)):
        gt, alpha = test.image(v, torch.tensor([1.0, 1.0, 1.0]))
        lum = gt.mean(-1).masked_fill(alpha <= 0.99, -1.0)
        if float(lum.max()) > best_v:
            best, best_v = v, float(lum.max())
    return best, best_v


def draw_crops(results: dict, out: str, path: str) -> Optional[dict]:
    """GT and every run's render of the first scene's most highlighted test view, whole and cropped.
    Returns the view, the window and each crop's PSNR (None when the first scene has no runs)."""
    import torch

    import nerf_core

    plt = _plt()
    scene = results["runs"][0]["scene"]
    rows = [r for r in results["runs"] if r["scene"] == scene and not r.get("error")]
    if not rows:
        return None
    ds = nerf_core.load_dataset(results["datasets"][scene])
    test = ds.split("test")
    view, peak = pick_view(test)
    gt, alpha = test.image(view, torch.tensor([1.0, 1.0, 1.0]))
    top, left = highlight_window(gt, alpha)
    images = [("ground truth", gt)]
    crop_psnr = {}
    for r in rows:
        model, config, _ = nerf_core.load_run(os.path.join(out, r["run"]), device=torch.device("cpu"))
        with torch.no_grad():
            rgb = nerf_core.render_view(model, test.cameras, view, background=(1.0, 1.0, 1.0), near=config["near"],
                                        far=config["far"], pixel_filter=ds.pixel_filter)["rgb"].clamp(0, 1)
        c, g = rgb[top:top + CROP, left:left + CROP], gt[top:top + CROP, left:left + CROP]
        crop_psnr[r["method"]] = float(nerf_core.psnr(c, g))
        images.append((r["method"], rgb))
    fig, axes = plt.subplots(2, len(images), figsize=(2.4 * len(images), 5.0), squeeze=False)
    for j, (name, img) in enumerate(images):
        axes[0][j].imshow(img.numpy())
        axes[0][j].add_patch(plt.Rectangle((left - 0.5, top - 0.5), CROP, CROP, fill=False, ec="red", lw=1))
        axes[0][j].set_title(name if j == 0 else f"{name}\ncrop {crop_psnr[name]:.1f} dB", fontsize=9)
        axes[1][j].imshow(img[top:top + CROP, left:left + CROP].numpy(), interpolation="nearest")
        for ax in (axes[0][j], axes[1][j]):
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(f"{scene}, test view {view}: the brightest highlight (red box, enlarged below)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"scene": scene, "view": view, "peak_luminance": round(peak, 4), "top": top, "left": left, "side": CROP,
            "crop_psnr": {k: round(v, 2) for k, v in crop_psnr.items()}}


def summary_markdown(results: dict, crops: Optional[dict]) -> str:
    runs = _series(results)
    marks = results["marks"]
    m = results.get("machine", {})
    lines = ["# View dependence: each method with and without the view direction", "",
             f"Command: `{results['command']}` at commit `{results['commit']}`, "
             f"{results.get('wall_minutes', '?')} min wall.",
             f"Machine: {m.get('cpu', '?')}, {m.get('cpus', '?')} cores, torch {m.get('torch', '?')}; load average "
             f"{m.get('load_avg', '?')} at the end. Each pair (M, M-noview) trained at the same time, one thread each, "
             "so both saw the same share of the machine. The machine was shared with other jobs, so absolute "
             "seconds are slower than on an idle one; the pair comparison is what counts.",
             f"Capture: {results['capture']} (Cycles, transparent film); test PSNR on {results['eval_views']} evenly "
             "spaced test views at each mark (`--eval-at`, training time only).", "",
             "![PSNR against time](view_dependence.png)", "",
             "| scene | method | " + " | ".join(f"{t:g} s" for t in marks) + " | steps |",
             "|---|---|" + "---|" * len(marks) + "---|"]
    for (scene, name), row in runs.items():
        by = {p["budget"]: p["psnr"] for p in row.get("points") or []}
        cells = [f"{by[t]:.2f}" if t in by and by[t] is not None else "-" for t in marks]
        lines.append(f"| {scene} | {name} | " + " | ".join(cells) + f" | {row.get('steps') or '-'} |")
    lines += ["", "Gap (with view direction minus without), dB:", "",
              "| scene | method | " + " | ".join(f"{t:g} s" for t in marks) + " |", "|---|---|" + "---|" * len(marks)]
    for (scene, name), row in runs.items():
        other = runs.get((scene, name + NOVIEW))
        if name.endswith(NOVIEW) or other is None:
            continue
        a = {p["budget"]: p["psnr"] for p in row.get("points") or []}
        b = {p["budget"]: p["psnr"] for p in other.get("points") or []}
        cells = [f"{a[t] - b[t]:+.2f}" if t in a and t in b else "-" for t in marks]
        lines.append(f"| {scene} | {name} | " + " | ".join(cells) + " |")
    if crops:
        lines += ["", "![Highlight crops](highlight_crops.png)", "",
                  f"Crops: {crops['scene']} test view {crops['view']}, a {crops['side']} px window at "
                  f"(top {crops['top']}, left {crops['left']}) centred on the brightest object pixel of all test "
                  "views (chosen from the ground truth alone). PSNR inside the crop: "
                  + ", ".join(f"{k} {v:.1f} dB" for k, v in crops["crop_psnr"].items()) + "."]
    return "\n".join(lines) + "\n"


def write_report(out: str, results: dict) -> list[str]:
    """Draw the chart and crops and write summary.md into ``out``; the paths written."""
    chart = os.path.join(out, "view_dependence.png")
    draw_chart(results, chart)
    crops_png = os.path.join(out, "highlight_crops.png")
    crops = draw_crops(results, out, crops_png)
    results["crops"] = crops
    summary = os.path.join(out, "summary.md")
    with open(summary, "w", encoding="utf-8") as fh:
        fh.write(summary_markdown(results, crops))
    return [chart] + ([crops_png] if crops else []) + [summary]

"""Writing the kernel-width study: the PSNR-against-sigma chart, the crops picture, JSON and README.md.

Takes the results of ``fourier2d.fit2d.sweep``; imports matplotlib (Agg) only when drawing.
"""
from __future__ import annotations

import json
import os
from typing import Dict, List, Sequence

import numpy as np

from fourier2d.fit2d import FitResult, even_grid_mask, summarize


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _write_atomic(path: str, write) -> None:
    """Write through a temporary file and a rename: an interrupted run leaves no half-written file."""
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.tmp{os.getpid()}")
    write(tmp)
    os.replace(tmp, path)


def _text_writer(text: str):
    def write(path: str) -> None:
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
    return write


def draw_chart(path: str, results: Sequence[FitResult], meta: Dict) -> None:
    """Held-out and train PSNR against sigma (log axis); none and best PE as horizontal lines."""
    plt = _plt()
    picks = summarize(results)
    rff = sorted((r for r in results if r.spec.kind == "rff"), key=lambda r: r.spec.sigma)
    sig = [r.spec.sigma for r in rff]
    fig, ax = plt.subplots(figsize=(7.5, 4.6), dpi=120)
    ax.plot(sig, [r.test_psnr for r in rff], "o-", color="C3", lw=2, label="Fourier features: held-out pixels")
    ax.plot(sig, [r.train_psnr for r in rff], "s--", color="C3", alpha=0.5, label="Fourier features: training pixels")
    none, pe = picks["none"], picks["pe"]
    ax.axhline(none.test_psnr, color="0.35", lw=1.5, label=f"no encoding: held-out ({none.test_psnr:.1f} dB)")
    ax.axhline(pe.test_psnr, color="C0", lw=1.5,
               label=f"positional encoding L={pe.spec.n_freqs}: held-out ({pe.test_psnr:.1f} dB)")
    nyq = meta["config"]["nyquist"]
    ax.axvline(nyq, color="0.6", ls=":", lw=1)
    # x in data units, y in axes units: the label sits mid-height, clear of the curves' ends.
    ax.text(nyq, 0.5, " Nyquist rate of\n the training grid", color="0.45", fontsize=8, va="center",
            transform=ax.get_xaxis_transform())
    best = picks["best"]
    ax.annotate(f"best σ={best.spec.sigma:g}", (best.spec.sigma, best.test_psnr), xytext=(0, 10),
                textcoords="offset points", ha="center", fontsize=9, color="C3")
    ax.set_xscale("log")
    ax.set_xlabel("σ of the Gaussian Fourier features (cycles per image width)")
    ax.set_ylabel("PSNR (dB)")
    img = meta["image"]
    ax.set_title(f"Kernel width: {os.path.basename(img['source'])} crop, {img['size'][0]} px, "
                 f"train on 1/4 of the pixels, {meta['config']['steps']} steps", fontsize=10)
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    _write_atomic(path, lambda p: fig.savefig(p, format="png"))
    plt.close(fig)


def _zoom_box(h: int, w: int, side: int) -> tuple:
    """(top, left, side) of the zoomed square: the lower-middle of the image (the fence, by default)."""
    side = min(side, h, w)
    return (max(0, h - side - h // 8), (w - side) // 2, side)


def draw_crops(path: str, image: np.ndarray, results: Sequence[FitResult]) -> None:
    """Ground truth, none, best PE, best / too-small / too-large sigma: full frame above, 4x zoom below."""
    plt = _plt()
    picks = summarize(results)
    panels = [("ground truth\n(training pixels: every 2nd row and column)", image, None)]
    for key, label in (("none", "no encoding"), ("pe", f"positional enc. L={picks['pe'].spec.n_freqs}"),
                       ("too_small", f"too small σ={picks['too_small'].spec.sigma:g}"),
                       ("best", f"best σ={picks['best'].spec.sigma:g}"),
                       ("too_large", f"too large σ={picks['too_large'].spec.sigma:g}")):
        r = picks[key]
        panels.append((f"{label}\nheld-out {r.test_psnr:.1f} dB, train {r.train_psnr:.1f} dB", r.image, r))
    h, w = image.shape[:2]
    top, left, side = _zoom_box(h, w, max(16, h // 4))
    fig, axes = plt.subplots(2, len(panels), figsize=(2.6 * len(panels), 5.6), dpi=110)
    for col, (title, img, _) in enumerate(panels):
        axes[0, col].imshow(np.clip(img, 0, 1), interpolation="nearest")
        axes[0, col].add_patch(plt.Rectangle((left - 0.5, top - 0.5), side, side, fill=False, ec="w", lw=1))
        axes[0, col].set_title(title, fontsize=8)
        axes[1, col].imshow(np.clip(img[top:top + side, left:left + side], 0, 1), interpolation="nearest")
        for ax in axes[:, col]:
            ax.set_xticks([])
            ax.set_yticks([])
    axes[1, 0].set_ylabel("zoom (white box)", fontsize=8)
    fig.suptitle("Reconstructions at every pixel; 3 of every 4 were never trained on", fontsize=10)
    fig.tight_layout()
    _write_atomic(path, lambda p: fig.savefig(p, format="png"))
    plt.close(fig)


def markdown(results: Sequence[FitResult], meta: Dict) -> str:
    """README.md for the output folder: what was fitted, the table, and the command."""
    picks = summarize(results)
    img, cfg = meta["image"], meta["config"]
    lines = [
        "# Kernel width: positional encoding and Fourier features on one photograph", "",
        f"Image: `{os.path.basename(img['source'])}`" + ("" if img["source"] == "synthetic" else
                                                         f" (Blender studio light), crop (top, left, "
                                                         f"side) {img['crop']}, "
                                                         f"downscale {img['downscale']}, tone map {img['tonemap']}") +
        f"; {img['size'][0]} x {img['size'][1]} px. Trained on the even-row, even-column pixels "
        "(a quarter), scored on the other three quarters.", "",
        f"Every model: MLP of {cfg['depth']} linear layers x {cfg['width']} (ReLU, sigmoid out), full-batch Adam "
        f"lr {cfg['lr']:g}, {cfg['steps']} steps, seed {cfg['seed']}, {cfg['features']} Gaussian Fourier "
        f"features for RFF. σ is in cycles per image width; the training grid's Nyquist rate is {cfg['nyquist']:g}.",
        "",
        "| model | held-out PSNR (dB) | train PSNR (dB) | parameters | seconds |", "|---|---|---|---|---|",
    ]
    for r in results:
        bold = "**" if r in (picks["best"], picks["pe"]) else ""
        lines.append(f"| {r.spec.name} | {bold}{r.test_psnr:.2f}{bold} | {r.train_psnr:.2f} | "
                     f"{r.params:,} | {r.seconds:.0f} |")
    m = meta["machine"]
    lines += ["",
              f"Seconds are wall time on a shared {m['cpus']}-CPU machine ({m['cpu']}, load average "
              f"{m['load_avg_end']} "
              f"at the end, {cfg['jobs']} fits at a time): not a speed measurement.", "",
              f"Run on {meta['date']}, torch {m['torch']}:", "", "```bash", meta["command"], "```", ""]
    return "\n".join(lines)


def write_all(out: str, photo, results: List[FitResult], meta: Dict) -> None:
    """DIR/kernel_width.json, kernel_width.png, kernel_width_crops.png, README.md."""
    picks = summarize(results)
    h, w = photo.image.shape[:2]
    data = dict(meta, results=[r.as_dict() for r in results],
                picks={k: r.spec.name for k, r in picks.items()},
                train_pixels=int(even_grid_mask(h, w).sum()), held_out_pixels=int((~even_grid_mask(h, w)).sum()))
    _write_atomic(os.path.join(out, "kernel_width.json"),
                  _text_writer(json.dumps(data, indent=1, ensure_ascii=False) + "\n"))
    draw_chart(os.path.join(out, "kernel_width.png"), results, meta)
    draw_crops(os.path.join(out, "kernel_width_crops.png"), photo.image, results)
    _write_atomic(os.path.join(out, "README.md"),
                  _text_writer(markdown(results, meta)))

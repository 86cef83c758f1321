"""Centre rays against the film's pixel filter, on the edges of one test view.

    python benchmarks/vmgrid200/pixel_filter_crops.py RUN --out pixel_filter.png [--view K] [--crop 48]

Renders test view K of RUN's dataset twice, as ``eval`` scores it: with one ray through each pixel
centre (``--pixel-filter none``) and through the dataset's pixel filter (the default: edge pixels are
the mean of 9 rays drawn from it). Draws the ground truth, both renders and their error maps (absolute
error, x4) on the crop of ``--crop`` px around the pixel with the largest centre-ray error there, each
labelled with the PSNR of the whole view. Prints both PSNRs and the share of pixels refined.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np
import torch

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from nerf_core.runs.checkpoints import load_run  # noqa: E402
from nerf_core.data.loading import load_dataset  # noqa: E402
from nerf_core.render.scoring import score_view  # noqa: E402
from nerf_core.image.pixel_filter import edge_pixels  # noqa: E402
from nerf_core.render.frame import render_view  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run")
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("--view", type=int, default=0)
    ap.add_argument("--crop", type=int, default=48)
    a = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    model, config, _ = load_run(a.run, torch.device("cpu"))
    ds = load_dataset(config["dataset"], splits=("test",))
    sp = ds.split("test")
    bg = tuple(config.get("eval_background", [1.0, 1.0, 1.0]))
    kw = dict(background=bg, near=config.get("near"), far=config.get("far"))
    centre = render_view(model, sp.cameras, a.view, **kw)
    filtered = render_view(model, sp.cameras, a.view, pixel_filter=ds.pixel_filter, **kw)
    gt, _ = sp.image(a.view, bg)
    p_centre = score_view(centre["rgb"], sp, a.view, bg)[0]["psnr"]
    p_filter = score_view(filtered["rgb"], sp, a.view, bg)[0]["psnr"]
    share = float(edge_pixels(torch.cat([centre["rgb"], centre["acc"][..., None]], -1)).float().mean())
    print(f"view {a.view}: centre rays {p_centre:.2f} dB, pixel filter {p_filter:.2f} dB "
          f"({100 * share:.1f} % of the pixels refined, {ds.pixel_filter})")

    err_c = (centre["rgb"] - gt).abs().mean(-1)
    h, w = err_c.shape
    c = a.crop
    # the crop around the worst centre-ray pixel (smoothed, so one noisy pixel does not choose it)
    smooth = torch.nn.functional.avg_pool2d(err_c[None, None], 9, 1, 4)[0, 0]
    y, x = divmod(int(smooth.argmax()), w)
    y0, x0 = min(max(0, y - c // 2), h - c), min(max(0, x - c // 2), w - c)
    sl = (slice(y0, y0 + c), slice(x0, x0 + c))
    tiles = [("Cycles (ground truth)", gt[sl].numpy(), None),
             (f"centre rays: {p_centre:.2f} dB", centre["rgb"][sl].numpy(), None),
             (f"pixel filter: {p_filter:.2f} dB", filtered["rgb"][sl].numpy(), None),
             ("", None, None),
             ("|error| x4, centre rays", None, (centre["rgb"] - gt).abs()[sl].numpy()),
             ("|error| x4, pixel filter", None, (filtered["rgb"] - gt).abs()[sl].numpy())]
    fig, axes = plt.subplots(2, 3, figsize=(9, 6.4))
    for ax, (title, img, err) in zip(axes.ravel(), tiles):
        ax.axis("off")
        if img is not None:
            ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
        elif err is not None:
            ax.imshow(np.clip(4 * err, 0, 1), interpolation="nearest")
        ax.set_title(title, fontsize=10)
    axes[1, 0].text(0.0, 0.5, f"test view {a.view}, crop {c}x{c} px\nat ({x0}, {y0}) of {w}x{h}\n"
                    f"{100 * share:.1f} % of the view's pixels\nrefined with 9 filter rays",
                    fontsize=10, va="center", transform=axes[1, 0].transAxes)
    fig.suptitle("Rendering a pixel as Cycles does: the mean over its pixel filter at edges", fontsize=11)
    fig.tight_layout()
    fig.savefig(a.out, dpi=110)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The README's real-scenes picture: for each benchmark run, three evenly spaced test views, Cycles
beside the NeRF (the run's latest checkpoint, rendered as `render` would: opaque with its learned world,
else onto the run's evaluation background).

    python benchmarks/real/real_scenes.py OUT.png "LABEL" RUN [RUN ...]
e.g. RUN = bench_real/runs/hdri/vmgrid and bench_real/runs/interior/vmgrid from benchmarks/benchmark.py.
"""
import json
import os
import sys

import numpy as np
import torch
from PIL import Image, ImageDraw

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
from nerf_core import contract  # noqa: E402
from nerf_core.runs.checkpoints import load_run  # noqa: E402
from nerf_core.data.loading import load_dataset  # noqa: E402
from nerf_core.render.frame import render_view  # noqa: E402


def row(run: str, n_views: int = 3):
    model, cfg, _ = load_run(run, torch.device("cpu"))
    ds = load_dataset(cfg["dataset"], splits=("test",))
    split = ds.splits["test"]
    bg = tuple(cfg.get("eval_background") or (1.0, 1.0, 1.0))
    tiles = []
    for v in contract.evenly_spaced(len(split), n_views):
        gt = split.images[v][..., :3].float().numpy() / 255.0
        pred = render_view(model, split.cameras, v, background=bg, near=ds.near, far=ds.far)["rgb"].numpy()
        tiles += [gt, pred]
    metrics = json.load(open(contract.metrics_path(run)))
    return np.concatenate(tiles, 1), metrics.get("psnr")


def main(out: str, label: str, runs):
    torch.set_num_threads(1)
    rows, notes = [], []
    for run in runs:
        img, psnr = row(run)
        rows.append(img)
        notes.append(f"{os.path.basename(os.path.dirname(os.path.normpath(run)))} ({psnr:.1f} dB)")
    body = (np.concatenate(rows, 0).clip(0, 1) * 255).astype(np.uint8)
    h, w = body.shape[:2]
    tile = w // 6
    canvas = Image.new("RGB", (w, h + 40), "white")
    canvas.paste(Image.fromarray(body), (0, 20))
    draw = ImageDraw.Draw(canvas)
    for k in range(6):
        draw.text((k * tile + 4, 4), "Cycles" if k % 2 == 0 else f"NeRF ({label})", fill="black")
    draw.text((4, h + 24), "rows: " + ", ".join(notes) + "; test PSNR over all 20 test views", fill="black")
    canvas.save(out)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3:])

"""Interior demo scene, two test views: Cycles | without gradient scaling | with it, colour and depth.

Made from two 400-step runs on the benchmark's interior capture (benchmarks/benchmark.py --scenes interior
--resolution 160 --views 100 --test-views 20 --samples 64):
    python -m nerf_core train DATASET --out BASE --max-steps 400 --eval-views 5 --set grad_reach=0
    python -m nerf_core train DATASET --out SCALED --max-steps 400 --eval-views 5
    python benchmarks/real/interior_fog.py DATASET BASE SCALED docs/images/interior_fog.png
"""
import sys, torch, numpy as np
sys.path.insert(0,
                __import__("os").path.join(__import__("os").path.dirname(__import__("os").path.abspath(__file__)), "..",
                                           ".."))
from nerf_core.runs.checkpoints import load_run
from nerf_core.render.frame import render_view
from nerf_core.data.loading import load_dataset
import matplotlib; matplotlib.use("Agg"); import matplotlib.pyplot as plt
torch.set_num_threads(1)
dataset, base, scaled, out = sys.argv[1:5]
runs = [("no gradient scaling", base), ("gradient scaled near the cameras", scaled)]
ds = load_dataset(dataset, splits=("test",))
s = ds.splits["test"]
views = [0, 8]
fig, axes = plt.subplots(2 * len(views), 3, figsize=(9, 6.2 * len(views)), constrained_layout=True)
for r, v in enumerate(views):
    gt = s.images[v][..., :3].float().numpy() / 255.0
    axes[2 * r, 0].imshow(gt); axes[2 * r, 0].set_title(f"Cycles, test view {v}")
    axes[2 * r + 1, 0].axis("off")
    for c, (name, run) in enumerate(runs, start=1):
        model, cfg, _ = load_run(run, torch.device("cpu"))
        res = render_view(model, s.cameras, v, background=(0.5, 0.5, 0.5), near=ds.near, far=ds.far)
        pred = res["rgb"].numpy()
        psnr = -10 * np.log10(((pred - gt) ** 2).mean())
        axes[2 * r, c].imshow(pred); axes[2 * r, c].set_title(f"{name}\n{psnr:.1f} dB (400 steps)")
        im = axes[2 * r + 1, c].imshow(res["depth"].numpy(), cmap="viridis", vmin=0, vmax=4)
        axes[2 * r + 1, c].set_title(f"depth, median {np.median(res['depth'].numpy()):.2f} m")
    cb = fig.colorbar(im, ax=axes[2 * r + 1, 0], location="left", shrink=0.8)
    cb.set_label("distance along the ray (m)")
for a in axes.flat:
    a.set_xticks([]); a.set_yticks([])
fig.suptitle("Interior demo scene: cameras inside the room grow fog in front of their lenses\n"
             "unless gradients near each camera are scaled by (distance / reach)^2", fontsize=11)
fig.savefig(out, dpi=80)

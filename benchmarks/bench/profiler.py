"""Where a training step's time goes: an in-process profile split into named stages.

The methods mark their own stages (``nerf_core.utils.profiling.stage``: ``sampling``, ``field``,
``rendering``); this module's driver loop runs a few training steps with a ``StageRecorder`` active
and marks the rest of each step itself: the training hook and the forward pass outside the methods'
stages (``other_forward``), the backward pass and the optimiser step. Time is exclusive: a stage
nested in another is charged to the inner one, so the shares add up to the whole step.

The one place the benchmark imports torch and nerf_core directly (inside ``profile_method``).
"""
from __future__ import annotations

import json
import os

# Report order; the first three are marked inside nerf_core, the rest by ``profile_method``.
STAGES = ("sampling", "field", "rendering", "other_forward", "backward", "optimizer")


def training_rays(dataset: str, n_rays: int, seed: int = 0):
    """A random batch of training rays (origins, directions, near, far, rgb, alpha) from the train split,
    computed from the JSON with the contract's pixel convention so the profile needs no loader API."""
    import numpy as np
    from PIL import Image

    rng = np.random.default_rng(seed)
    with open(os.path.join(dataset, "transforms_train.json"), encoding="utf-8") as fh:
        meta = json.load(fh)
    frames = meta["frames"]
    w, h = int(meta["w"]), int(meta["h"])
    fx, fy, cx, cy = (float(meta[k]) for k in ("fl_x", "fl_y", "cx", "cy"))
    images = []
    for f in frames[: min(len(frames), 8)]:
        path = os.path.join(dataset, f["file_path"])
        path = path if os.path.splitext(path)[1] else path + ".png"
        with Image.open(path) as im:
            images.append((np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0, np.asarray(f["transform_matrix"])))
    v = rng.integers(0, len(images), n_rays)
    i = rng.integers(0, w, n_rays)
    j = rng.integers(0, h, n_rays)
    d_cam = np.stack([(i + 0.5 - cx) / fx, -(j + 0.5 - cy) / fy, -np.ones(n_rays)], -1)
    c2w = np.stack([images[k][1] for k in v])
    d = np.einsum("nij,nj->ni", c2w[:, :3, :3], d_cam)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = c2w[:, :3, 3]
    rgba = np.stack([images[k][0][jj, ii] for k, ii, jj in zip(v, i, j)])
    aabb = np.asarray(meta["aabb"], dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (aabb[0] - o) / d
        t1 = (aabb[1] - o) / d
    tmin = np.nanmax(np.minimum(t0, t1), -1)
    tmax = np.nanmin(np.maximum(t0, t1), -1)
    near = np.maximum(tmin, float(meta.get("near", 0.0)))
    far = np.minimum(tmax, float(meta.get("far", 1e9)))
    far = np.maximum(far, near + 1e-3)  # rays missing the box: an empty interval the model still accepts
    return o, d, near, far, rgba, aabb


def profile_method(dataset: str, method: str, steps: int = 20, n_rays: int = 1024) -> dict:
    """Time ``steps`` training steps of ``method`` (after 2 warm-up steps) on ``n_rays`` random training
    rays of ``dataset``, split into ``STAGES``. Returns seconds per stage, their shares and seconds per
    step; CUDA is synchronised at every stage boundary when it is the device."""
    import torch

    from nerf_core.methods.registry import build_model
    from nerf_core.utils.profiling import StageRecorder

    o, d, near, far, rgba, aabb = training_rays(dataset, n_rays)
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    sync = torch.cuda.synchronize if device.type == "cuda" else None
    as_t = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)  # noqa: E731
    rays_o, rays_d, t_near, t_far = as_t(o), as_t(d), as_t(near), as_t(far)
    # Composite on white, as the trainer and the original loaders do.
    target = as_t(rgba[:, :3] * rgba[:, 3:] + (1 - rgba[:, 3:]))
    background = torch.ones_like(target)
    model = build_model(method, as_t(aabb)).to(device)
    opt = torch.optim.Adam(model.param_groups(1e-2))
    warmup = 2
    with StageRecorder(sync) as rec:
        for step in range(steps + warmup):
            if step == warmup:
                rec.reset()
            # The hook (occupancy updates, growth) and the forward pass; the methods' own marks inside
            # take their share, the remainder is "other_forward".
            with rec.stage("other_forward"):
                if model.training_hook(step, None):
                    opt = torch.optim.Adam(model.param_groups(1e-2))
                out = model.render_rays(rays_o, rays_d, t_near, t_far, background, training=True)
                loss, _ = model.loss(out, target, None)
            with rec.stage("backward"):
                opt.zero_grad(set_to_none=True)
                loss.backward()
            with rec.stage("optimizer"):
                opt.step()
    stages = {k: rec.totals.get(k, 0.0) for k in STAGES}
    total = sum(stages.values()) or 1.0
    return {"method": method, "steps": steps, "rays": n_rays, "device": str(device),
            "seconds": stages, "seconds_per_step": total / steps,
            "shares": {k: v / total for k, v in stages.items()}}

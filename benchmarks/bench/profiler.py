"""Where a training step's time goes: an in-process profile split into named stages.

The methods mark their own stages (``nerf_core.utils.profiling.stage``: ``sampling``, ``field``,
``rendering``); this module's driver loop runs a few training steps with a ``StageRecorder`` active
and marks the rest of each step itself: the training hook and the forward pass outside the methods'
stages (``other_forward``), the backward pass and the optimiser step. Time is exclusive: a stage
nested in another is charged to the inner one, so the shares add up to the whole step.

The one place the benchmark imports torch and nerf_core directly (inside ``profile_method``).
"""
from __future__ import annotations

# Report order; the first three are marked inside nerf_core, the rest by ``profile_method``.
STAGES = ("sampling", "field", "rendering", "other_forward", "backward", "optimizer")


def training_batch(dataset: str, model, n_rays: int, device, seed: int = 0):
    """``(batch, near, far)``: a ``RayBatch`` of ``n_rays`` random training rays of ``dataset``, drawn by
    the method's own batcher (``model.make_batcher``) from the train split as the library loads it
    (any layout ``load_dataset`` reads), on white, and the dataset's ray bounds."""
    import torch

    from nerf_core.data.loading import load_dataset

    ds = load_dataset(dataset)
    batcher = model.make_batcher(ds.split("train"), "white", torch.Generator().manual_seed(seed), device)
    return batcher.sample(n_rays), ds.near, ds.far


def dataset_box(dataset: str):
    """The (2, 3) scene box the library's loader gives ``dataset``."""
    from nerf_core.data.loading import load_dataset

    return load_dataset(dataset).aabb


def profile_method(dataset: str, method: str, steps: int = 20, n_rays: int = 1024) -> dict:
    """Time ``steps`` training steps of ``method`` (after 2 warm-up steps) on ``n_rays`` random training
    rays of ``dataset``, split into ``STAGES``. Returns seconds per stage, their shares and seconds per
    step; CUDA is synchronised at every stage boundary when it is the device."""
    import torch

    from nerf_core.engine.optim import make_optimizer, rebuild_optimizer
    from nerf_core.methods.registry import build_model
    from nerf_core.utils.profiling import StageRecorder

    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    sync = torch.cuda.synchronize if device.type == "cuda" else None
    model = build_model(method, dataset_box(dataset)).to(device).train()
    batch, near, far = training_batch(dataset, model, n_rays, device)
    opt = make_optimizer(model, 1e-2)
    warmup = 2
    with StageRecorder(sync) as rec:
        for step in range(steps + warmup):
            if step == warmup:
                rec.reset()
            # The hook (occupancy updates, growth) and the forward pass; the methods' own marks inside
            # take their share, the remainder is "other_forward".
            with rec.stage("other_forward"):
                if model.training_hook(step, None):
                    opt = rebuild_optimizer(model, opt, 1e-2)
                out = model.render_batch(batch.rays_o, batch.rays_d, batch.background, near, far, training=True)
                loss, _ = model.loss(out, batch.target, batch.weight)
            with rec.stage("backward"):
                opt.zero_grad(set_to_none=True)
                loss.backward()
            with rec.stage("optimizer"):
                model.optimizer_step(opt, out)
    stages = {k: rec.totals.get(k, 0.0) for k in STAGES}
    total = sum(stages.values()) or 1.0
    return {"method": method, "steps": steps, "rays": n_rays, "device": str(device),
            "seconds": stages, "seconds_per_step": total / steps,
            "shares": {k: v / total for k, v in stages.items()}}

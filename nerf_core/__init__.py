"""nerf_core: a standalone, CPU-first PyTorch NeRF library (CUDA when there is one).

The public surface is ``__all__`` below (``docs/API.md`` lists the same names, and a test keeps the two
equal). Names load lazily, so ``import nerf_core`` imports no torch; the first use of a name imports
its module. Everything else is internal and may change; its layers are in ``docs/ARCHITECTURE.md``.

    import nerf_core
    ds = nerf_core.load_dataset("scene_dataset")
    nerf_core.train(nerf_core.TrainConfig(dataset="scene_dataset", out="runs/scene", max_seconds=60))
    run = nerf_core.open_run("runs/scene")
    out = run.render(run.dataset.split("test").cameras, 0)

``nerf_core.volume`` holds the volume-rendering functions, nerfacc-style (flat functions with
shapes in their docstrings).
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> the module that defines it (one home each)
_HOMES = {
    # datasets
    "load_dataset": "nerf_core.data.loading",
    "load_cameras": "nerf_core.data.loading",
    "Dataset": "nerf_core.data.split",
    "Split": "nerf_core.data.split",
    "RayBatcher": "nerf_core.data.batcher",
    # cameras and rays
    "Cameras": "nerf_core.cameras.rays",
    "rays_for_view": "nerf_core.cameras.rays",
    # methods and their registry
    "RadianceModel": "nerf_core.methods.base",
    "register": "nerf_core.methods.registry",
    "build_model": "nerf_core.methods.registry",
    "available_methods": "nerf_core.methods.registry",
    # training
    "TrainConfig": "nerf_core.engine.config",
    "train": "nerf_core.engine.trainer",
    # a trained run
    "open_run": "nerf_core.render.run",
    "Run": "nerf_core.render.run",
    "load_run": "nerf_core.runs.checkpoints",
    # rendering
    "render_view": "nerf_core.render.frame",
    "render_run": "nerf_core.render.views",
    # evaluation
    "evaluate_split": "nerf_core.evaluation.evaluate",
    "evaluate_run": "nerf_core.evaluation.evaluate",
    # checking a dataset
    "check_dataset": "nerf_core.check.dataset",
    # metrics
    "psnr": "nerf_core.image.metrics",
    "ssim": "nerf_core.image.metrics",
    "depth_mae": "nerf_core.image.metrics",
    # errors
    "DatasetError": "nerf_core.errors",
    "PoseError": "nerf_core.errors",
    "TrainError": "nerf_core.errors",
    "RunError": "nerf_core.errors",
    "CheckpointRefused": "nerf_core.errors",
    "ImageReadError": "nerf_core.errors",
}
_SUBMODULES = ("volume",)

__all__ = sorted(_HOMES) + list(_SUBMODULES) + ["__version__"]


def __getattr__(name: str):
    """Load a public name on first use (PEP 562), so that ``import nerf_core`` stays light."""
    if name in _HOMES:
        value = getattr(importlib.import_module(_HOMES[name]), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f"nerf_core.{name}")
    else:
        raise AttributeError(f"module 'nerf_core' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))

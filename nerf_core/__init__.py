"""nerf_core: a standalone, CPU-first PyTorch NeRF library.

Imports no ``bpy``, and nothing at import time (the add-on imports ``nerf_core.contract``, the
shared rules in standard library + numpy, inside Blender without torch). Modules: ``contract``,
``cameras`` (rays), ``data`` (dataset loading), ``dataset_checks``, ``metrics``, ``encodings``,
``fields``, ``sampling``, ``occupancy``, ``volrend`` (volume rendering), ``losses``, ``methods`` (named
models), ``train``, ``evaluate``, ``render``, ``check`` and ``cli`` (``python -m nerf_core``).
"""
__version__ = "0.1.0"

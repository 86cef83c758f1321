"""nerf_core: a standalone, CPU-first PyTorch NeRF library.

Imports no ``bpy``. Modules: ``cameras`` (intrinsics, rays), ``data`` (dataset loading),
``encodings``, ``fields``, ``sampling``, ``occupancy``, ``volrend`` (volume rendering), ``losses``,
``methods`` (named models), ``train``, ``evaluate``, ``render``, ``check`` and ``cli``
(``python -m nerf_core``).
"""
__version__ = "0.1.0"

"""nerf_core: a standalone, CPU-first PyTorch NeRF library.

Imports no ``bpy``, and no torch at import time (the add-on imports ``nerf_core.contract``, the
shared rules in standard library + numpy, inside Blender without torch). Modules:

- ``contract`` (the shared rules in code: run-folder names, budget fraction, event lines, transforms
  files, the intrinsics rule, output names; no torch);
- ``cameras`` (rays), ``data`` (dataset loading, ``RayBatcher`` for training batches), ``scene_box`` (the box of a
  dataset without ``aabb``, an interior's margin), ``dataset_checks``;
- ``encodings``, ``fields``, ``sampling``, ``occupancy``, ``volrend`` (volume rendering),
  ``contraction``, ``backgrounds``, ``environment``, ``grad_scaling``, ``methods`` (named models), ``sizing``;
- ``losses`` (photometric loss, regularisers), ``metrics`` (PSNR, SSIM, depth error, error maps);
- ``train`` (the loop and its rollback), ``train_config`` (``TrainConfig``, ``--resume`` merging),
  ``optim`` (optimiser, schedule), ``seeding`` (seeds, RNG state), ``previews``, ``interrupts``;
- ``runfolder`` (checks, lock, written list, ``--overwrite``, dataset hash), ``checkpoints``
  (writing, weights-only reading, loading a run's model);
- ``evaluate`` (held-out evaluation), ``render``, ``render_server``, ``camera_path``, ``check`` and
  ``cli`` (``python -m nerf_core``); ``photo2d``/``fit2d`` (the 2D kernel-width study).
"""
__version__ = "0.1.0"

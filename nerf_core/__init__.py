"""nerf_core: a standalone, CPU-first PyTorch NeRF library.

Imports no ``bpy``. Modules:

- ``contract`` (the shared rules in code: run-folder names, budget fraction, event lines; no torch);
- ``cameras`` (intrinsics, rays), ``data`` (dataset loading, ``RayBatcher`` for training batches);
- ``encodings``, ``fields``, ``sampling``, ``occupancy``, ``volrend`` (volume rendering),
  ``contraction``, ``backgrounds``, ``environment``, ``methods`` (named models), ``sizing``;
- ``losses`` (photometric loss, regularisers, the one PSNR-from-MSE formula);
- ``train`` (the loop and its rollback), ``train_config`` (``TrainConfig``, ``--resume`` merging),
  ``optim`` (optimiser, schedule), ``seeding`` (seeds, RNG state), ``previews``, ``interrupts``;
- ``runfolder`` (checks, lock, written list, ``--overwrite``, dataset hash), ``checkpoints``
  (writing, weights-only reading, loading a run's model);
- ``evaluate`` (metrics, held-out evaluation), ``render``, ``check`` and ``cli`` (``python -m nerf_core``).
"""
__version__ = "0.1.0"

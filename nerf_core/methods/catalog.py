"""The built-in methods. Importing this module registers them with ``registry.register``.

- ``vmgrid`` (DEFAULT_METHOD): VM-factorised grid, coarse-to-fine, occupancy-skipped; minutes on a CPU.
- ``nerf``: the classic MLP NeRF with positional encoding and hierarchical sampling (CPU-sized).
- ``nerf-nope``: ``nerf`` without positional encoding, the blurry baseline.
- ``nerf-noview``, ``vmgrid-noview``: ``nerf`` and ``vmgrid`` with a colour that ignores the view
  direction (option ``view_dependent`` off): what the direction input buys on glossy surfaces.

Registering a method registers its hooks with it: ``training_hook`` (schedules driven by the
trainer's budget fraction) and ``size_options`` (``--size auto``), both looked up through the class.
"""
from nerf_core.methods import nerf, vmgrid  # noqa: F401  (their @register decorators run on import)

DEFAULT_METHOD = "vmgrid"

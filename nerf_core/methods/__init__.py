"""NeRF methods, selected by name: ``registry.build_model(name, aabb, **options)``.

Importing this package registers the built-in methods (``catalog``: vmgrid, nerf, nerf-nope, and the
``-noview`` variants).
- ``base``: ``RadianceModel``, the interface every method implements, and option checks;
- ``registry``: ``register``, ``build_model``, ``available_methods``, ``method_class``;
- ``vmgrid``, ``nerf``: the methods; ``sizing``: ``--size auto``.
"""
from nerf_core.methods import catalog  # noqa: F401  (registers the built-in methods)

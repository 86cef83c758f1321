"""NeRF methods, selected by name: see ``base.build_model`` and ``catalog``."""
from nerf_core.methods.base import RadianceModel, available_methods, build_model, register

__all__ = ["RadianceModel", "available_methods", "build_model", "register"]

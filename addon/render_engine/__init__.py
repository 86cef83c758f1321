"""The "NeRF" render engine: a trained run rendered in Blender's viewport and F12 render."""
from .engine import register, unregister  # noqa: F401

"""Capture feature: lay out cameras (``layouts``) and render them into a NeRF dataset (``capture_job``);
the Capture panel, its settings and operators live in ``capture_ui``."""
from .capture_ui import register, unregister  # noqa: F401

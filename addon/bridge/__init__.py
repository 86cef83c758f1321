"""The child trainer process and its JSON-line seam: no bpy here, ever (blender_tests/test_addon_layers.py)."""

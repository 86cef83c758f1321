"""NeRF Bridge: a Blender extension that captures a scene as a NeRF dataset, trains a NeRF in a
separate process (torch never loads inside Blender), and imports its novel views as image planes.

Each UI module exposes ``register()``/``unregister()`` built with ``register_classes_factory`` from
its own ``CLASSES`` tuple. Non-UI modules (``layouts``, ``capture``, ``export``, ``demo_scenes``,
``trainer_process``, ``progress``, ``planes``, ``render_client``) are importable by scripts without registering
anything. ``render_engine`` registers the "NeRF" render engine and its Render Properties panel.
"""
from . import prefs, capture_ui, train_ui, render_engine

_MODULES = (prefs, capture_ui, train_ui, render_engine)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()

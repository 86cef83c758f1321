"""NeRF Bridge: a Blender extension that captures a scene as a NeRF dataset, trains a NeRF in a
separate process (torch never loads inside Blender), and imports its novel views as image planes.

UI modules (``prefs``, ``jobs``, ``capture_ui``, ``train_ui``, ``render_engine``) expose
``register()``/``unregister()`` built with ``register_classes_factory`` from their own ``classes`` tuple
(``prefs``: ``CLASSES``). Non-UI modules (``layouts``, ``capture``, ``export``, ``demo_scenes``, ``compare``,
``trainer_process``, ``progress``, ``planes``, ``runs``, ``core_contract``, ``render_client``) are importable
by scripts without registering anything. ``render_engine`` registers the "NeRF" render engine and its
Render Properties panel.
"""
from . import capture, common, compare, render_engine, train

_MODULES = (common, capture, train, compare, render_engine)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()

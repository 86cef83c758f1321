"""NeRF Bridge: a Blender extension that captures a scene as a NeRF dataset, trains a NeRF in a
separate process (torch never loads inside Blender), and imports its novel views as image planes.

UI modules (``prefs``, ``jobs``, ``capture_ui``, ``train_ui``) expose ``register()``/``unregister()``
built with ``register_classes_factory`` from their own ``classes`` tuple (``prefs``: ``CLASSES``).
Non-UI modules (``layouts``, ``capture``, ``export``, ``demo_scenes``, ``compare``, ``trainer_process``,
``progress``, ``planes``, ``runs``, ``core_contract``) are importable by scripts without registering anything.
"""
from . import prefs, jobs, capture_ui, train_ui

_MODULES = (prefs, jobs, capture_ui, train_ui)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()

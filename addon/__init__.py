"""NeRF Bridge: a Blender extension that captures a scene as a NeRF dataset, trains a NeRF in a
separate process (torch never loads inside Blender), and imports its novel views as image planes.

Packages, lowest layer first (blender_tests/test_addon_layers.py checks the rules):

- ``file_writes``: atomic file writes and PNG encoding (standard library and numpy only).
- ``bridge/``: the child trainer process (``child_process``), its JSON-line progress (``progress``),
  nerf_core's contract loaded without torch (``core_contract``, ``core_path``), the run list (``runs``)
  and the render server client (``render_client``). Never imports bpy.
- ``scene/``: reading the Blender scene (``scene_bounds``, ``scene_appearance``, ``scene_files``,
  ``camera_checks``, render ``passes``, ``point_normals``).
- ``dataset/``: the dataset files (``cameras``, ``transforms``, ``capture_manifest``, ``points``, ``aabb``).
- ``common/``: what the features share: preferences (``prefs``), panel helpers (``ui_common``) and the
  job registry with its modal follower (``jobs``).
- Features, which import the layers above and not each other (except compare -> train):
  ``capture/`` (layouts, the capture job, the Capture panel), ``train/`` (the Train panel and job),
  ``compare/`` (rendering a run's views and importing them as planes) and ``render_engine/`` (the
  "NeRF" render engine).

Each package's ``register()``/``unregister()`` registers its own ``classes`` tuple; this module calls
them in order. Everything but the UI modules is importable by scripts without registering anything.
"""
from . import capture, common, compare, render_engine, train
from .common.registration import registrar

_MODULES = (common, capture, train, compare, render_engine)

register, unregister = registrar(_MODULES)

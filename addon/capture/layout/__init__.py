"""Where a capture's cameras go: the layouts (``positions``, pure functions), the camera objects made from
them (``cameras``) or imported from a transforms file (``layout.camera_import``), the "NeRF Cameras" collection
(``collection``) and what the panel says about a layout (``notes``)."""

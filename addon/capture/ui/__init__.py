"""The Capture panel: its settings on the scene (``props``), the panel and its operators (``panel``) and
the *Import Cameras* operator (``import_cameras``)."""

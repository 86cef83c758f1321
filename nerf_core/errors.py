"""The errors nerf_core raises for bad input, each with a message that names the file, frame,
field or flag and says what to do. The command line prints the message alone (no traceback).

- ``DatasetError``: a dataset folder or transforms file that cannot be used. ``PoseError``: a camera
  matrix that is not a finite rigid transform; a ``ValueError``, not a ``DatasetError``: the loaders
  turn it into a ``DatasetError`` naming the frame. Both are defined in ``nerf_core.contract`` (the
  add-on raises them inside Blender, without torch).
- ``TrainError``: training cannot start or cannot continue (a flag, a run folder, a full disk).
- ``RunError`` (and ``CheckpointRefused``): a run folder or checkpoint that cannot be used.
- ``ImageReadError``: an image file that is missing, unreadable or not the kind expected.
"""
from __future__ import annotations

from nerf_core.contract.errors import DatasetError, PoseError

__all__ = ["DatasetError", "PoseError", "TrainError", "RunError", "CheckpointRefused", "ImageReadError"]


class TrainError(Exception):
    """Training cannot start or cannot continue; the message says why and what to do."""


class RunError(Exception):
    """A run folder or checkpoint that cannot be used; the message names the file."""


class CheckpointRefused(RunError):
    """A checkpoint that would need code to load (a crafted pickle): never skipped over silently."""


class ImageReadError(Exception):
    """A file that is missing, unreadable or not the kind of image expected."""

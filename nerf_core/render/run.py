"""``open_run``: a trained run as one object (``Run``), for the library's users.

    run = nerf_core.open_run("runs/scene")
    out = run.render(run.dataset.split("test").cameras, 0)   # near, far and background: the run's

A ``Run`` holds the model, the typed record of RUN/config.json (``runs.record.RunRecord``), the
checkpoint it came from and, loaded on first use, the dataset it trained on; ``render`` renders a view
over the run's own ray bounds, background and film filter, as ``eval`` and ``render`` do.
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Callable, Dict, Optional, Sequence, Union

import torch

from nerf_core.cameras.rays import Cameras
from nerf_core.data.loading import load_cameras, load_dataset
from nerf_core.data.split import Dataset
from nerf_core.errors import RunError
from nerf_core.image import pixel_filter as pf
from nerf_core.methods.base import RadianceModel
from nerf_core.render.frame import render_view
from nerf_core.render.memory import DEFAULT_CHUNK
from nerf_core.runs.checkpoints import load_trained
from nerf_core.runs.dataset_identity import SCORES, dataset_changed_note
from nerf_core.runs.record import RunRecord
from nerf_core.utils import arguments
from nerf_core.utils.device import pick_device


class DatasetChanged(UserWarning):
    """The dataset a run names no longer holds the data it trained on (the message says what changed)."""


class Run:
    """A trained run, opened (``open_run``).

    Attributes:
        path: the run folder.
        model: the trained ``RadianceModel``, in eval mode on the run's device.
        config: the run's record (``RunRecord``: dataset, near, far, eval_background, downscale, method,
            and ``raw``, the whole config.json).
        checkpoint: the checkpoint dict the model came from (``step``, ``method``, ``options``...).
        step: the optimisation steps the checkpoint holds.
    """

    def __init__(self, path: Path, model: RadianceModel, config: RunRecord, checkpoint: dict):
        self.path, self.model, self.config, self.checkpoint = path, model, config, checkpoint
        self.step = int(checkpoint.get("step", 0))
        self._dataset: Optional[Dataset] = None
        self.notes: list = []  # what reading the run's dataset had to say (it changed since training)
        self._identity_checked = False

    def _dataset_path(self, consequence: str) -> str:
        """The recorded dataset's path, after the one check of whether it still holds what the run
        trained on (``runs.dataset_identity.dataset_changed_note``): a change is a ``DatasetChanged``
        warning and a line in ``notes``, as ``eval`` prints it."""
        if not self.config.dataset:
            raise RunError(f"{self.config.path}: no 'dataset' recorded")
        if not self._identity_checked:  # once a Run: the hash reads every transforms file, and one word is enough
            self._identity_checked = True
            note = dataset_changed_note(self.config.raw, consequence)
            if note:
                self.notes.append(note)
                warnings.warn(note, DatasetChanged, stacklevel=3)
        return self.config.dataset

    @property
    def dataset(self) -> Dataset:
        """The dataset the run trained on, at the run's downscale (loaded on first use).

        Raises:
            RunError: the run recorded no dataset. DatasetError: it cannot be loaded.
        Warns ``DatasetChanged`` (and adds to ``notes``) when it changed since the run trained on it."""
        if self._dataset is None:
            path = self._dataset_path("what is computed from it compares the model with the data there now")
            self._dataset = load_dataset(path, downscale=self.config.downscale)
        return self._dataset

    def cameras(self, split: str = "train", consequence: str = SCORES) -> Cameras:
        """The cameras of one split of the run's dataset, without reading its images (``load_cameras``),
        checked like ``dataset`` (a change since training is noted, ``consequence`` saying what it means).

        Raises:
            RunError: the run recorded no dataset. DatasetError: its transforms cannot be read."""
        return load_cameras(self._dataset_path(consequence), split)[0]

    def render(self, cameras: Cameras, view: int, background: Optional[Sequence[float]] = None,
               chunk: int = DEFAULT_CHUNK, pixel_filter: Union[str, pf.PixelFilter, None] = None,
               on_chunk: Optional[Callable[[int, int], None]] = None) -> Dict[str, torch.Tensor]:
        """Render view ``view`` of ``cameras`` over the run's ray bounds (``render_view``).

        Args:
            cameras: the ``Cameras`` (e.g. ``run.dataset.split("test").cameras``).
            view: index of the camera.
            background: (3,) RGB in [0, 1] behind the scene; None: the run's ``eval_background``. A run
                with a learned world renders its world instead.
            chunk: most rays per model call.
            pixel_filter: None or "none" (one ray through each pixel centre, as ``render_view``'s None),
                "auto" (the capture's film filter, as ``eval`` scores views), or a ``PixelFilter``; any
                other value is refused (ValueError naming ``pixel_filter``).
            on_chunk: progress callback, ``on_chunk(done, h * w)``.

        Returns:
            ``render_view``'s dict: ``rgb`` (h, w, 3), ``acc`` (h, w), ``depth`` (h, w), ``z_depth``
            (h, w) float32 CPU tensors, and ``n_rays``.
        """
        film = pf.of_run(self.config.raw, pixel_filter, where="Run.render: pixel_filter")
        bg = tuple(self.config.eval_background) if background is None else tuple(background)
        return render_view(self.model, cameras, view, background=bg, near=self.config.near, far=self.config.far,
                           chunk=chunk, on_chunk=on_chunk, pixel_filter=film)

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r}, method={self.config.method!r}, step={self.step})"


def open_run(path: Union[str, Path], device: Union[str, torch.device, None] = None,
             checkpoint: Union[str, Path, None] = None) -> Run:
    """Open a run folder written by ``train``.

    Args:
        path: the run folder (holds ``config.json`` and ``checkpoints/``).
        device: "cpu", "cuda", a ``torch.device``...; None: CUDA when there is one, else the CPU.
        checkpoint: a checkpoint file to load instead of ``RUN/checkpoints/latest.pt``.

    Returns:
        the ``Run``: ``.model``, ``.config`` (typed), ``.dataset``, ``.render(cameras, i)``.

    Raises:
        RunError: a missing or unusable run folder, config.json or checkpoint.
        CheckpointRefused: a checkpoint that would need code to load.
    """
    path = Path(arguments.path("open_run", "path", path))
    if checkpoint is not None:
        arguments.path("open_run", "checkpoint", checkpoint)
    if device is not None and not isinstance(device, (str, torch.device)):
        raise TypeError(f"open_run: device must be 'cpu', 'cuda', ... or a torch.device, got {device!r}")
    dev = pick_device(device, flag="open_run: device")  # a torch.device is checked too (meta, a missing cuda:3)
    model, record, ckpt = load_trained(path, dev, checkpoint)
    return Run(path, model, record, ckpt)

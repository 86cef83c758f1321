"""Preview images written while training: ``RUN/previews/step_XXXXXXX.png``.

One fixed camera (the first val view, else test, else train), shrunk to ``size`` pixels on its
longest side, rendered every ``every`` steps or every ``seconds`` of training time, whichever the
run asks for. Each file is listed in ``RUN/.written.json`` before it is written.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

from nerf_core import contract
from nerf_core.image.io import write_png
from nerf_core.render.frame import render_view
from nerf_core.runs.folder import record_written


def preview_camera(dataset, size: int):
    """The ``Cameras`` of one view to preview (longest side at most ``size`` px), or None without views."""
    for name in ("val", "test", "train"):
        sp = dataset.splits.get(name)
        if sp is not None and len(sp):
            cams = sp.cameras[0]
            scale = min(1.0, size / max(sp.width, sp.height))
            return cams.scaled(scale) if scale < 1.0 else cams
    return None


class Previews:
    """When previews are due, and writing them (``background``: the evaluation colour, RGB)."""

    def __init__(self, run: Path, dataset, size: int, every: Optional[int], seconds: float, background, chunk: int):
        self.run, self.every, self.seconds = run, every, seconds
        self.near, self.far, self.background, self.chunk = dataset.near, dataset.far, background, chunk
        self.camera = preview_camera(dataset, size)
        self.cost = 0.0  # wall seconds the last preview took

    def due(self, step: int, last_step: int, elapsed: float, last_elapsed: float) -> bool:
        if self.every:
            return step - last_step >= self.every
        # A slow method (the classic MLP renders a 200x200 view in ~1 min on 2 cores) would otherwise spend
        # more time on previews than on training: keep previews under ~20% of the training time.
        return elapsed - last_elapsed >= max(self.seconds, 4.0 * self.cost)

    def write(self, model, step: int) -> Optional[Path]:
        """Render the preview camera with ``model`` (back in train mode afterwards); the PNG's path."""
        if self.camera is None:
            return None

        started = time.monotonic()
        model.eval()
        try:
            res = render_view(model, self.camera.to("cpu"), 0, background=self.background, near=self.near,
                              far=self.far, chunk=self.chunk)
        finally:
            model.train()
        Path(contract.previews_dir(self.run)).mkdir(exist_ok=True)
        path = Path(contract.preview_path(self.run, step))
        record_written(self.run, path)
        write_png(path, res["rgb"].numpy())
        self.cost = time.monotonic() - started
        return path

"""The render job: ``nerf_core render`` of a cameras file in a child process, then the views imported
as planes (``compare_views.import_views``)."""
from __future__ import annotations

import os
from typing import List

from ..bridge import child_process
from ..common.jobs import ProcessJob
from . import compare_views, planes


class RenderJob(ProcessJob):
    """``nerf_core render`` of a transforms file, then the planes import (``compare_views.import_views``)."""

    kind = "rendering"

    def __init__(self, scene_name: str, python: str, run: str, cameras: str, out: str, layout: str,
                 distance: float, n_views: int, checkpoint: str = ""):
        super().__init__(scene_name)
        self.run, self.cameras, self.out, self.layout, self.distance = run, cameras, out, layout, distance
        self.n_views, self.checkpoint = n_views, checkpoint
        self.process = child_process.BackgroundProcess(
            child_process.render_command(python, run, cameras, out, checkpoint=checkpoint)).start()
        self.views: List[planes.View] = []

    def rendered(self) -> int:
        return compare_views.rendered_count(self.out)

    def succeeded(self) -> str:
        try:
            self.views = planes.views_from_render(self.out, self.cameras)
            note = compare_views.import_views(self.scene, self.views, self.layout, self.out, self.run, self.distance)
        except (ValueError, RuntimeError, TypeError, KeyError) as exc:  # a damaged renders.json
            return self.fail(f"{os.path.join(self.out, 'renders.json')}: cannot import the views: {exc}")
        except OSError as exc:
            return self.fail(child_process.describe_os_error(exc, self.out))
        self.state = "done"
        self.message = f"Imported {len(self.views)} view(s) from {self.out}" + (f"; {note}" if note else "")
        self.warnings = compare_views.render_notes(self.out)  # e.g. the scores are against a re-captured dataset
        if self.checkpoint:  # latest.pt was gone: say which checkpoint the views show
            self.warnings.insert(0, f"Rendered from {self.checkpoint}: the run has no checkpoints/latest.pt")
        return self.state

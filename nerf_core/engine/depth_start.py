"""``train --depth`` at the start of a run (and on ``--resume``, since the mark is not saved): the
occupancy grid is told which cells the capture's depth shows empty (``data.carving.free_cells``)."""
from __future__ import annotations

import sys

from nerf_core.data.carving import free_cells
from nerf_core.data.split import Split
from nerf_core.methods.base import RadianceModel


def carve_free_space(model: RadianceModel, train: Split, method: str, log, is_main: bool) -> None:
    """Mark the cells of ``model``'s occupancy grid that ``train``'s depth (v, h, w) shows empty, and
    say how much of the box that was (stderr on the main process, and a ``note`` event on ``log``)."""
    grid = model.occupancy_grid()
    if grid is None:
        msg = (f"--depth: method {method!r} has no occupancy grid over the scene box here; "
               "the depth is used by the loss only")
    else:
        free = free_cells(grid.aabb, grid.resolution, train, train.depth)
        grid.mark_known_free(free)
        msg = (f"--depth: the occupancy grid starts with {float(free.float().mean()):.0%} of the box empty, "
               "as the train views' depth shows it")
    if is_main:
        print(f"train: {msg}", file=sys.stderr)
    log.emit("note", message=msg)

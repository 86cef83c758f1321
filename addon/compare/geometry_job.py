"""The geometry job: ``nerf_core export mesh|volume|world`` of a run in a child process (progress from its
``progress`` events, Cancel stops it), then the result imported into the scene (``geometry_import``).

Each export goes to a new file ``RUN/geometry/<kind>_NNN.ply|.npz|.png``: earlier exports, which a saved
.blend may still reference, are never overwritten."""
from __future__ import annotations

import os

from ..bridge import child_process
from ..bridge.core_contract import contract
from ..common.jobs import ProcessJob
from . import geometry_import

GEOMETRY_DIR = "geometry"
# the exports' table (nerf_core/contract/exports.py): each format's suffix, and the files written beside it
SUFFIX = {name: fmt.suffix for name, fmt in contract.exports.EXPORTS.items()}
BESIDE = {name: fmt.beside for name, fmt in contract.exports.EXPORTS.items()}


def fresh_file(run: str, kind: str) -> str:
    """``RUN/geometry/<kind>_001.<ext>``, ``_002``...: the first name not taken (the folder is created)."""
    folder = os.path.join(run, GEOMETRY_DIR)
    if os.path.lexists(folder) and not os.path.isdir(folder):
        raise child_process.SetupError(f"{folder} is in the way (not a folder): geometry exports go there; "
                                       "move it away (it was left untouched).")
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as exc:
        raise child_process.SetupError(child_process.describe_os_error(exc, folder, "creating")) from None
    k = 1
    while any(os.path.lexists(os.path.join(folder, f"{kind}_{k:03d}{ext}")) for ext in (SUFFIX[kind],) + BESIDE[kind]):
        k += 1
    return os.path.join(folder, contract.exports.export_file_name(kind, k))


def stage_text(event) -> str:
    """'density 40 %' from a ``progress`` event of ``nerf_core export``, '' for anything else."""
    if not isinstance(event, dict) or event.get("event") != "progress":
        return ""
    frac = event.get("fraction")
    share = f" {100 * frac:.0f} %" if isinstance(frac, (int, float)) else ""
    return f"{event.get('stage', '')}{share}"


class GeometryJob(ProcessJob):
    """``nerf_core export`` of a run into ``out``, then its mesh, volume or world imported into the scene."""

    kind = "export"

    def __init__(self, scene_name: str, python: str, run: str, geometry: str, out: str, checkpoint: str = ""):
        super().__init__(scene_name)
        self.run, self.geometry, self.out = run, geometry, out
        self.process = child_process.BackgroundProcess(
            child_process.export_command(python, geometry, run, out, checkpoint=checkpoint)).start()
        self.object_name = ""

    def stage(self) -> str:
        return stage_text(self.process.progress.last_event)

    def succeeded(self) -> str:
        scene = self.scene
        if scene is None:
            return self.fail("The scene the export was started from is gone")
        try:
            obj = geometry_import.IMPORTERS[self.geometry](scene, self.out)
        except (ValueError, RuntimeError) as exc:
            return self.fail(f"{self.out}: cannot import the {self.geometry}: {exc}")
        except OSError as exc:
            return self.fail(child_process.describe_os_error(exc, self.out))
        self.object_name = obj.name
        self.state = "done"
        self.message = f"Imported the NeRF {self.geometry} as {obj.name} from {self.out}"
        return self.state

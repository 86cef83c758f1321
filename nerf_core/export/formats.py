"""How each declared export (``nerf_core.contract.exports``) is made: its writer, registered once.

A writer says what one sample of its grid costs in memory (``bytes_per_sample``, checked before the
work by ``grid.check_fits``), how it extracts its result from an ``ExportJob`` and how it writes that
result, atomically, to the output file, and what of it goes into the summary. The orchestrator
(``export.run_export.export_run``) does everything else, the same for every format: the output rule,
loading the run, the memory check, notes, progress, one-line errors.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, Optional

import numpy as np

from nerf_core.cameras.rays import Cameras
from nerf_core.contract import colour_management
from nerf_core.contract.errors import DatasetError
from nerf_core.contract.exports import MESH, VOLUME, WORLD, ExportFormat, export_format
from nerf_core.errors import RunError
from nerf_core.export import grid, mesh, ply, volume, world
from nerf_core.render.run import DatasetChanged, Run

CULLING = "the culling uses the cameras there now"


@dataclass
class ExportJob:
    """What a writer's ``extract`` gets: the opened ``run`` (``render.run.Run``), its ``model``, the scene
    ``box`` (2, 3) float64, the grid ``resolution``, the format's ``options`` (by ``Option.dest``),
    ``say(stage, share)`` for progress and ``note(message)`` for what the user should read."""

    run: Run
    box: np.ndarray
    resolution: Optional[int]  # None for a format without a grid (``ExportFormat.grid``)
    options: Dict[str, Any]
    say: Callable[[str, float], None]
    note: Callable[[str], None]
    notes: list = field(default_factory=list)

    @property
    def model(self):
        return self.run.model

    def training_cameras(self) -> Optional[Cameras]:
        """The run's training cameras (a changed dataset is noted: the one check, ``Run.cameras``), or
        None with a note when its dataset cannot be read any more."""
        with warnings.catch_warnings():  # said once, as a note event, not as a Python warning on stderr
            warnings.simplefilter("ignore", DatasetChanged)
            try:
                return self.run.cameras("train", consequence=CULLING)
            except (DatasetError, RunError) as exc:
                self.note(f"no culling by training cameras: {exc}")
                return None
            finally:
                for n in self.run.notes:
                    self.note(n)


@dataclass(frozen=True)
class Writer:
    """The making of format ``fmt``: ``extract(job) -> result``, ``write(path, result)`` (atomic),
    ``summary(result) -> dict`` (merged into the export's summary), ``bytes_per_sample`` of its grid."""

    fmt: ExportFormat
    bytes_per_sample: float
    extract: Callable[[ExportJob], Any]
    write: Callable[[Path, Any], None]
    summary: Callable[[Any], dict]
    detail_scale: int = 1  # the default grid: this many samples per model cell along each axis
    default_max: int = 0  # and no more than this per axis (0: no cap but the grid's own)
    beyond_box: bool = False  # it exports a contracted run's world beyond the box too (it notes how far)


WRITERS: Dict[str, Writer] = {}


def writer(name: str, bytes_per_sample: float, extract, write, summary=lambda result: {}, detail_scale: int = 1,
           default_max: int = 0, beyond_box: bool = False) -> Writer:
    """Register the writer of the declared format ``name`` (``contract.exports.declare`` first)."""
    w = Writer(export_format(name, "writer"), bytes_per_sample, extract, write, summary, detail_scale, default_max,
               beyond_box)
    WRITERS[name] = w
    return w


def writer_of(name: str) -> Writer:
    """The writer of format ``name``; ValueError naming the formats that have one."""
    export_format(name)
    if name not in WRITERS:
        raise ValueError(f"export {name!r} is declared but has no writer; one of {', '.join(sorted(WRITERS))}")
    return WRITERS[name]


def _extract_mesh(job: ExportJob) -> mesh.Mesh:
    o = job.options
    cams = job.training_cameras() if not o.get("keep_unseen") else None
    return mesh.extract_mesh(job.model, job.box, job.resolution, level=o.get("level"), n_faces=o.get("n_faces"),
                             cameras=cams, min_component=o.get("min_component", mesh.DEFAULT_MIN_COMPONENT),
                             fill_inside=o.get("fill_inside", True), on_progress=job.say)


def _volume_summary(arrays: dict) -> dict:
    d = arrays["density"]
    return {"level": float(arrays["level"]), "density_range": [float(np.min(d)), float(np.max(d))],
            "far_levels": int(arrays.get("far_levels", 0))}


writer(MESH.name, mesh.BYTES_PER_SAMPLE, _extract_mesh,
       lambda path, m: ply.write_mesh_ply(path, m.vertices, m.faces, m.colors), lambda m: dict(m.info))
def _recorded_colours(job: ExportJob, what: str) -> Optional[dict]:
    """The capture's colour management (``contract.colour_management.recorded``), or None with a note."""
    cm = colour_management.recorded(job.run.config.dataset) if job.run.config.dataset else None
    if cm is None:
        job.note(f"the dataset records no colour management (no nerf_capture/manifest.json): "
                 f"the {what}'s colours are taken as sRGB (the Standard view transform)")
    return cm


def _extract_volume(job: ExportJob) -> dict:
    levels = job.options.get("far_levels")
    levels = (volume.FAR_LEVELS if job.model.contracted else 0) if levels is None else int(levels)
    far_res = min(job.resolution, volume.FAR_RESOLUTION)
    if levels:  # before any work: the box's grid and every far grid are held together until the write
        per_far_node = volume.BYTES_PER_SAMPLE * (levels + (job.resolution / far_res) ** 3)
        grid.check_fits(far_res, per_far_node, flag="--far-levels", fixed=grid.CHUNK_BYTES)
    arrays = volume.volume_grids(job.model, job.box, job.resolution, on_progress=job.say)
    if levels and not job.model.contracted:
        job.note(f"--far-levels {levels}: the run does not model the world beyond its box (not unbounded); "
                 "the far grids hold nothing but what the field guesses there")
    if job.model.contracted and not levels:
        job.note("--far-levels 0: the run models the world beyond its scene box, and the volume covers the box only")
    if levels:
        arrays.update(volume.far_grids(job.model, job.box, levels, far_res, job.say))
        job.note(f"the volume reaches {2 ** levels} times the box ({levels} nested grids of {far_res}^3 beyond it); "
                 "past that the run's world is not exported")
    arrays["color_management"] = volume.colour_record(_recorded_colours(job, "volume"))
    return arrays


# The volume's default grid is twice the model's: Cycles interpolates colours between the nodes in light,
# and at the model's own plane size that blurs what the field's decoder keeps sharp. Measured (Cycles
# against the NeRF's render, 2 views, 128 samples, under the captures' AgX): multi 34.44 -> 37.38 dB,
# highfreq 27.00 -> 29.23 dB at 320^3 (229 MB .npz, 320 MB .vdb) against 160^3; 320 per axis at most.
writer(VOLUME.name, volume.BYTES_PER_SAMPLE, _extract_volume, volume.write_volume, _volume_summary,
       detail_scale=2, default_max=320, beyond_box=True)


def _extract_world(job: ExportJob) -> dict:
    env = job.model.environment
    if env is None:
        raise RunError(f"{job.run.path}: the run learned no world (only a run on opaque images does, its "
                       "background 'environment'): its background was a colour, so there is no world to export")
    job.say("world", 0.0)
    image = world.world_image(env, job.options.get("width"))
    job.say("world", 1.0)
    return {"image": image, "color_management": _recorded_colours(job, "world")}


writer(WORLD.name, 0, _extract_world, lambda path, w: world.write_world(path, w["image"], w["color_management"]),
       lambda w: {"width": int(w["image"].shape[1]), "height": int(w["image"].shape[0])})

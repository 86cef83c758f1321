"""``export mesh`` and ``export volume`` of a run folder: load the run, check the output path and the
grid's memory before any work, extract, write; a summary dict for the CLI's last stdout line."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from nerf_core.contract.errors import DatasetError
from nerf_core.data.loading import load_cameras
from nerf_core.export import field, grid, mesh, ply, volume
from nerf_core.export.output import check_output
from nerf_core.runs.checkpoints import load_run
from nerf_core.utils.device import pick_device
from nerf_core.utils.memory import named_out_of_memory

OUT_OF_MEMORY_ADVICE = "lower the resolution (or --device cpu, when the GPU's memory is the smaller)"
WORLD_NOTE = ("the run models the world beyond its scene box (light from infinity or a contracted world): "
              "that is not geometry; the export covers the scene box only")


def _load(run, checkpoint, device, notes: list):
    model, config, ckpt = load_run(run, pick_device(device), checkpoint)
    if field.models_the_world(model):
        notes.append(WORLD_NOTE)
    box = model.aabb.detach().cpu().double().numpy()
    return model, config, ckpt, box


def _training_cameras(config: dict, notes: list):
    """The run's training cameras, or None with a note when its dataset cannot be read any more."""
    dataset = config.get("dataset")
    try:
        if not dataset:
            raise DatasetError("the run records no dataset")
        return load_cameras(dataset, "train")[0]
    except DatasetError as exc:
        notes.append(f"no culling by training cameras: {exc}")
        return None


def export_mesh(
    run,
    out,
    resolution: Optional[int] = None,
    n_faces: Optional[int] = None,
    level: Optional[float] = None,
    min_component: float = mesh.DEFAULT_MIN_COMPONENT,
    cull_unseen: bool = True,
    fill_inside: bool = True,
    overwrite: bool = False,
    checkpoint=None,
    device=None,
    on_progress: Optional[Callable[[str, float], None]] = None,
    on_note: Optional[Callable[[str], None]] = None,
) -> dict:
    """Write the run's coloured mesh to ``out`` (binary PLY, scene frame); see ``export.mesh`` for the rules.

    Returns the summary: ``out``, ``vertices``, ``faces``, ``resolution``, ``level``, ``seconds``,
    ``notes`` and the culling counts. Raises ValueError (bad output path, a grid too large, no
    surface, the mesh extra missing) or RunError (an unusable run) before anything is written.
    """
    started = time.perf_counter()
    out = check_output(out, overwrite, suffix=".ply")
    notes: list = []
    model, config, ckpt, box = _load(run, checkpoint, device, notes)
    res = int(resolution or field.grid_resolution(model))
    grid.check_fits(res, mesh.BYTES_PER_SAMPLE, fixed=grid.CHUNK_BYTES)
    cams = _training_cameras(config, notes) if cull_unseen else None
    for n in notes:
        (on_note or (lambda s: None))(n)
    with named_out_of_memory(f"--resolution {res}", OUT_OF_MEMORY_ADVICE):
        m = mesh.extract_mesh(model, box, res, level=level, n_faces=n_faces, cameras=cams,
                              min_component=min_component, fill_inside=fill_inside, on_progress=on_progress)
        check_output(out, overwrite, suffix=".ply")  # again: the path may have changed while we worked
        ply.write_mesh_ply(out, m.vertices, m.faces, m.colors)
    return {"out": str(Path(out).resolve()), "kind": "mesh", "run": str(Path(run).resolve()),
            "step": ckpt.get("step"), "method": ckpt.get("method"), "box": box.tolist(), **m.info,
            "seconds": round(time.perf_counter() - started, 3), "notes": notes}


def export_volume(run, out, resolution: Optional[int] = None, overwrite: bool = False, checkpoint=None,
                  device=None, on_progress: Optional[Callable[[str, float], None]] = None,
                  on_note: Optional[Callable[[str], None]] = None) -> dict:
    """Write the run's density and colour grids to ``out`` (``.npz``, format in ``export.volume``).

    Returns the summary: ``out``, ``resolution``, ``box``, ``level``, ``density_range``, ``seconds``,
    ``notes``. Raises ValueError or RunError before anything is written.
    """
    started = time.perf_counter()
    out = check_output(out, overwrite, suffix=".npz")
    notes: list = []
    model, config, ckpt, box = _load(run, checkpoint, device, notes)
    res = int(resolution or field.grid_resolution(model))
    grid.check_fits(res, volume.BYTES_PER_SAMPLE, fixed=grid.CHUNK_BYTES)
    for n in notes:
        (on_note or (lambda s: None))(n)
    with named_out_of_memory(f"--resolution {res}", OUT_OF_MEMORY_ADVICE):
        arrays = volume.volume_grids(model, box, res, on_progress=on_progress)
        d = arrays["density"]
        check_output(out, overwrite, suffix=".npz")
        volume.write_volume(out, arrays)
    return {"out": str(Path(out).resolve()), "kind": "volume", "run": str(Path(run).resolve()),
            "step": ckpt.get("step"), "method": ckpt.get("method"), "resolution": res, "box": box.tolist(),
            "level": float(arrays["level"]), "density_range": [float(np.min(d)), float(np.max(d))],
            "seconds": round(time.perf_counter() - started, 3), "notes": notes}

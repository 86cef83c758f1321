"""``export NAME RUN --out FILE`` of any declared format (``contract.exports``, made by ``export.formats``),
the same steps for each: the output rule and a write probe, the run opened through ``open_run``, the
grid's memory checked, the format's extraction and its atomic write, one summary dict for the CLI's last
stdout line. Nothing is written when any step refuses; every refusal is one line naming the flag or file.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Optional

from nerf_core.contract.exports import export_format
from nerf_core.export import field, formats, grid, mesh
from nerf_core.export.output import check_output, probe_writable, writing
from nerf_core.render.run import open_run
from nerf_core.utils.memory import named_out_of_memory

OUT_OF_MEMORY_ADVICE = "lower the resolution (or --device cpu, when the GPU's memory is the smaller)"
ENVIRONMENT_NOTE = ("the run learned the world behind its scene box as light from infinity: that is not geometry; "
                    "`export world` writes it as a Blender World")
BEYOND_BOX_NOTE = "the run models the world beyond its scene box (contracted): the export covers the scene box only"


def export_run(kind: str, run, out, resolution: Optional[int] = None, overwrite: bool = False, checkpoint=None,
               device=None, on_progress: Optional[Callable[[str, float], None]] = None,
               on_note: Optional[Callable[[str], None]] = None, **options) -> dict:
    """Write format ``kind`` of the run folder ``run`` to ``out``.

    Args:
        kind: a declared export ("mesh", "volume", "world"; ``contract.exports.EXPORTS``).
        resolution: samples per axis of the scene box; None: ``default_resolution`` (the model's own,
            ``field.grid_resolution``, twice that for a volume); refused for a format without a grid.
        options: the format's own options, by ``Option.dest`` (``n_faces=``, ``level=``...).
        on_progress: called with (stage, share done in [0, 1]); on_note: with each note, as it arises.

    Returns:
        the summary: ``out``, ``kind``, ``run``, ``step``, ``method``, ``box``, ``resolution``,
        ``seconds``, ``notes`` and the format's own fields (``Writer.summary``); ``resolution`` is None
        for a format without a grid.

    Raises:
        ValueError (an output refused, a grid too large, not enough memory, no surface, a missing
        extra, a full disk naming ``out``) or RunError (an unusable run), with nothing written.
    """
    started = time.perf_counter()
    fmt, make = export_format(kind), formats.writer_of(kind)
    out = check_output(out, overwrite, suffix=fmt.suffix)
    probe_writable(out)  # /proc/x.ply, a read-only folder: refused now, not after the work
    notes: list = []

    def note(message: str) -> None:
        if message not in notes:
            notes.append(message)
            (on_note or (lambda s: None))(message)
    if resolution is not None and not fmt.grid:
        raise ValueError(f"--resolution: export {kind} samples no grid over the scene box; "
                         + (f"its size is {fmt.options[0].flag}" if fmt.options else "it has no size to set"))
    opened = open_run(run, device=device, checkpoint=checkpoint)
    model = opened.model
    if fmt.grid and model.models_world:
        note(ENVIRONMENT_NOTE)
    if fmt.grid and model.contracted and not make.beyond_box:
        note(BEYOND_BOX_NOTE)
    box = model.aabb.detach().cpu().double().numpy()
    res = None
    if fmt.grid:  # a world samples directions, not the box
        res = int(resolution or default_resolution(make, field.grid_resolution(model), note))
        grid.check_fits(res, make.bytes_per_sample, fixed=grid.CHUNK_BYTES)
    job = formats.ExportJob(opened, box, res, options, on_progress or (lambda stage, share: None), note, notes)
    with named_out_of_memory(f"--resolution {res}" if res else f"export {kind}", OUT_OF_MEMORY_ADVICE):
        result = make.extract(job)
        check_output(out, overwrite, suffix=fmt.suffix)  # again: the path may have changed while we worked
        with writing(out):
            make.write(out, result)
    return {"out": str(Path(out).resolve()), "kind": kind, "run": str(Path(run).resolve()), "step": opened.step,
            "method": opened.checkpoint.get("method"), "box": box.tolist(), "resolution": res,
            **make.summary(result), "seconds": round(time.perf_counter() - started, 3), "notes": notes}


def default_resolution(make: formats.Writer, own: int, note: Callable[[str], None]) -> int:
    """The grid without ``--resolution``: the format's ``detail_scale`` times the model's own ``own``
    (at most its ``default_max``), or ``own`` with a note when that finer grid would not fit in memory."""
    res = own * make.detail_scale
    res = min(res, make.default_max) if make.default_max else res
    res = max(own, min(res, grid.MAX_RESOLUTION))
    if res > own:
        try:
            grid.check_fits(res, make.bytes_per_sample, fixed=grid.CHUNK_BYTES)
        except ValueError:
            note(f"a {res}^3 grid does not fit in memory: exported at the model's own {own}^3 "
                 "(--resolution chooses)")
            return own
    return res


def export_mesh(run, out, resolution: Optional[int] = None, n_faces: Optional[int] = None,
                level: Optional[float] = None, min_component: float = mesh.DEFAULT_MIN_COMPONENT,
                cull_unseen: bool = True, fill_inside: bool = True, **common) -> dict:
    """``export_run("mesh", ...)`` with the mesh's options as keywords (see ``export.mesh`` for the rules)."""
    return export_run("mesh", run, out, resolution, n_faces=n_faces, level=level, min_component=min_component,
                      keep_unseen=not cull_unseen, fill_inside=fill_inside, **common)


def export_volume(run, out, resolution: Optional[int] = None, **common) -> dict:
    """``export_run("volume", ...)``: the density and colour grids (``.npz``, format in ``export.volume``)."""
    return export_run("volume", run, out, resolution, **common)


def export_world(run, out, width: Optional[int] = None, **common) -> dict:
    """``export_run("world", ...)``: the learned world as an equirectangular PNG (``export.world``)."""
    return export_run("world", run, out, width=width, **common)

"""The exports of a trained run, declared once: each format's name (``export NAME``), the suffix of its
file, what it extracts, its own options and the files written beside it.

Everyone reads this table: the CLI builds ``export NAME`` from it (``nerf_core/cli/export.py``), the
export orchestrator checks ``--out``'s suffix with it (``nerf_core/export/run_export.py``), the add-on's
geometry job and ``scripts/import_geometry.py`` name their files by it. Standard library only: the
add-on loads it inside Blender (``addon/bridge/core_contract.py``).

A new format is this declaration plus a writer (``nerf_core.export.formats.writer``)::

    declare(ExportFormat("points", ".ply", "the surface as a point cloud", "points on the surface",
                         options=(Option("--count", "positive_int", "points to write"),)))

(``export colmap`` exports a dataset, not a run: it is no format of this table.)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, Optional, Tuple

# How an option's value is read on the command line (``nerf_core.cli.options`` holds the parsers).
OPTION_KINDS = ("positive_int", "nonneg_int", "positive_float", "share", "switch")


@dataclass(frozen=True)
class Option:
    """One option of one format: ``flag`` ("--faces"), ``kind`` (one of ``OPTION_KINDS``; "switch" is a
    flag without a value), ``help``, ``default`` and the keyword its writer receives (``dest``; default:
    the flag without dashes, ``-`` as ``_``)."""

    flag: str
    kind: str
    help: str
    default: Any = None
    metavar: str = "N"
    dest: str = ""

    def __post_init__(self):
        if self.kind not in OPTION_KINDS:
            raise ValueError(f"export option {self.flag}: kind {self.kind!r} is not one of {OPTION_KINDS}")
        if not self.dest:
            object.__setattr__(self, "dest", self.flag.lstrip("-").replace("-", "_"))


@dataclass(frozen=True)
class ExportFormat:
    """An export of a run: ``name`` (``export NAME``), ``suffix`` of its file (".ply"), ``help`` (one
    line), ``extracts`` (what it takes of the field), ``options`` (its own flags, besides the common
    ``--out --resolution --overwrite --checkpoint --device``), ``beside`` (suffixes of files that
    others write beside it: the add-on's ``.vdb`` of a volume), ``grid`` (False for a format that
    samples no grid over the scene box, such as the world: it has no ``--resolution``)."""

    name: str
    suffix: str
    help: str
    extracts: str
    options: Tuple[Option, ...] = ()
    beside: Tuple[str, ...] = ()
    grid: bool = True


EXPORTS: Dict[str, ExportFormat] = {}


def declare(fmt: ExportFormat) -> ExportFormat:
    """Add ``fmt`` to the table (ValueError when its name is taken by another declaration)."""
    if not fmt.suffix.startswith(".") or fmt.suffix != fmt.suffix.lower():
        raise ValueError(f"export {fmt.name}: suffix {fmt.suffix!r} must be a lower-case '.ext'")
    old = EXPORTS.get(fmt.name)
    if old is not None and old != fmt:
        raise ValueError(f"export {fmt.name!r} is declared twice")
    EXPORTS[fmt.name] = fmt
    return fmt


def export_format(name: str, where: str = "export") -> ExportFormat:
    """The declared format ``name``; ValueError naming ``where`` and the formats there are."""
    fmt = EXPORTS.get(name) if isinstance(name, str) else None
    if fmt is None:
        raise ValueError(f"{where}: unknown export {name!r}; one of {', '.join(sorted(EXPORTS))}")
    return fmt


def export_suffix(name: str) -> str:
    """The suffix of format ``name``'s file (".ply" for "mesh")."""
    return export_format(name).suffix


def export_file_name(name: str, number: int) -> str:
    """``mesh_001.ply``: the ``number``-th file of format ``name`` in a run's ``geometry/`` folder."""
    return f"{name}_{number:03d}{export_suffix(name)}"


def option(fmt: ExportFormat, dest: str) -> Optional[Option]:
    return next((o for o in fmt.options if o.dest == dest), None)


MESH = declare(ExportFormat(
    "mesh", ".ply", "marching cubes, culled and coloured: binary PLY",
    "the surface at a density level, culled to what the training cameras see, coloured head-on",
    options=(
        Option("--faces", "positive_int", "decimate to about N faces", dest="n_faces"),
        Option("--level", "positive_float", "surface density per scene unit (default: where the training rays "
               "first meet the surface, transmittance 0.95 over the 4 grid steps before it)", metavar="SIGMA"),
        Option("--min-component", "share", "drop connected pieces with less than this share of the total area "
               "(floaters; 0 keeps all)", default=0.005, metavar="SHARE"),
        Option("--keep-unseen", "switch", "keep what no training camera sees"),
    )))
VOLUME = declare(ExportFormat(
    "volume", ".npz", "density and colour grids (.npz) for a Blender Volume",
    "density per scene unit and colour at the nodes of a grid over the scene box, and for a run that models "
    "the world beyond it (unbounded), nested grids out to 2^N times the box", beside=(".vdb",),
    options=(Option("--far-levels", "nonneg_int", "grids beyond the box of an unbounded run, each twice the one "
                    "before (default 4: out to 16 times the box; 0: the box only)"),)))
WORLD = declare(ExportFormat(
    "world", ".png", "the learned world (light from infinity) as an equirectangular PNG for a Blender World",
    "the world behind the scene box that an opaque capture's run learned, in Blender's equirectangular "
    "layout, with the colours the NeRF renders",
    options=(Option("--width", "positive_int", "image width in pixels, height half of it (default: the learned "
                    "world's finest texture)"),),
    beside=(".exr",), grid=False))

"""Where an export may write: the output rule (``contract.outputs.check_output``), before any work."""
from __future__ import annotations

from pathlib import Path

from nerf_core.contract.outputs import check_output as _output_rule


def check_output(path: Path | str, overwrite: bool, flag: str = "--out", suffix: str = "") -> Path:
    """The output path, after refusing (ValueError naming ``flag``) a link, a folder, a FIFO or another
    non-file, a missing parent folder, a dataset's own file, an existing file without ``overwrite``,
    and, with ``suffix`` (".ply"), a name with another suffix: a mesh in ``mesh.txt`` or grids in
    ``volume.ply`` would open in the wrong program, or in none."""
    return _output_rule(path, overwrite, flag=flag, suffix=suffix)

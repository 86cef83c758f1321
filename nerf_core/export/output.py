"""Where an export may write: one clear error before any work for a path that cannot take the file,
and no user file replaced without ``--overwrite``."""
from __future__ import annotations

from pathlib import Path

from nerf_core.contract.paths import not_a_regular_file


def check_output(path: Path | str, overwrite: bool, flag: str = "--out", suffix: str = "") -> Path:
    """The output path, after refusing (ValueError naming ``flag``) a folder, a FIFO or another
    non-file, a missing parent folder, an existing file without ``overwrite``, and, with ``suffix``
    (".ply"), a name with another suffix: a mesh in ``mesh.txt`` or grids in ``volume.ply`` would
    open in the wrong program, or in none."""
    path = Path(path)
    if not str(path).strip():
        raise ValueError(f"{flag}: is empty; name the file to write")
    kind = not_a_regular_file(path)
    if kind:
        raise ValueError(f"{flag} {path}: {kind}; name the file to write")
    if suffix and path.suffix.lower() != suffix:
        raise ValueError(f"{flag} {path}: this export writes a {suffix} file; name one ending in {suffix}")
    if not path.parent.is_dir():
        raise ValueError(f"{flag} {path}: folder {path.parent} does not exist")
    if path.exists() and not overwrite:
        raise ValueError(f"{flag} {path}: exists; pass --overwrite to replace it")
    return path

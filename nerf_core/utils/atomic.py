"""Atomic file writes: the one home of write-to-a-temporary-file-then-rename (standard library and
``nerf_core.contract`` only, so the scripts import it under Blender's Python too).

A reader (another process, a crash, a full disk) never sees a half-written file: the content goes
to a temporary file beside the target, which replaces the target only once it is complete. On
failure the temporary file is removed and the target keeps its previous content.

Nothing is ever written through a link (docs/CONTRACTS.md, "Outputs"):

* every temporary is new: created exclusively (``O_CREAT | O_EXCL | O_NOFOLLOW``) under a random
  name, so a link or a stale file planted at a temporary name is never opened, never reused;
* a target that is a symbolic link is refused (``LinkRefused``, one line naming it) before the
  work and again just before the rename, which replaces the link's own entry, never its file.

    with atomic_file(run / "latest.pt") as fh:      # an open file: torch.save, np.savez, zipfile
        torch.save(state, fh)
    with atomic_path(out / "scene.blend") as tmp:   # a fresh path: writers that only take a name
        bpy.ops.wm.save_as_mainfile(filepath=str(tmp), copy=True)
    write_json_atomic(run / "config.json", config)
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
import shutil
import tempfile
from pathlib import Path
from typing import IO, Any, Iterator

from nerf_core.contract.outputs import link_problem

# A temporary's name: ``.NAME.<random>.tmp`` (a file) or ``.NAME.<random>.tmpdir/NAME`` (a private
# folder, for writers that take a path): hidden from a folder listing, recognisable as a leftover.
TEMP_SUFFIX = ".tmp"
TEMP_DIR_SUFFIX = ".tmpdir"
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)  # Windows has none; O_EXCL alone never opens an existing name
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)


class LinkRefused(OSError):
    """A write refused because its target is a link (or no regular file); ``str()`` is the one line."""


def temp_name(path: Path, suffix: str = TEMP_SUFFIX) -> Path:
    """``DIR/.NAME.<random>.tmp``: a name no earlier run used (the random part has 64 bits)."""
    return path.with_name(f".{path.name}.{secrets.token_hex(8)}{suffix}")


def refuse_link(path: Path | str, flag: str = "") -> None:
    """Raise ``LinkRefused`` when ``path`` is a symbolic link (dangling or not) or exists as something
    other than a regular file (``contract.outputs.link_problem``): replacing it would silently retarget
    a name the user made, or write where no file should go."""
    problem = link_problem(path)
    if problem:
        raise LinkRefused(f"{_named(path, flag)}: {problem}")


def _named(path: Path | str, flag: str) -> str:
    return f"{flag} {path}" if flag else str(path)


def open_exclusive(path: Path | str, binary: bool = True) -> IO:
    """Open a new file at ``path`` for writing: created here and now (``O_EXCL``), never through a link
    (``O_NOFOLLOW``); FileExistsError when anything (a file, a link, a dangling link) is there."""
    def opener(name: str, flags: int) -> int:  # mode "x" is O_CREAT | O_EXCL; the umask decides the rest
        return os.open(name, flags | _NOFOLLOW | _CLOEXEC, 0o666)

    # (builtin open keeps the name on the file object: error messages and writers read it there)
    return open(path, "xb", opener=opener) if binary else open(path, "x", encoding="utf-8", newline="", opener=opener)


def _new_temp(path: Path, binary: bool) -> tuple[Path, IO]:
    for _ in range(100):  # a clash of 64 random bits means someone plants names: try others
        tmp = temp_name(path)
        try:
            return tmp, open_exclusive(tmp, binary)
        except FileExistsError:
            continue
    raise FileExistsError(f"{path}: cannot create a new temporary file beside it")


def _commit(tmp: Path, path: Path, flag: str, replace: bool = True) -> None:
    refuse_link(path, flag)  # again: a link may have appeared while the content was written
    if replace:
        os.replace(tmp, path)
        return
    try:  # a hard link fails where the name exists: nothing that appeared meanwhile is replaced
        os.link(tmp, path)
    except FileExistsError:
        raise
    except OSError:  # no hard links here (FAT, some network shares): check, then rename
        if os.path.lexists(path):
            raise FileExistsError(errno.EEXIST, "exists", str(path)) from None
        os.replace(tmp, path)


@contextlib.contextmanager
def atomic_file(path: Path | str, binary: bool = True, flag: str = "", replace: bool = True) -> Iterator[IO]:
    """Yield a new temporary file (open for writing) beside ``path``; on a clean exit it replaces ``path``.

    Args:
        path: the file to write; refused (``LinkRefused``) when it is a symbolic link or no regular file.
        binary: ``True`` for bytes, ``False`` for UTF-8 text.
        flag: the option that named ``path`` ("--out"), for the error message.
        replace: ``False``: never replace a file (FileExistsError when one appeared while writing).
    Raises:
        whatever the body raised, after removing the temporary file.
    """
    path = Path(path)
    refuse_link(path, flag)
    tmp, fh = _new_temp(path, binary)
    try:
        with fh:
            yield fh
        _commit(tmp, path, flag, replace)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()  # (after a rename the name is gone already; after a hard link it is the spare)


@contextlib.contextmanager
def atomic_path(path: Path | str, flag: str = "", beside: bool = False) -> Iterator[Path]:
    """Yield a fresh path to write (for writers that take a name: PIL, OpenEXR, Blender's
    ``save_as_mainfile``); on a clean exit that file replaces ``path``.

    The path lies in a new private folder beside ``path`` (``mkdtemp``: exclusive, mode 0700), with
    ``path``'s own name, so a writer that adds its own temporary or a backup does so inside it; the
    folder is removed in every case. ``beside``: the path is a new file (``.NAME.<random>.tmp``,
    reserved with ``O_EXCL``) in ``path``'s own folder instead, for writers whose output refers to
    files relative to its folder (Blender's ``save_as_mainfile``: its ``NAME@`` temporary and
    ``NAME1`` backup are removed afterwards too).

    Raises:
        ``LinkRefused`` when ``path`` is a symbolic link or no regular file; whatever the body raised.
    """
    path = Path(path)
    refuse_link(path, flag)
    if beside:
        tmp, fh = _new_temp(path, binary=True)
        fh.close()
        try:
            yield tmp
            refuse_link(tmp, flag)  # the writer replaced our reservation by its own file, never a link
            _commit(tmp, path, flag)
        finally:
            for p in (tmp, Path(f"{tmp}@"), Path(f"{tmp}1")):
                with contextlib.suppress(OSError):
                    p.unlink()
        return
    folder = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=TEMP_DIR_SUFFIX, dir=path.parent))
    tmp = folder / path.name
    try:
        yield tmp
        if tmp.is_symlink() or not tmp.is_file():
            raise FileNotFoundError(f"{path}: the writer wrote no file")
        _commit(tmp, path, flag)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def write_bytes_atomic(path: Path | str, data: bytes, flag: str = "") -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_file(path, flag=flag) as fh:
        fh.write(data)


def write_text_atomic(path: Path | str, text: str, flag: str = "") -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_file(path, binary=False, flag=flag) as fh:
        fh.write(text)


def write_json_atomic(path: Path | str, data: Any, **dumps_kwargs) -> None:
    """Write ``data`` as indented JSON to ``path`` atomically; ``dumps_kwargs`` go to ``json.dumps``."""
    write_text_atomic(path, json.dumps(data, indent=2, **dumps_kwargs))


def is_leftover_temp(name: str) -> bool:
    """Whether a file or folder name is a temporary this module made (``.NAME.<hex>.tmp[dir]``) that a
    killed writer left behind: ``--overwrite`` and folder checks count it as the writer's own."""
    if not name.startswith("."):
        return False
    for suffix in (TEMP_SUFFIX, TEMP_DIR_SUFFIX):
        if name.endswith(suffix):
            rest = name[1:-len(suffix)]
            stem, _, token = rest.rpartition(".")
            return bool(stem) and len(token) >= 6 and all(c in "0123456789abcdefghijklmnopqrstuvwxyz_" for c in token)
    return False

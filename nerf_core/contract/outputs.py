"""The output rule: where a command may write, the one home every script and CLI verb calls
(standard library + numpy: the scripts use it under Blender's Python too).

An output is refused, with one line naming the flag and the path, before any work when

* it is, or passes through as its last part, a symbolic link (dangling or not): nothing is written
  through a link;
* it exists and is not a regular file (a folder, a FIFO, a device), or its folder is missing;
* it is an input of the same command (``inputs``), compared by identity (device and inode), so a
  link, a relative path or a hard link to the input is caught too;
* it is a file that a dataset's transforms file names (an image, depth, normal or mask), or a
  transforms file itself, of any dataset the output's folder is or lies in: even with ``--overwrite``;
* it exists and ``overwrite`` is off.

``--overwrite`` replaces outputs; it never deletes an input (``refuse_deleting_inputs``).

    out = check_output(args.out, args.overwrite, {"--blend": args.blend}, suffix=".blend")
"""
from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import Dict, Iterable, List, Mapping, Optional, Sequence

from .errors import DatasetError
from .transforms import SPLITS, frame_infos


class OutputError(ValueError):
    """An output refused by the rule; ``str()`` is the one line to print."""


def identity(path: Path | str) -> Optional[tuple]:
    """(device, inode) of the file ``path`` names, through links; None when there is none."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def same_file(a: Path | str, b: Path | str) -> bool:
    """Whether two paths name one file, by identity (links, relative paths and hard links included)."""
    ia = identity(a)
    return ia is not None and ia == identity(b)


def link_problem(path: Path | str) -> Optional[str]:
    """Why ``path`` may not be written in place (a message end), else None: a symbolic link (dangling
    or not), a link loop, or something that is no regular file."""
    try:
        mode = os.lstat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):  # nothing there (a file in the way is named by its writer)
        return None
    except (OSError, ValueError) as exc:
        return f"cannot be written ({os.strerror(getattr(exc, 'errno', 0) or errno.EINVAL).lower()})"
    if stat.S_ISLNK(mode):
        try:
            os.stat(path)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                return "is a symbolic link loop (a link that points back to itself); remove it or choose another name"
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        where = "" if os.path.exists(path) else ", which does not exist"
        return (f"is a symbolic link (to {target}{where}); nothing is written through a link. Remove the link or "
                "name another file")
    if stat.S_ISDIR(mode):
        return "is a folder, not a file; name the file to write"
    if stat.S_ISFIFO(mode):
        return "is a named pipe (FIFO), not a regular file; name the file to write"
    if not stat.S_ISREG(mode):
        return "exists and is not a regular file; name the file to write"
    return None


def dataset_files(*paths) -> Dict[Path, str]:
    """{resolved file: 'FILE: frame K (PATH)'} of every image, depth, normal and mask file, and the
    transforms files, of the datasets (folders or transforms files) at ``paths``, all splits; a path
    that is not a dataset adds nothing. No output is written over these, even with --overwrite."""
    out: Dict[Path, str] = {}
    for path in paths:
        if not path:
            continue
        try:
            _, root, infos, _ = frame_infos(path, SPLITS)
        except (DatasetError, OSError, ValueError):
            continue
        for jf in sorted(Path(root).glob("transforms*.json")):
            _protect(out, jf, f"{jf.name} (the dataset's transforms file)")
        for frames in infos.values():
            for fr in frames:
                for f in (fr.image, fr.depth, fr.normal, fr.mask):
                    if f is not None:
                        _protect(out, Path(f), fr.where)
    return out


def _protect(out: Dict[Path, str], path: Path, why: str) -> None:
    try:
        out.setdefault(path.resolve(), why)
    except (OSError, RuntimeError):  # a symlink loop: not a file we could overwrite
        pass


def datasets_around(path: Path | str) -> Dict[Path, str]:
    """``dataset_files`` of every dataset that the folder of ``path`` is or lies in."""
    folder = Path(os.path.abspath(path)).parent
    try:
        real = folder.resolve()
    except (OSError, RuntimeError):
        real = folder
    return dataset_files(*dict.fromkeys([folder, *folder.parents, real, *real.parents]))


def check_output(path: Path | str, overwrite: bool, inputs: Optional[Mapping[str, object]] = None,
                 flag: str = "--out", suffix: str = "", protected: Optional[Dict[Path, str]] = None,
                 need_folder: bool = True) -> Path:
    """The absolute output path, once the rule (module docstring) lets it be written.

    Args:
        path: the file to write, as the user typed it.
        overwrite: whether an existing output may be replaced.
        inputs: {flag or description: path or None} of what the command reads.
        flag: the option that named ``path``, for the message.
        suffix: the suffix the file must end in (".ply"), or "" for any.
        protected: files never to write (``dataset_files``); default: those of the datasets around ``path``.
        need_folder: refuse a missing folder (``False``: the command makes it).
    Raises:
        OutputError naming ``flag`` and ``path``.
    """
    text = os.fspath(path) if isinstance(path, os.PathLike) else str(path)
    if not text.strip():
        raise OutputError(f"{flag}: is empty; name the file to write")
    try:
        out = Path(os.path.abspath(text))
        os.lstat(out.parent)  # a NUL byte or a name too long fails here
    except ValueError:
        raise OutputError(f"{flag} {text!r}: not a usable file name") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputError(f"{flag} {text}: a symbolic link loop in its folders; choose another name") from None
    check_not_an_input(out, text, inputs or {}, flag)  # first: a link to an input is named as the input
    problem = link_problem(out)
    if problem:
        raise OutputError(f"{flag} {text}: {problem}")
    if suffix and out.suffix.lower() != suffix:
        raise OutputError(f"{flag} {text}: this command writes a {suffix} file; name one ending in {suffix}")
    if need_folder and not out.parent.is_dir():
        raise OutputError(f"{flag} {text}: folder {out.parent} does not exist")
    check_not_a_dataset_file(out, text, datasets_around(out) if protected is None else protected, flag)
    if os.path.lexists(out) and not overwrite:
        raise OutputError(f"{flag} {text} already exists; pass --overwrite to replace it, or choose another name")
    return out


def check_outputs_in(folder: Path | str, names: Sequence[str], overwrite: bool,
                     inputs: Optional[Mapping[str, object]] = None, flag: str = "--out") -> List[Path]:
    """The rule for a command that writes many files (``names``, relative) into ``folder`` (which
    may not exist yet): each as ``check_output`` would take it; existing ones are listed together."""
    root = Path(os.path.abspath(os.fspath(folder)))
    problem = link_problem(root)
    if problem and not problem.startswith("is a folder"):
        raise OutputError(f"{flag} {folder}: {problem}")
    protected = datasets_around(root / "x")
    existing, out = [], []
    for name in names:
        target = root / name
        problem = link_problem(target)
        if problem:
            raise OutputError(f"{flag} {folder}: {name} {problem}")
        check_not_an_input(target, str(target), inputs or {}, flag)
        check_not_a_dataset_file(target, str(target), protected, flag)
        if os.path.lexists(target):
            existing.append(name)
        out.append(target)
    if existing and not overwrite:
        more = f" and {len(existing) - 1} more" if len(existing) > 1 else ""
        raise OutputError(f"{flag} {folder}: already holds {existing[0]}{more}; pass --overwrite or choose another "
                          "folder")
    return out


def check_not_an_input(out: Path, text: str, inputs: Mapping[str, object], flag: str) -> None:
    """OutputError when ``out`` is the same file as one of ``inputs`` (by identity)."""
    for name, src in inputs.items():
        if src and same_file(out, os.fspath(src)):
            raise OutputError(f"{flag} {text}: is the same file as {name} {src}; an output never replaces an input. "
                              "Choose another name")


def check_not_a_dataset_file(out: Path, text: str, protected: Dict[Path, str], flag: str) -> None:
    """OutputError when ``out`` (resolved) is a file a dataset's transforms file names."""
    try:
        frame = protected.get(out.resolve())
    except (OSError, RuntimeError):
        frame = None
    if frame is not None:
        raise OutputError(f"{flag} {text}: is a dataset's own file ({frame}); outputs never replace a dataset's "
                          "files, even with --overwrite. Choose another name")


def refuse_deleting_inputs(doomed: Iterable[Path | str], inputs: Mapping[str, object], flag: str = "--out") -> None:
    """OutputError when ``--overwrite`` would delete an input: one of ``inputs`` is, or lies inside, a
    path in ``doomed`` (compared by identity, so links and hard links count), or a doomed path is a
    symbolic link (deleting through it would reach a user's folder)."""
    wanted = {identity(v): (k, v) for k, v in inputs.items() if v and identity(v) is not None}
    for d in doomed:
        d = Path(d)
        if d.is_symlink():
            raise OutputError(f"{flag} {d.parent}: {d.name} is a symbolic link (to {os.readlink(d)}); --overwrite "
                              "deletes only the dataset's own files, never through a link. Remove the link or "
                              "choose another folder")
        if not wanted or not os.path.lexists(d):
            continue
        walk = [d] + ([p for p in d.rglob("*") if not p.is_symlink()] if d.is_dir() else [])
        for p in walk:
            hit = wanted.get(identity(p))
            if hit is not None:
                raise OutputError(f"{flag} {d.parent}: --overwrite would delete {p}, which is {hit[0]} {hit[1]}; "
                                  "an input is never deleted. Move it out of the folder or choose another one")

"""Why a path is not a file that can be read: the one helper every reader uses (standard library).

A path that exists but is no regular file (a folder, a named pipe, a device such as /dev/zero, a
socket) would hang or flood a reader, and must not be reported as "missing"; a missing one gets
the likeliest reason (case, extension, Windows separators, Unicode normalisation, a dangling link,
a missing folder).

    problem = file_problem(path)
    if problem:
        raise DatasetError(f"{path}: {problem}")
"""
from __future__ import annotations

import os
import stat
import unicodedata
from pathlib import Path
from typing import Optional

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".exr")


def not_a_regular_file(path: Path | str) -> Optional[str]:
    """What ``path`` is when it exists but is not a regular file ("is a folder, not a file", "is a named
    pipe (FIFO), not a regular file", ...), else None (a regular file, or nothing there)."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "is a folder, not a file"
    if stat.S_ISFIFO(mode):
        return "is a named pipe (FIFO), not a regular file"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "is a device, not a regular file"
    if stat.S_ISSOCK(mode):
        return "is a socket, not a regular file"
    return "is not a regular file"


def file_problem(path: Path | str, written: Optional[str] = None) -> Optional[str]:
    """None when ``path`` is a regular file this process may read; otherwise why not, as the end of a
    message after its name (``why_not_a_file``, or "cannot be read (permission denied)").

    Args:
        path: the file to read.
        written: the path as the user wrote it (in a JSON field or a flag), for the hints.
    """
    path = Path(path)
    try:
        regular = stat.S_ISREG(os.stat(path).st_mode)
    except (OSError, ValueError):
        regular = False
    if not regular:
        return why_not_a_file(path, written)
    if not os.access(path, os.R_OK):
        return "cannot be read (permission denied)"
    return None


def why_not_a_file(path: Path | str, written: Optional[str] = None) -> str:
    """Why ``path`` (a file a dataset names; ``written``: the value as written in the JSON) cannot be
    read, as the end of a message after its name: "not found; r_1.PNG exists there (names are
    case-sensitive)". The hints cover what other tools and operating systems write differently:
    case, an extension left out or added, Windows separators, a folder, a dangling link."""
    path = Path(path)
    kind = not_a_regular_file(path)
    if kind:
        return kind
    if path.is_symlink():
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        return f"is a link to {target}, which does not exist"
    if written is not None and "\\" in written:
        return f"not found; the path is written with '\\' ({written!r}): write '/' between folders"
    folder = path.parent
    if not folder.is_dir():
        return f"not found (its folder {folder} does not exist)"
    try:
        names = [n for n in os.listdir(folder) if not n.startswith(".")]
    except OSError:
        return "not found"
    normalised = [
        n
        for n in names
        if n != path.name and unicodedata.normalize("NFC", n) == unicodedata.normalize("NFC", path.name)
    ]
    if normalised:
        return (f"not found; {normalised[0]!r} exists there, the same name with its accents encoded another way "
                "(Unicode NFC vs NFD, as macOS and Linux write them): rename the file or fix the path")
    same_case = [n for n in names if n.lower() == path.name.lower()]
    if same_case:
        return f"not found; {same_case[0]} exists there (file names are case-sensitive)"
    stem = path.name[: -len(path.suffix)] if path.suffix.lower() in IMAGE_EXTS else path.name
    other_ext = sorted(n for n in names if Path(n).stem.lower() == stem.lower() and n != path.name)
    files = [n for n in other_ext if not (folder / n).is_dir()]
    if files:
        return f"not found; {', '.join(files[:3])} exists there: write the file name with its extension"
    if other_ext:  # "./train" names the split's folder, not one of its images
        return f"not found; {other_ext[0]} there is a folder: file_path must name an image in it"
    return "not found"

"""Where an export may write: the output rule (``contract.outputs.check_output``) and a write probe,
before any work; and a failed write (a full disk, ``ulimit -f``) named by its output file."""
from __future__ import annotations

import contextlib
import errno
import zipfile
from pathlib import Path
from typing import Iterator

from nerf_core.contract.outputs import check_output as _output_rule
from nerf_core.runs.folder import os_reason
from nerf_core.utils.atomic import LinkRefused, open_exclusive, temp_name

FULL = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)  # the disk or a limit: the user can make room


def check_output(path: Path | str, overwrite: bool, flag: str = "--out", suffix: str = "") -> Path:
    """The output path, after refusing (ValueError naming ``flag``) a link, a folder, a FIFO or another
    non-file, a missing parent folder, a dataset's own file, an existing file without ``overwrite``,
    and, with ``suffix`` (".ply"), a name with another suffix: a mesh in ``mesh.txt`` or grids in
    ``volume.ply`` would open in the wrong program, or in none."""
    return _output_rule(path, overwrite, flag=flag, suffix=suffix)


def probe_writable(path: Path | str, flag: str = "--out") -> None:
    """Refuse (ValueError naming ``flag`` and ``path``) a folder where no new file can be made, by making
    one: the temporary an atomic write would make there, created exclusively and removed at once. Run
    before the work: ``/proc/x.ply`` or a read-only folder once failed only after the whole export,
    naming the hidden temporary."""
    path = Path(path)
    probe = temp_name(path)
    try:
        open_exclusive(probe).close()
    except OSError as exc:
        raise ValueError(f"{flag} {path}: cannot create a file in {path.parent} ({os_reason(exc)})") from None
    with contextlib.suppress(OSError):
        probe.unlink()


@contextlib.contextmanager
def writing(path: Path | str, flag: str = "--out") -> Iterator[None]:
    """Name ``path`` in a write that fails inside the block (ValueError: "--out FILE: cannot write: no
    space left on device"): the writers' own errors name a hidden temporary or nothing, and ``np.savez``'s
    zip layer can turn a short write into ``zipfile``'s errors. The atomic writers have removed their
    temporary by then, so the old file, if any, is unchanged."""
    try:
        yield
    except LinkRefused:
        raise  # names the file already
    except OSError as exc:
        if exc.errno is None:
            raise
        advice = "; free space or raise the limit, then export again" if exc.errno in FULL else ""
        raise ValueError(f"{flag} {path}: cannot write: {os_reason(exc)}; nothing was written{advice}") from None
    except (zipfile.BadZipFile, zipfile.LargeZipFile) as exc:
        raise ValueError(f"{flag} {path}: cannot write: the zip file could not be finished ({exc}); "
                         "nothing was written") from None

"""The run folder a trainer writes (``--out RUN``): its checks, its lock, and what ``--overwrite`` may remove.

Rules (docs/CONTRACTS.md, "Run folder"; every file name comes from ``nerf_core.contract``):

* an existing non-empty run folder is refused unless ``--resume`` or ``--overwrite``
  (``check_run_folder``); a run folder must not be, hold or sit inside the dataset
  (``check_run_vs_dataset``);
* one trainer at a time writes a run: it holds an exclusive ``flock`` on ``RUN/.lock``
  (``lock_run_folder``);
* every file a trainer writes is listed in ``RUN/.written.json`` before it is written
  (``record_written``), and ``--overwrite`` removes only those (``clear_run_folder``);
* ``--resume`` continues on the dataset the run was trained on, recognised by ``dataset_hash``
  (``resume_dataset``).

Checkpoint files themselves (writing, reading, loading a model) live in ``nerf_core.runs.checkpoints``.
"""
from __future__ import annotations

import errno
import json
import os
import re
import stat
import sys
import time
from glob import escape as glob_escape
from pathlib import Path
from typing import Callable, List, Optional

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None

from nerf_core import contract
from nerf_core.errors import TrainError

# The dataset a run belongs to has its own module; these names stay importable from here.
from nerf_core.runs.dataset_identity import dataset_changed_note, dataset_hash, resume_dataset  # noqa: F401
from nerf_core.utils.atomic import is_leftover_temp, write_json_atomic

RUN_LOCK = contract.LOCK  # RUN/.lock: held (flock) by the one trainer writing RUN; holds its PID
WRITTEN_LIST = contract.WRITTEN_LIST  # RUN/.written.json: every file (relative path) this run's trainers wrote

_STEP_PT = contract.step_name_pattern(".pt")
_STEP_PNG = contract.step_name_pattern(".png")
_CK = re.escape(contract.CHECKPOINTS_DIR)
_PV = re.escape(contract.PREVIEWS_DIR)
# What a trainer writes, by exact name: the only files --overwrite removes in a run that has no WRITTEN_LIST.
LEGACY_WRITTEN = re.compile(
    "|".join(re.escape(n) for n in (contract.CONFIG, contract.PROGRESS, contract.METRICS))
    + f"|{_CK}/{re.escape(contract.LATEST_CHECKPOINT)}|{_CK}/{_STEP_PT}|{_PV}/{_STEP_PNG}")
# Files a trainer writes before its first checkpoint: a folder holding only these can be started again.
PRE_CHECKPOINT = re.compile(
    f"{re.escape(contract.CONFIG)}|{re.escape(contract.PROGRESS)}|{_PV}/{_STEP_PNG}|{re.escape(WRITTEN_LIST)}"
    f"|{_CK}/({re.escape(contract.LATEST_CHECKPOINT)}|{_STEP_PT})\\.tmp"  # an older trainer's fixed temporary
    f"|{_CK}/\\.({re.escape(contract.LATEST_CHECKPOINT)}|{_STEP_PT})\\.[0-9a-f]{{16}}\\.tmp")  # utils.atomic's


def read_written(run: Path) -> Optional[List[str]]:
    """The relative paths listed in RUN/.written.json; None when the run has no (readable) list."""
    try:
        names = json.loads((run / WRITTEN_LIST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(names, list):
        return None
    return [n for n in names if isinstance(n, str)]


def record_written(run: Path, *paths: Path) -> None:
    """Add ``paths`` (files inside ``run``) to RUN/.written.json, atomically (tmp file + rename)."""
    names = read_written(run) or []
    added = False
    for p in paths:
        rel = _own_file(run, Path(p))
        if rel not in names:
            names.append(rel)
            added = True
    if added or not (run / WRITTEN_LIST).is_file():
        write_json_atomic(run / WRITTEN_LIST, names, default=str)


def _link_in_path(run: Path, path: Path) -> Optional[Path]:
    """The first part of ``path`` (below ``run``) that is a symbolic link, else None."""
    try:
        rel = path.relative_to(run)
    except ValueError:
        return path
    at = run
    for part in rel.parts:
        at = at / part
        if at.is_symlink():
            return at
    return None


def _own_file(run: Path, path: Path) -> str:
    """``path`` relative to ``run`` (posix) when it is a run's own file: inside the run folder, and no
    part of it a symbolic link (a link would carry a write, or a later --overwrite, out of the run).
    Raises TrainError naming the link or the path otherwise."""
    run_abs, path_abs = Path(os.path.abspath(run)), Path(os.path.abspath(path))
    try:
        rel = path_abs.relative_to(run_abs)
    except ValueError:
        raise TrainError(f"{path}: lies outside the run folder {run}; a run writes only inside it") from None
    if not rel.parts or ".." in rel.parts:
        raise TrainError(f"{path}: lies outside the run folder {run}; a run writes only inside it")
    link = _link_in_path(run_abs, path_abs)
    if link is not None:
        raise TrainError(f"{link}: is a symbolic link (to {os.readlink(link)}) inside the run folder {run}; a run "
                         "writes and removes only its own files. Remove the link, or choose another --out")
    return rel.as_posix()


def removable(run: Path, rel: str) -> Optional[Path]:
    """``run/rel`` when --overwrite may remove it: a plain relative path, no part of it a symbolic link,
    and its resolved path inside the resolved run folder; else None (it is left alone)."""
    p = _inside(run, rel)
    if p is None or _link_in_path(run, p) is not None:
        return None
    real_run = run.resolve()
    real = p.resolve()
    if real == real_run or real_run not in real.parents:
        return None
    return p


def _inside(run: Path, rel: str) -> Optional[Path]:
    """``run/rel`` when ``rel`` is a plain relative path that stays inside ``run`` (no .., not absolute)."""
    parts = Path(rel).parts
    if not parts or Path(rel).is_absolute() or ".." in parts or rel == RUN_LOCK:
        return None
    return run / rel


def _written_by_a_trainer(run: Path) -> bool:
    """Whether a folder without RUN/.written.json is a run from before that list: its config.json is
    a trainer's (a JSON object naming the method and the dataset). A user's own folder that happens
    to hold a config.json or metrics.json is not."""
    try:
        cfg = json.loads((run / contract.CONFIG).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(cfg, dict) and isinstance(cfg.get("method"), str) and "dataset" in cfg


def trainer_written(run: Path) -> List[Path]:
    """Files in ``run`` that a previous training wrote (the only ones --overwrite may delete).

    Those listed in RUN/.written.json (and their leftover ``.tmp``), else, for runs from before that
    list, only the exact names a trainer writes. Never RUN/.lock, never a file a user put there.
    """
    listed = read_written(run)
    found: List[Path] = []
    if listed is not None:
        for rel in listed:
            p = removable(run, rel)
            if p is None:
                continue
            for cand in (p, p.with_name(p.name + ".tmp"), *_leftover_temps(p)):
                if cand.is_file() and not cand.is_symlink() and cand not in found:
                    found.append(cand)
        if (run / WRITTEN_LIST).is_file():
            found.append(run / WRITTEN_LIST)
        return found
    if not _written_by_a_trainer(run):
        return found  # not a run at all: nothing in it is ours to delete
    for p in sorted(run.rglob("*")) if run.is_dir() else []:
        rel = p.relative_to(run).as_posix()
        if p.is_file() and LEGACY_WRITTEN.fullmatch(rel) and removable(run, rel) is not None:
            found.append(p)
    return found


def _leftover_temps(path: Path) -> List[Path]:
    """The temporaries of ``path`` that a killed writer left (``utils.atomic``'s ``.NAME.<random>.tmp``)."""
    if not path.parent.is_dir():
        return []
    return [p for p in path.parent.glob(f".{glob_escape(path.name)}.*") if is_leftover_temp(p.name)
            and p.name[1:].rsplit(".", 2)[0] == path.name]


def run_contents(run: Path) -> List[str]:
    """Relative paths of the files in ``run`` (the lock excluded)."""
    if not run.is_dir():
        return []
    return sorted(p.relative_to(run).as_posix() for p in run.rglob("*") if p.is_file() and p.name != RUN_LOCK)


def resume_candidates(run: Path) -> List[Path]:
    """Checkpoints to resume from, best first: latest.pt, then step_*.pt from the newest."""
    ck = Path(contract.checkpoints_dir(run))
    latest = Path(contract.latest_checkpoint(run))
    out = [latest] if latest.is_file() else []
    if ck.is_dir():
        out += sorted((p for p in ck.glob(contract.step_glob(".pt")) if p.is_file()), reverse=True)
    return out


def check_run_layout(run: Path) -> None:
    """Refuse a run folder whose own names are symbolic links (a write or an --overwrite through one
    would reach a user's file outside the run) or whose checkpoints/previews folder is a file."""
    if not run.is_dir():
        return
    for name in (RUN_LOCK, contract.CONFIG, contract.PROGRESS, WRITTEN_LIST, contract.METRICS,
                 contract.CHECKPOINTS_DIR, contract.PREVIEWS_DIR, *_checkpoint_names(run)):
        _own_file(run, run / name)  # TrainError naming the link
    for name in (contract.CHECKPOINTS_DIR, contract.PREVIEWS_DIR):
        if (run / name).exists() and not (run / name).is_dir():
            raise TrainError(f"{run / name}: is a file, and the run keeps a folder there; move the file away")


def _checkpoint_names(run: Path) -> List[str]:
    """The checkpoints a resume reads and a checkpoint replaces, relative to ``run``."""
    ck = run / contract.CHECKPOINTS_DIR
    names = [f"{contract.CHECKPOINTS_DIR}/{contract.LATEST_CHECKPOINT}"]
    if ck.is_dir() and not ck.is_symlink():
        names += [f"{contract.CHECKPOINTS_DIR}/{p.name}" for p in ck.glob(contract.step_glob(".pt"))]
    return names


def check_run_folder(run: Path, resume: bool, overwrite: bool) -> None:
    """Refuse to touch an existing run unless asked (raises TrainError); changes nothing."""
    if resume and overwrite:
        raise TrainError("--resume and --overwrite contradict each other; pick one")
    if run.exists() and not run.is_dir():
        raise TrainError(f"--out {run}: {run.name} is a file, and a folder is needed there")
    check_run_layout(run)
    if resume:
        if not resume_candidates(run):
            latest = Path(contract.latest_checkpoint(run))
            files = run_contents(run)
            if not files:
                raise TrainError(f"{latest}: not found; nothing to resume (drop --resume to start a new run)")
            listed = f"{', '.join(files[:6])}{', ...' if len(files) > 6 else ''}"
            if all(PRE_CHECKPOINT.fullmatch(f) for f in files):
                raise TrainError(
                    f"{latest}: not found; nothing to resume: the trainer stopped before its first checkpoint. "
                    f"Start the run again with --overwrite instead of --resume (it removes only what that trainer "
                    f"wrote: {listed})"
                )
            raise TrainError(
                f"{latest}: not found and no {contract.CHECKPOINTS_DIR}/{contract.step_glob('.pt')} either; "
                f"nothing to resume. {run} "
                f"holds other files ({listed}): choose another --out, or --overwrite "
                "(removes only files a trainer wrote there)"
            )
        return
    # The writer lock (RUN_LOCK) is not content: a trainer starting a new run creates it before it
    # re-checks the folder, and a trainer killed with SIGKILL may leave it behind, unlocked.
    names = sorted(p.name for p in run.iterdir() if p.name != RUN_LOCK) if run.is_dir() else []
    if names and overwrite and read_written(run) is None and not _written_by_a_trainer(run):
        # Not a run (no .written.json, no trainer's config.json): --overwrite may delete nothing here,
        # and the new run would write over the user's files of the same names.
        clash = [f for f in run_contents(run) if LEGACY_WRITTEN.fullmatch(f) or PRE_CHECKPOINT.fullmatch(f)]
        if clash:
            shown = ", ".join(clash[:6]) + (", ..." if len(clash) > 6 else "")
            raise TrainError(
                f"{run}: is not a run folder written by train (no {WRITTEN_LIST}, and its {contract.CONFIG} is not a "
                f"trainer's), but holds files a run would write over ({shown}); --overwrite only replaces a run. "
                "Choose another --out"
            )
    if names and not overwrite:
        shown = ", ".join(names[:6]) + (", ..." if len(names) > 6 else "")
        raise TrainError(
            f"{run}: run folder exists and is not empty ({shown}); pass --resume to continue it, "
            "--overwrite to start again (removes only files the trainer wrote), or choose another --out"
        )


def dataset_overlap(folder, dataset) -> Optional[str]:
    """How an output ``folder`` overlaps the ``dataset`` folder (a sentence fragment), else None."""
    ds = Path(dataset).resolve()
    if ds.is_file():
        ds = ds.parent
    folder = Path(folder).resolve()
    if folder == ds:
        return "is the dataset folder itself"
    if ds in folder.parents:
        return f"lies inside the dataset folder {ds}"
    if folder in ds.parents:
        return f"contains the dataset {ds}"
    return None


def check_run_vs_dataset(run: Path, dataset) -> None:
    """Refuse a run folder that is the dataset folder, lies inside it, or contains it (TrainError)."""
    overlap = dataset_overlap(run, dataset)
    if overlap is None:
        return
    run = Path(run).resolve()
    why = {"is": "the run's files would mix with the dataset's. Choose a run folder outside the dataset",
           "lies": "tools that scan the dataset would find the run's files; choose a run folder outside the dataset",
           "contains": "--overwrite and the run's files would live beside your data. Choose a run folder that does "
                       "not hold the dataset"}[overlap.split()[0]]
    raise TrainError(f"--out {run}: {overlap}; {why}")


def check_progress_file(path: Path, dataset, run: Optional[Path] = None) -> None:
    """Refuse a ``--progress`` file that appending events would damage (TrainError): one inside the
    dataset folder (a transforms file, an image), one inside the run folder ``run`` (it would make a
    new run's folder "not empty" before the run starts, on every retry; the run writes
    RUN/progress.jsonl itself), or an existing file that is not a progress log (its first line is no
    JSON event). A log of an earlier run is appended to, as ``--resume`` expects."""
    path = Path(path)
    target = path.resolve()
    if run is not None and (target == Path(run).resolve() or Path(run).resolve() in target.parents):
        raise TrainError(f"--progress {path}: lies inside --out {run}; the run writes "
                         f"{contract.progress_path(Path(run))} itself. Leave --progress out, or name a file "
                         "outside the run folder")
    ds = Path(dataset).resolve()
    if ds.is_file():
        ds = ds.parent
    if target == ds or ds in target.parents:
        raise TrainError(f"--progress {path}: lies inside the dataset folder {ds}; the events would be appended "
                         "to your data. Choose a file outside the dataset")
    if target.is_dir():
        raise TrainError(f"--progress {path}: is a folder; name a file")
    if path.exists():
        try:  # /proc files, devices and read-only files fail here, named, rather than at the first event
            with open(path, "a", encoding="utf-8"):
                pass
        except OSError as exc:
            raise TrainError(f"--progress {path}: cannot append to it ({os_reason(exc)}); name a file") from None
    if target.is_file() and target.stat().st_size > 0:
        with open(target, "rb") as fh:
            first = fh.readline(1 << 16).decode("utf-8", errors="replace")
        if contract.parse_event_line(first) is None:
            raise TrainError(f"--progress {path}: exists and is not a progress log (its first line is no JSON "
                             "event); appending would damage it. Choose a new file")


def lock_run_folder(run: Path) -> Callable[[], None]:
    """Make this process the only trainer writing ``run``; returns the function that lets go.

    Two trainers started into one folder would both pass ``check_run_folder`` and then interleave
    their events and checkpoints. An exclusive, non-blocking ``flock`` on ``RUN/.lock`` settles it:
    the kernel drops the lock when the process dies however it dies, so a crash never leaves the
    run locked. The holder writes its PID into the file so that the refusal can say who holds it.
    Raises TrainError naming the folder and that PID when another process holds the lock.

    Releasing unlinks the file while still holding the lock, so a finished run leaves no lock file;
    that is why a winner checks that the file it locked is still the one at ``RUN/.lock``: it may
    have opened the file just before the previous holder unlinked it.

    The lock file is never opened through a link (``O_NOFOLLOW``) and nothing is ever truncated: a
    link, a hard link (a second name of some other file), or anything but a small regular file at
    ``RUN/.lock`` is refused with a TrainError naming it, before a byte is written.
    """
    if fcntl is None:
        # Windows has no flock. msvcrt.locking (mandatory byte-range locks) could stand in, but it
        # behaves differently enough (reads of the locked range fail, unlinking an open file fails)
        # to need its own tests on Windows; until then nothing is locked there.
        return lambda: None
    path = run / RUN_LOCK
    while True:
        fd = _open_lock_file(path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _lock_holder_pid(fd)
            os.close(fd)
            raise TrainError(
                f"{run}: another trainer (PID {holder or 'unknown'}) is writing to this run folder (it holds "
                f"{path}); wait for it to end or stop it, or choose another --out"
            ) from None
        except OSError as exc:  # a filesystem without locks (some network mounts): train unprotected
            os.close(fd)
            print(f"train: cannot lock {path} ({exc.strerror}); nothing stops a second trainer from writing "
                  "to this run folder at the same time", file=sys.stderr)
            return lambda: None
        try:
            current = os.stat(path)
        except FileNotFoundError:
            current = None
        if current is not None and os.path.samestat(os.fstat(fd), current):
            break
        os.close(fd)  # we locked a file the previous holder had just unlinked: lock the new one
    # A fixed-width record over what an earlier holder wrote (a PID is shorter): no truncation.
    os.pwrite(fd, f"{os.getpid()}".ljust(_LOCK_RECORD - 1).encode("ascii") + b"\n", 0)

    def release() -> None:
        try:
            os.unlink(path)
        except OSError:
            pass
        os.close(fd)

    return release


_LOCK_RECORD = 32  # bytes: the PID, padded with spaces, and a newline; a larger file is no lock file


def _open_lock_file(path: Path) -> int:
    """Open (or create) ``RUN/.lock`` for reading and writing, never through a link; a TrainError names
    it when it is a link, a hard link, or no lock file (not a regular file, or larger than a record)."""
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags | getattr(os, "O_NONBLOCK", 0), 0o644)  # (a FIFO must not block the open)
    except OSError as exc:
        if exc.errno == errno.ELOOP or os.path.islink(path):
            raise TrainError(f"{path}: is a symbolic link (to {os.readlink(path)}); the run's lock file is never "
                             "opened through a link. Remove the link, or choose another --out") from None
        # a folder we may not write to: training could not write there either
        raise TrainError(f"{path}: cannot create the run folder's lock file ({exc.strerror})") from None
    st = os.fstat(fd)
    problem = None
    if not stat.S_ISREG(st.st_mode):
        problem = "is not a regular file"
    elif st.st_nlink > 1:
        problem = f"is a hard link (one of {st.st_nlink} names of one file)"
    elif st.st_size > _LOCK_RECORD:
        problem = f"holds {st.st_size} bytes, more than a trainer's lock file"
    if problem:
        os.close(fd)
        raise TrainError(f"{path}: {problem}; the run's lock file is written only when it is the trainer's own. "
                         "Move it away, or choose another --out")
    return fd


def _lock_holder_pid(fd: int) -> Optional[int]:
    """The PID in a lock file held by someone else; waits briefly, as the holder writes it just after locking."""
    for _ in range(20):
        try:
            return int(os.pread(fd, 32, 0).decode("ascii").strip())
        except (OSError, ValueError, UnicodeDecodeError):
            time.sleep(0.05)
    return None


def clear_run_folder(run: Path) -> List[str]:
    """Delete what a previous training wrote in ``run``; return the removed paths (relative)."""
    removed = []
    for p in trainer_written(run):
        if removable(run, p.relative_to(run).as_posix()) is None:  # checked again just before: never outside
            continue
        p.unlink()
        removed.append(str(p.relative_to(run)))
    for sub in (contract.CHECKPOINTS_DIR, contract.PREVIEWS_DIR):
        d = run / sub
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()
    return removed


# How torch.save's C++ stream writer reports a failed write (a full disk, a file-size limit).
_STREAM_WRITER_FAILED = ("unexpected pos", "PytorchStreamWriter failed", "file write failed")


def os_reason(exc: BaseException) -> str:
    """'no space left on device' and the like, from an OSError (or torch's RuntimeError around one)."""
    err = getattr(exc, "errno", None)
    if err is None:
        cause = exc.__cause__ or exc.__context__
        err = getattr(cause, "errno", None)
        if err is None and "No space left on device" in str(exc):
            err = errno.ENOSPC
    if err == errno.ENOSPC:
        return "no space left on device"
    if err == errno.EFBIG:
        return "file too large (a file-size limit, ulimit -f, was reached)"
    if err is not None:
        return os.strerror(err).lower()
    if any(s in str(exc) for s in _STREAM_WRITER_FAILED):  # torch's writer hides the errno
        return "the write stopped part-way: the disk is full, or a file-size limit (ulimit -f) was reached"
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def os_error_text(exc: OSError) -> str:
    """One line for an OSError that reached the command line: the path first, the reason in words,
    and for a path through a file, which part is the file (instead of Python's ``[Errno 20] ...``)."""
    name = exc.filename if exc.filename is not None else ""
    where = f"{name} -> {exc.filename2}" if exc.filename2 is not None else str(name)
    text = f"{where}: {os_reason(exc)}" if where else os_reason(exc)
    path = Path(str(name)) if name else None
    if path is not None and exc.errno in (errno.ENOTDIR, errno.EEXIST):
        blocker = next((p for p in [path, *path.parents] if p.exists() and not p.is_dir()), None)
        if blocker is not None:
            text += f" ({blocker} is a file, and a folder is needed there)"
    return text

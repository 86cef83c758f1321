"""Training a method on a dataset: ``python -m nerf_core train DATASET --out RUN``.

What the loop guarantees (docs/CONTRACTS.md has the file layout and the event vocabulary):

* Seeded and deterministic for a step budget: python, numpy and torch RNGs are seeded, and batches
  come from a dedicated generator that is saved in checkpoints, so ``--resume`` continues the same
  random stream.
* Budgets: ``--max-steps`` and/or ``--max-seconds`` (training time only: previews, checkpoints and
  evaluation are not counted). The learning-rate schedule follows whichever budget is nearer.
* Robust: a NaN/inf loss or gradient, or a loss far above its running average, rolls the model
  and optimiser back to the last good in-memory snapshot and halves the learning rate
  (``rollback`` event); after too many rollbacks training stops with an ``error`` event.
* Never destroys data: an existing non-empty run folder is refused unless ``--resume`` or
  ``--overwrite``; ``--overwrite`` removes only files the trainer writes and lists them.
* One writer per run folder: a trainer holds an exclusive lock on ``RUN/.lock`` while it runs, and
  a second trainer into the same folder stops at once, naming the PID of the first.
* Checkpoints hold only tensors and plain Python data, so they load with ``weights_only=True``
  (``nerf_core.render.read_checkpoint`` refuses anything that could run code).
"""
from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import re
import platform
import random
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional

import numpy as np
import torch

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None

from . import __version__
from .cameras import rays_for_pixels
from .data import Dataset, DatasetError, Split, load_dataset
from .progress import EventLog
from .evaluate import _mean
from .progressbar import ProgressBar
from .render import CheckpointRefused, RunError, load_state_resizing, read_checkpoint
from . import backgrounds
from .backgrounds import BACKGROUNDS


class TrainError(Exception):
    """Training cannot start or cannot continue; the message says why and what to do."""


@dataclass
class TrainConfig:
    """Everything that decides a run (saved in RUN/config.json and in checkpoints)."""

    dataset: str
    out: str
    method: Optional[str] = None
    max_steps: Optional[int] = None
    max_seconds: Optional[float] = None
    seed: int = 0
    resume: bool = False
    overwrite: bool = False
    dataset_moved: bool = False  # --resume with a DATASET path other than the recorded one (hash checked when recorded)
    size: Optional[str] = None  # "auto": nerf_core.sizing picks the model size for the dataset
    options: Dict[str, object] = field(default_factory=dict)  # explicit method options (--set key=value)
    progress: Optional[str] = None  # extra JSON-lines file
    device: Optional[str] = None
    lr: Optional[float] = None  # base learning rate; default: the method's default_lr
    batch_rays: Optional[int] = None  # None: the method's default_batch_rays, else 4096 on CUDA / 1024 on CPU
    background: str = "auto"  # auto: nerf_core.backgrounds.choose (environment for opaque images, random for cut-outs)
    downscale: int = 1
    log_every: int = 50
    preview_every: Optional[int] = None  # steps; None: every preview_seconds of training time
    preview_seconds: float = 30.0
    preview_size: int = 256  # longest side of preview images
    checkpoint_every: Optional[int] = None  # steps; None: every checkpoint_seconds of wall time
    checkpoint_seconds: float = 300.0
    keep_checkpoints: int = 3  # step_XXXXXXX.pt files kept besides latest.pt
    max_rollbacks: int = 8
    eval_views: Optional[int] = None  # None: as many as fit in eval_seconds; 0: skip evaluation
    eval_seconds: Optional[float] = None  # None: max(30 s, 25 % of the training time)
    eval_at: List[float] = field(default_factory=list)  # training seconds at which to evaluate held-out views
    chunk: int = 8192
    stdout_events: bool = True
    show_bar: bool = True

    def budget_fraction(self, step: int, elapsed: float) -> float:
        fracs = []
        if self.max_steps:
            fracs.append(step / self.max_steps)
        if self.max_seconds:
            fracs.append(elapsed / self.max_seconds)
        return min(1.0, max(fracs)) if fracs else 0.0

    def finished(self, step: int, elapsed: float) -> bool:
        return (self.max_steps is not None and step >= self.max_steps) or (
            self.max_seconds is not None and elapsed >= self.max_seconds
        )


DEFAULT_MAX_STEPS = 5000  # used only when neither budget is given
STEP_EVENT_SECONDS = 5.0  # slow steps still produce a step event this often
AUTO_WHITE_FRACTION = 0.2  # --background white-then-random: white for this share of the budget
PREFIT_RAYS = 400_000  # train rays tested against the box before an environment run (those that miss fit the world)
PREFIT_STEPS = 200  # Adam steps of that fit (8192 texture lookups each: ~15 ms on an idle 2-core CPU)


# ----------------------------------------------------------------------------------------------
# run folder

TRAINER_FILES = ("config.json", "progress.jsonl", "metrics.json")
WRITTEN_LIST = ".written.json"  # RUN/.written.json: every file (relative path) this run's trainers wrote
# What a trainer writes, by exact name: the only files --overwrite removes in a run that has no WRITTEN_LIST.
_LEGACY_WRITTEN = re.compile(r"(config\.json|progress\.jsonl|metrics\.json|checkpoints/latest\.pt"
                             r"|checkpoints/step_\d{7}\.pt|previews/step_\d{7}\.png)")
# Files a trainer writes before its first checkpoint: a folder holding only these can be started again.
_PRE_CHECKPOINT = re.compile(r"(config\.json|progress\.jsonl|previews/step_\d{7}\.png|\.written\.json"
                             r"|checkpoints/(latest|step_\d{7})\.pt\.tmp)")


def _read_written(run: Path) -> Optional[List[str]]:
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
    names = _read_written(run) or []
    added = False
    for p in paths:
        rel = Path(p).resolve().relative_to(run.resolve()).as_posix()
        if rel not in names:
            names.append(rel)
            added = True
    if added or not (run / WRITTEN_LIST).is_file():
        _atomic_json(run / WRITTEN_LIST, names)


def _inside(run: Path, rel: str) -> Optional[Path]:
    """``run/rel`` when ``rel`` is a plain relative path that stays inside ``run`` (no .., not absolute)."""
    parts = Path(rel).parts
    if not parts or Path(rel).is_absolute() or ".." in parts or rel == RUN_LOCK:
        return None
    return run / rel


def _trainer_written(run: Path) -> List[Path]:
    """Files in ``run`` that a previous training wrote (the only ones --overwrite may delete).

    Those listed in RUN/.written.json (and their leftover ``.tmp``), else, for runs from before that
    list, only the exact names a trainer writes. Never RUN/.lock, never a file a user put there.
    """
    listed = _read_written(run)
    found: List[Path] = []
    if listed is not None:
        for rel in listed:
            p = _inside(run, rel)
            if p is None:
                continue
            for cand in (p, p.with_name(p.name + ".tmp")):
                if cand.is_file() and not cand.is_symlink() and cand not in found:
                    found.append(cand)
        if (run / WRITTEN_LIST).is_file():
            found.append(run / WRITTEN_LIST)
        return found
    for p in sorted(run.rglob("*")) if run.is_dir() else []:
        rel = p.relative_to(run).as_posix()
        if p.is_file() and not p.is_symlink() and _LEGACY_WRITTEN.fullmatch(rel):
            found.append(p)
    return found


def _run_contents(run: Path) -> List[str]:
    """Relative paths of the files in ``run`` (the lock excluded)."""
    if not run.is_dir():
        return []
    return sorted(p.relative_to(run).as_posix() for p in run.rglob("*") if p.is_file() and p.name != RUN_LOCK)


def resume_candidates(run: Path) -> List[Path]:
    """Checkpoints to resume from, best first: latest.pt, then step_*.pt from the newest."""
    ck = run / "checkpoints"
    out = [ck / "latest.pt"] if (ck / "latest.pt").is_file() else []
    if ck.is_dir():
        out += sorted((p for p in ck.glob("step_*.pt") if p.is_file()), reverse=True)
    return out


def check_run_folder(run: Path, resume: bool, overwrite: bool) -> None:
    """Refuse to touch an existing run unless asked (raises TrainError); changes nothing."""
    if resume and overwrite:
        raise TrainError("--resume and --overwrite contradict each other; pick one")
    if run.exists() and not run.is_dir():
        raise TrainError(f"{run}: exists and is not a folder")
    if resume:
        if not resume_candidates(run):
            latest = run / "checkpoints" / "latest.pt"
            files = _run_contents(run)
            if not files:
                raise TrainError(f"{latest}: not found; nothing to resume (drop --resume to start a new run)")
            if all(_PRE_CHECKPOINT.fullmatch(f) for f in files):
                raise TrainError(
                    f"{latest}: not found; nothing to resume: the trainer stopped before its first checkpoint. "
                    f"Start the run again with --overwrite instead of --resume (it removes only what that trainer "
                    f"wrote: {', '.join(files[:6])}{', ...' if len(files) > 6 else ''})"
                )
            raise TrainError(
                f"{latest}: not found and no checkpoints/step_*.pt either; nothing to resume. {run} holds other files "
                f"({', '.join(files[:6])}{', ...' if len(files) > 6 else ''}): choose another --out, or --overwrite "
                "(removes only files a trainer wrote there)"
            )
        return
    # The writer lock (RUN_LOCK) is not content: a trainer starting a new run creates it before it
    # re-checks the folder, and a trainer killed with SIGKILL may leave it behind, unlocked.
    names = sorted(p.name for p in run.iterdir() if p.name != RUN_LOCK) if run.is_dir() else []
    if names and not overwrite:
        shown = ", ".join(names[:6]) + (", ..." if len(names) > 6 else "")
        raise TrainError(
            f"{run}: run folder exists and is not empty ({shown}); pass --resume to continue it, "
            "--overwrite to start again (removes only files the trainer wrote), or choose another --out"
        )


def dataset_hash(path) -> str:
    """sha256 over the transforms files of a dataset (names and contents): what ``--resume`` compares
    to tell the dataset a run was trained on from another one at the same or a different path."""
    from .data import detect_layout

    layout, root = detect_layout(Path(path))
    if layout == "synthetic":
        files = [root / f"transforms_{s}.json" for s in ("train", "val", "test")]
    else:
        files = [Path(path) if Path(path).is_file() else root / "transforms.json"]
    h = hashlib.sha256()
    for f in files:
        if f.is_file():
            h.update(f.name.encode() + b"\0")
            try:
                h.update(f.read_bytes())
            except OSError as exc:
                raise DatasetError(f"{f}: cannot read ({exc.strerror})") from None
            h.update(b"\0")
    return h.hexdigest()


def check_run_vs_dataset(run: Path, dataset) -> None:
    """Refuse a run folder that is the dataset folder, lies inside it, or contains it (TrainError)."""
    ds = Path(dataset).resolve()
    if ds.is_file():
        ds = ds.parent
    run = Path(run).resolve()
    if run == ds:
        raise TrainError(f"--out {run}: is the dataset folder itself; the run's files would mix with the dataset's. "
                         "Choose a run folder outside the dataset")
    if ds in run.parents:
        raise TrainError(f"--out {run}: lies inside the dataset folder {ds} (tools that scan the dataset would find "
                         "the run's files); choose a run folder outside the dataset")
    if run in ds.parents:
        raise TrainError(f"--out {run}: contains the dataset {ds}; --overwrite and the run's files would live beside "
                         "your data. Choose a run folder that does not hold the dataset")


RUN_LOCK = ".lock"  # RUN/.lock: held (flock) by the one trainer writing RUN; holds its PID


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
    """
    if fcntl is None:
        # Windows has no flock. msvcrt.locking (mandatory byte-range locks) could stand in, but it
        # behaves differently enough (reads of the locked range fail, unlinking an open file fails)
        # to need its own tests on Windows; until then nothing is locked there.
        return lambda: None
    path = run / RUN_LOCK
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:  # a folder we may not write to: training could not write there either
            raise TrainError(f"{path}: cannot create the run folder's lock file ({exc.strerror})") from None
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
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode("ascii"))

    def release() -> None:
        try:
            os.unlink(path)
        except OSError:
            pass
        os.close(fd)

    return release


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
    for p in _trainer_written(run):
        p.unlink()
        removed.append(str(p.relative_to(run)))
    for sub in ("checkpoints", "previews"):
        d = run / sub
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()
    return removed


def _atomic_json(path: Path, data: dict) -> None:
    tmp = path.with_name("." + path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=str), encoding="utf-8")
    os.replace(tmp, path)


def _atomic_torch_save(obj, path: Path) -> None:
    """Write ``path`` through ``path.tmp`` and a rename. On failure (a full disk) the temporary file is
    removed, ``path`` keeps its previous content, and TrainError names the file and the cause."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    except (OSError, RuntimeError) as exc:  # torch.save reports a failed write as RuntimeError too
        try:
            tmp.unlink()
        except OSError:
            pass
        raise TrainError(f"{path}: cannot write checkpoint: {_os_reason(exc)}") from None


def _os_reason(exc: BaseException) -> str:
    """'no space left on device' and the like, from an OSError (or torch's RuntimeError around one)."""
    err = getattr(exc, "errno", None)
    if err is None:
        cause = exc.__cause__ or exc.__context__
        err = getattr(cause, "errno", None)
        if err is None and "No space left on device" in str(exc):
            err = errno.ENOSPC
    if err == errno.ENOSPC:
        return "no space left on device"
    if err is not None:
        return os.strerror(err).lower()
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


# ----------------------------------------------------------------------------------------------
# helpers


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % (2 ** 32))
    torch.manual_seed(seed)


def rng_state(gen: torch.Generator) -> dict:
    """Every RNG's state as tensors and plain Python data, so that a checkpoint holding it loads with
    ``torch.load(weights_only=True)`` (a numpy array would need numpy's unpickling globals)."""
    kind, key, pos, has_gauss, gauss = np.random.get_state()
    state = {"python": random.getstate(),  # (version, tuple of ints, float or None): plain data already
             "numpy": {"bit_generator": str(kind), "key": torch.from_numpy(key.astype(np.int64)), "pos": int(pos),
                       "has_gauss": int(has_gauss), "cached_gaussian": float(gauss)},
             "torch": torch.get_rng_state(), "batches": gen.get_state()}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict, gen: torch.Generator) -> None:
    random.setstate(state["python"])
    nps = state["numpy"]
    if isinstance(nps, dict):
        key = np.asarray(torch.as_tensor(nps["key"]).numpy(), dtype=np.uint32)
        np.random.set_state((nps["bit_generator"], key, nps["pos"], nps["has_gauss"], nps["cached_gaussian"]))
    else:  # checkpoints from before the weights-only format stored np.random.get_state() as it is
        np.random.set_state(nps)
    torch.set_rng_state(state["torch"])
    gen.set_state(state["batches"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def default_method() -> str:
    from .methods import available_methods
    from .methods import catalog

    names = available_methods()
    name = getattr(catalog, "DEFAULT_METHOD", None)
    if name in names:
        return name
    if not names:
        raise TrainError("no NeRF methods are registered (nerf_core/methods/catalog.py registers none)")
    return names[0]


def make_optimizer(model, lr: float) -> torch.optim.Optimizer:
    groups = model.optimizer_groups(lr)
    for g in groups:
        g["base_lr"] = g["lr"]  # the schedule scales each group's own base rate
    return torch.optim.Adam(groups, betas=(0.9, 0.99), eps=1e-15 if getattr(model, "adam_eps", None) is None else model.adam_eps,
                            **fused_adam_kwargs(groups))


def fused_adam_kwargs(groups) -> dict:
    """``fused=True`` where every parameter allows it (float tensors on the CPU or CUDA): one kernel per
    step instead of a chain of elementwise ops per tensor, measured 17x faster on a 1.5 M-parameter
    texture on a 2-core CPU (3.5 ms against 59 ms a step)."""
    params = [p for g in groups for p in g["params"]]
    ok = params and all(p.dtype in (torch.float32, torch.float64, torch.float16, torch.bfloat16)
                        and p.device.type in ("cpu", "cuda") for p in params)
    return {"fused": True} if ok else {}


def rebuild_optimizer(model, old: torch.optim.Optimizer, lr: float) -> torch.optim.Optimizer:
    """A new optimiser for the model's current parameters; Adam moments are carried over for
    parameters that are unchanged (same object and shape), grown tensors start fresh."""
    new = make_optimizer(model, lr)
    for g in new.param_groups:
        for p in g["params"]:
            st = old.state.get(p)
            if st and all((not torch.is_tensor(v)) or v.dim() == 0 or v.shape == p.shape for v in st.values()):
                new.state[p] = st
    return new


WARMUP_MAX_FRACTION = 0.02  # warm-up never takes more than this share of the budget


def schedule_factor(step: int, frac: float, warmup_steps: int, final_ratio: float = 0.1) -> float:
    """Learning-rate multiplier: linear warm-up over ``warmup_steps`` (cut short once 2 % of the budget
    is spent, so that slow steps under a time budget do not spend the run warming up), then
    exponential decay to ``final_ratio`` at the end of the budget (``frac`` in [0, 1])."""
    warm = 1.0
    if warmup_steps > 0:
        warm = min(1.0, max((step + 1) / warmup_steps, frac / WARMUP_MAX_FRACTION))
    return warm * final_ratio ** frac


def _fmt_option(value: str):
    for cast in (int, float):
        try:
            return cast(value)
        except ValueError:
            pass
    if value.lower() in ("true", "false"):
        return value.lower() == "true"
    try:
        return json.loads(value)
    except ValueError:
        return value


def parse_options(items: List[str]) -> Dict[str, object]:
    """``["n_samples=64", "resolution=[64,128]"]`` -> dict (numbers, booleans and JSON are parsed)."""
    out = {}
    for it in items or []:
        if "=" not in it:
            raise TrainError(f"--set {it!r}: expected KEY=VALUE")
        k, v = it.split("=", 1)
        out[k.strip()] = _fmt_option(v.strip())
    return out


class _Batcher:
    """Random ray batches over every pixel of the train split (images stay uint8 on the CPU)."""

    def __init__(self, split: Split, background: str, gen: torch.Generator, device: torch.device):
        self.split, self.gen, self.device = split, gen, device
        self.background = background
        self.hw = split.height * split.width
        self.total = len(split) * self.hw
        # Ground truth is composited onto white in environment mode too (the loaders' convention for the
        # few transparent pixels an opaque capture may have); the model's environment replaces ``bg``.
        self.fixed_bg = torch.tensor([0.0, 0.0, 0.0] if background == "black" else [1.0, 1.0, 1.0])

    def sample(self, n: int, frac: float = 1.0):
        flat = torch.randint(0, self.total, (n,), generator=self.gen)
        view = flat // self.hw
        pix = flat % self.hw
        j, i = pix // self.split.width, pix % self.split.width
        random_bg = self.background == "random" or (self.background == "white-then-random" and frac >= AUTO_WHITE_FRACTION)
        if random_bg:
            bg = torch.rand(n, 3, generator=self.gen)
        else:
            bg = self.fixed_bg.expand(n, 3)
        rgb, _ = self.split.pixels(view, j, i, bg)
        rays_o, rays_d, _ = rays_for_pixels(self.split.cameras, view, i, j)
        weight = self.split.masks[view, j, i].float() if self.split.masks is not None else None
        d = self.device
        return (rays_o.to(d), rays_d.to(d), bg.to(d).contiguous(), rgb.to(d),
                None if weight is None else weight.to(d))


# ----------------------------------------------------------------------------------------------


class Trainer:
    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.run = Path(cfg.out).resolve()

    # The public entry point: never raises for expected problems without first emitting an error event.
    def fit(self) -> dict:
        self._unlock: Optional[Callable[[], None]] = None
        try:
            return self._fit_run_folder()
        finally:
            if self._unlock is not None:
                self._unlock()

    def _fit_run_folder(self) -> dict:
        cfg = self.cfg
        extra_logs = [cfg.progress] if cfg.progress else []
        early_log = EventLog(extra_logs, stdout=cfg.stdout_events)
        self.log = early_log
        try:
            # Before the lock file is made: a run folder that is (or holds, or sits in) the dataset would
            # mix the trainer's files with the user's data, and --overwrite would delete from the dataset.
            check_run_vs_dataset(self.run, cfg.dataset)
            if self.run.is_dir():
                # Before anything else, so that a second trainer into a busy run learns who holds it
                # (rather than that the folder is not empty) and never reads a half-written checkpoint.
                self._unlock = lock_run_folder(self.run)
            check_run_folder(self.run, cfg.resume, cfg.overwrite)
            if cfg.background not in BACKGROUNDS:
                raise TrainError(f"--background {cfg.background!r}: choose one of {', '.join(BACKGROUNDS)}")
            for name in ("max_steps", "max_seconds"):
                v = getattr(cfg, name)
                if v is not None and v <= 0:
                    raise TrainError(f"--{name.replace('_', '-')} must be positive, got {v}")
            if cfg.batch_rays is not None and cfg.batch_rays < 1:
                raise TrainError(f"--batch-rays must be positive, got {cfg.batch_rays}")
            from .device import pick_device

            self.device = pick_device(cfg.device)
            ckpt = None
            if cfg.resume:
                ckpt = self._read_resume_checkpoint()
                self._merge_resumed_config(ckpt)
                check_run_vs_dataset(self.run, self.cfg.dataset)
            self.dataset_hash = dataset_hash(self.cfg.dataset)
            dataset = load_dataset(self.cfg.dataset, downscale=self.cfg.downscale)
            if self._unlock is None:
                # A new folder is made only now, so that a run that never starts leaves nothing behind.
                self.run.mkdir(parents=True, exist_ok=True)
                self._unlock = lock_run_folder(self.run)
                # Another trainer may have made and filled the folder since the first check.
                check_run_folder(self.run, cfg.resume, cfg.overwrite)
        except (TrainError, DatasetError, RunError, ValueError) as exc:
            early_log.emit("error", message=str(exc))
            early_log.close()
            raise
        try:
            removed = clear_run_folder(self.run) if cfg.overwrite else []
            self.log = EventLog([self.run / "progress.jsonl"] + extra_logs, stdout=cfg.stdout_events)
            record_written(self.run, self.run / "progress.jsonl")
        except OSError as exc:
            msg = f"{exc.filename or self.run}: {_os_reason(exc)}"
            early_log.emit("error", message=msg)
            early_log.close()
            raise TrainError(msg) from None
        early_log.close()
        if removed:
            print(f"train: --overwrite removed {len(removed)} file(s) written by an earlier run: "
                  + ", ".join(removed[:8]) + (" ..." if len(removed) > 8 else ""), file=sys.stderr)
        restore = _terminate_as_interrupt()
        try:
            return self._fit(dataset, ckpt)
        except KeyboardInterrupt:
            try:
                path = self._save_checkpoint(final=True) if hasattr(self, "opt") else None
            except TrainError as exc:
                self.log.emit("error", message=f"interrupted at step {getattr(self, 'step', 0)}; {exc}")
                raise
            self.log.emit("error", message=f"interrupted at step {getattr(self, 'step', 0)}"
                          + (f"; checkpoint saved, continue with --resume" if path else ""))
            raise
        except (TrainError, DatasetError, RunError, ValueError) as exc:
            self.log.emit("error", message=str(exc))
            raise
        except OSError as exc:  # a full disk while writing config, previews or metrics: name the file
            msg = f"{exc.filename or self.run}: {_os_reason(exc)} (at step {getattr(self, 'step', 0)})"
            self.log.emit("error", message=msg)
            raise TrainError(msg) from None
        except RuntimeError as exc:  # e.g. out of memory inside a model: one clear line, no traceback
            msg = str(exc).splitlines()[0]
            self.log.emit("error", message=f"training failed at step {getattr(self, 'step', 0)}: {msg}")
            raise TrainError(f"training failed at step {getattr(self, 'step', 0)}: {msg}") from exc
        finally:
            restore()
            self.log.close()

    def _read_resume_checkpoint(self) -> dict:
        """latest.pt, else the newest step_*.pt that loads (a full disk may have cost latest.pt)."""
        failures = []
        for path in resume_candidates(self.run):
            try:
                ckpt = read_checkpoint(path)
            except CheckpointRefused:
                raise  # a crafted checkpoint is an alarm, not damage to route around
            except RunError as exc:
                failures.append(str(exc))
                continue
            if failures or path.name != "latest.pt":
                print(f"train: resuming from {path}" + (f" ({failures[0]})" if failures else
                      " (checkpoints/latest.pt is missing)"), file=sys.stderr)
            self.resumed_checkpoint = path
            return ckpt
        raise RunError(failures[0] if len(failures) == 1 else
                       f"{self.run / 'checkpoints'}: no checkpoint loads: " + "; ".join(failures))

    def _merge_resumed_config(self, ckpt: dict) -> None:
        saved = dict(ckpt.get("config") or {})
        cli = self.cfg
        if cli.method and saved.get("method") and cli.method != saved["method"]:
            raise TrainError(f"--resume: the run was trained with method {saved['method']!r}, not {cli.method!r}")
        dataset = self._resume_dataset(saved)
        # What the user may change when resuming: budgets, device, output plumbing.
        keep = {"max_steps", "max_seconds", "device", "progress", "stdout_events", "show_bar", "resume", "out",
                "eval_views", "eval_seconds", "log_every", "checkpoint_every", "checkpoint_seconds"}
        merged = asdict(cli)
        for k, v in saved.items():
            if k in merged and k not in keep:
                merged[k] = v
        if cli.max_steps is None and cli.max_seconds is None:
            merged["max_steps"], merged["max_seconds"] = saved.get("max_steps"), saved.get("max_seconds")
        merged["resume"], merged["overwrite"] = True, False
        merged["dataset"], merged["dataset_moved"] = dataset, cli.dataset_moved
        self.cfg = TrainConfig(**merged)

    def _resume_dataset(self, saved: dict) -> str:
        """The dataset to resume on: the recorded one, or DATASET when it holds the same dataset.

        A run continued on other data would silently mix two scenes, so a DATASET other than the one the
        run was trained on is refused unless the content hash of its transforms files (recorded in
        config.json when the run started) matches: then the dataset was moved or copied, and the new
        path is used. Runs from before the hash was recorded need --dataset-moved to accept another path.
        """
        cli = self.cfg
        recorded = saved.get("dataset")
        if not recorded:
            return cli.dataset
        new = str(Path(cli.dataset).resolve())
        want = saved.get("dataset_hash")
        if new == str(Path(recorded).resolve()):
            if want and Path(new).exists():
                have = dataset_hash(new)
                if have != want:
                    raise TrainError(
                        f"{new}: the dataset changed since the run started (transforms hash {have[:12]} "
                        f"instead of {want[:12]}); resuming would train on other data. Start a new run "
                        "(another --out, or --overwrite)")
            return new
        if want:
            try:
                have = dataset_hash(new)
            except DatasetError as exc:
                raise TrainError(f"--resume: the run was trained on {recorded}, and {exc}") from None
            if have == want:
                print(f"train: {new} holds the dataset the run was trained on (moved from {recorded}); using it",
                      file=sys.stderr)
                return new
            raise TrainError(
                f"--resume: the run was trained on {recorded} (transforms hash {want[:12]}), but {new} holds "
                f"another dataset (hash {have[:12]}); resume with the original DATASET, or start a new run")
        if cli.dataset_moved:
            print(f"train: --dataset-moved: resuming on {new} instead of {recorded} (this run recorded no dataset "
                  "hash to check it against)", file=sys.stderr)
            return new
        raise TrainError(
            f"--resume: the run was trained on {recorded}, not {new}, and recorded no dataset hash to check that "
            f"they hold the same data; resume with the original DATASET, or pass --dataset-moved if you moved it")

    # ------------------------------------------------------------------ setup

    def _build(self, dataset: Dataset, ckpt: Optional[dict]):
        from .methods import build_model

        cfg = self.cfg
        train = dataset.split("train")
        self.method = cfg.method or default_method()
        self.size_reasons: List[str] = []
        if ckpt is not None:
            options = dict(ckpt["options"])
            self.size_reasons = list(ckpt.get("size_reasons", []))
            aabb = torch.as_tensor(ckpt["aabb"])
        else:
            options = {}
            if cfg.size == "auto":
                options, self.size_reasons = self._auto_size(dataset)
            elif cfg.size not in (None, "", "default"):
                raise TrainError(f"--size {cfg.size!r}: only 'auto' is supported")
            options.update(cfg.options)
            aabb = dataset.aabb
        if ckpt is None and self.bg_mode == "environment" and "environment" not in options:
            from .environment import size_for_focal

            options["environment"] = {"width": size_for_focal(float(train.cameras.fx.median()))}
        seed_everything(cfg.seed)
        try:
            model = build_model(self.method, aabb, **options)
        except TypeError as exc:
            raise TrainError(f"method {self.method!r} does not accept these options {sorted(options)}: {exc}") from exc
        except ValueError as exc:  # unknown method or option values the method rejects
            raise TrainError(str(exc)) from exc
        if ckpt is not None:
            load_state_resizing(model, ckpt["model"])
        self.model = model.to(self.device).train()
        self.base_lr = float(cfg.lr or getattr(model, "default_lr", 5e-4))
        if cfg.batch_rays is None:
            cfg.batch_rays = int(getattr(model, "default_batch_rays", 0) or (4096 if self.device.type == "cuda" else 1024))
        self.warmup = int(getattr(model, "warmup_steps", 0) or min(100, (cfg.max_steps or 2000) // 20))
        self.train = train

    def _auto_size(self, dataset: Dataset):
        from .sizing import auto_size, nearest_box_distance

        tr = dataset.split("train")
        near = nearest_box_distance(tr.cameras.origins, dataset.aabb)
        # The probes look at a few images only: hand them 8 evenly spaced views as float (composited
        # onto the evaluation background, with their alpha) instead of a float copy of the whole split.
        pick = torch.linspace(0, len(tr) - 1, min(len(tr), 8)).round().long().tolist()
        bg = [0.0, 0.0, 0.0] if self.cfg.background == "black" else [1.0, 1.0, 1.0]
        views = [tr.image(v, bg) for v in pick]
        probe = torch.stack([rgb for rgb, _ in views])
        alphas = torch.stack([a for _, a in views]) if tr.has_alpha else None
        options, reasons = auto_size(self.method, dataset.aabb, float(tr.cameras.fx[0]), tr.width, tr.height, near,
                                     probe, alphas=alphas)
        return dict(options), list(reasons)

    # ------------------------------------------------------------------ checkpoints

    def _checkpoint_state(self) -> dict:
        return {
            "format": 1,
            "method": self.method,
            "options": self.model.options,
            "aabb": self.model.aabb.detach().cpu(),
            "model": {k: v.detach().cpu() for k, v in self.model.state_dict().items()},
            "optimizer": self.opt.state_dict(),
            "step": self.step,
            "elapsed": self.elapsed,
            "lr_scale": self.lr_scale,
            "rollbacks": self.rollbacks,
            "loss_ema": self.loss_ema,
            "rng": rng_state(self.gen),
            "config": self.config_record(),
            "size_reasons": self.size_reasons,
            "versions": _versions(),
        }

    def _save_checkpoint(self, final: bool = False) -> Path:
        ck = self.run / "checkpoints"
        ck.mkdir(parents=True, exist_ok=True)
        state = self._checkpoint_state()
        step_path = ck / f"step_{self.step:07d}.pt"
        latest = ck / "latest.pt"
        try:
            record_written(self.run, step_path, latest)
        except OSError as exc:
            raise TrainError(f"{self.run / WRITTEN_LIST}: cannot write: {_os_reason(exc)}") from None
        # step_* first: when latest.pt cannot be written, a complete step_*.pt still is (--resume uses it).
        _atomic_torch_save(state, step_path)
        _atomic_torch_save(state, latest)
        olds = sorted(ck.glob("step_*.pt"))
        for p in olds[: max(0, len(olds) - self.cfg.keep_checkpoints)]:
            p.unlink()
        self.log.emit("checkpoint", step=self.step, path=str(latest))
        self._last_ckpt_wall = time.monotonic()
        self._last_ckpt_step = self.step
        return latest

    def _snapshot(self) -> None:
        self.snap = {
            "model": {k: v.detach().clone() for k, v in self.model.state_dict().items()},
            "opt": _clone_state(self.opt.state_dict()),
            "step": self.step,
            "elapsed_at": self.elapsed,
            "loss_ema": self.loss_ema,
        }

    def _rollback(self, reason: str) -> None:
        self.rollbacks += 1
        self.lr_scale *= 0.5
        if self.rollbacks > self.cfg.max_rollbacks:
            raise TrainError(
                f"training diverged: {self.rollbacks - 1} rollbacks did not help (last: {reason} at step {self.step}); "
                f"try a lower --lr than {self.base_lr * self.lr_scale * 2:.3g} or another --method"
            )
        snap = self.snap
        load_state_resizing(self.model, snap["model"])
        self.opt = make_optimizer(self.model, self.base_lr * self.lr_scale)
        try:
            self.opt.load_state_dict(_clone_state(snap["opt"]))
        except (ValueError, KeyError):
            pass  # parameter set changed since the snapshot: fresh Adam moments
        self._rescale_base_lrs()  # load_state_dict restored the pre-rollback rates
        at = self.step
        self.step = snap["step"]
        self.loss_ema = snap["loss_ema"]
        self.steps_since_rollback = 0
        self.log.emit("rollback", step=at, reason=f"{reason}; restored step {self.step}",
                      lr=self.base_lr * self.lr_scale, restored_step=self.step, rollbacks=self.rollbacks)

    def _rescale_base_lrs(self) -> None:
        groups = self.model.optimizer_groups(self.base_lr * self.lr_scale)
        for g, fresh in zip(self.opt.param_groups, groups):
            g["base_lr"] = fresh["lr"]

    # ------------------------------------------------------------------ records

    def config_record(self) -> dict:
        rec = asdict(self.cfg)
        rec.update({
            "dataset": str(Path(self.cfg.dataset).resolve()),
            "dataset_hash": getattr(self, "dataset_hash", None),
            "out": str(self.run),
            "method": self.method,
            "model": self.model.describe(),
            "lr": self.base_lr,
            "warmup_steps": self.warmup,
            "background_used": self.bg_mode,
            "background_reason": self.bg_reason,
            "eval_background": self.eval_bg,
            "aabb": self.model.aabb.detach().cpu().tolist(),
            "aabb_source": self.dataset.aabb_source,
            "near": self.dataset.near,
            "far": self.dataset.far,
            "size_reasons": self.size_reasons,
            "dataset_notes": self.dataset.notes,
            "n_train_views": len(self.train),
            "image_size": [self.train.width, self.train.height],
            "device_used": str(self.device),
            "versions": _versions(),
        })
        return rec

    # ------------------------------------------------------------------ loop

    def _fit(self, dataset: Dataset, ckpt: Optional[dict]) -> dict:
        cfg = self.cfg
        self.dataset = dataset
        train = dataset.split("train")
        recorded = (ckpt.get("config") or {}).get("background_used") if ckpt is not None else None
        if cfg.background == "auto" and recorded in BACKGROUNDS:
            # A resumed run keeps the background it started with (also runs from before the environment).
            self.bg_mode, self.bg_reason = recorded, "as recorded when the run started"
        elif cfg.background == "auto":
            self.bg_mode, self.bg_reason = backgrounds.choose(train.images, dataset.film_transparent,
                                                              where=f"{dataset.root}",
                                                              cameras_inside=dataset.cameras_inside)
        else:
            self.bg_mode = cfg.background
            self.bg_reason = "as recorded when the run started" if recorded == cfg.background else "--background given"
        if self.bg_mode == "random" and not train.has_alpha:
            raise TrainError(
                f"{train.frames[0].image}: --background {self.bg_mode} needs images with an alpha channel (RGBA); "
                "this dataset's images are RGB (--background environment learns their background)"
            )
        if ckpt is not None and self.bg_mode == "environment" and "environment" not in ckpt["options"]:
            raise TrainError(f"--resume: the run was trained without a learned environment; "
                             f"it cannot continue with --background environment")
        self._build(dataset, ckpt)
        self.eval_bg = [0.0, 0.0, 0.0] if self.bg_mode == "black" else [1.0, 1.0, 1.0]
        if cfg.max_steps is None and cfg.max_seconds is None:
            cfg.max_steps = int(getattr(self.model, "default_max_steps", DEFAULT_MAX_STEPS))

        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.step, self.elapsed, self.lr_scale, self.rollbacks = 0, 0.0, 1.0, 0
        self.loss_ema: Optional[float] = None
        self.opt = make_optimizer(self.model, self.base_lr)
        resumed_from = None
        if ckpt is not None:
            self.step, self.elapsed = int(ckpt["step"]), float(ckpt["elapsed"])
            self.lr_scale, self.rollbacks = float(ckpt.get("lr_scale", 1.0)), int(ckpt.get("rollbacks", 0))
            self.loss_ema = ckpt.get("loss_ema")
            self.opt = make_optimizer(self.model, self.base_lr * self.lr_scale)
            try:
                self.opt.load_state_dict(ckpt["optimizer"])
            except (ValueError, KeyError) as exc:
                print(f"train: optimiser state in the checkpoint does not fit ({exc}); starting Adam afresh", file=sys.stderr)
            self._rescale_base_lrs()
            set_rng_state(ckpt["rng"], self.gen)
            resumed_from = self.step
        record_written(self.run, self.run / "config.json")
        _atomic_json(self.run / "config.json", self.config_record())
        n_params = self.model.num_parameters()
        self.log.emit("start", run=str(self.run), method=self.method, max_steps=cfg.max_steps, max_seconds=cfg.max_seconds,
                      device=str(self.device), n_params=n_params, model=self.model.describe(),
                      size_reasons=self.size_reasons, resumed_from=resumed_from, seed=cfg.seed,
                      dataset=str(Path(cfg.dataset).resolve()), n_train_views=len(train),
                      image_size=[train.width, train.height], background=self.bg_mode,
                      background_reason=self.bg_reason, notes=dataset.notes)
        if self.size_reasons:
            for r in self.size_reasons:
                print(f"train: size: {r}", file=sys.stderr)
        print(f"train: background: {self.bg_mode} ({self.bg_reason})", file=sys.stderr)
        for note in dataset.notes:
            print(f"train: note: {note}", file=sys.stderr)

        if ckpt is None and self.model.environment is not None and not getattr(self.model, "contracted", False):
            # (A contracted scene has no ray that misses it: the world beyond the box is geometry too.)
            self._prefit_environment()
        self.preview_view = self._preview_source()
        self._preview_cost = 0.0
        self._eval_marks = sorted(t for t in cfg.eval_at if t > self.elapsed)
        batcher = _Batcher(train, self.bg_mode, self.gen, self.device)
        self._snapshot()
        self.steps_since_rollback = 0
        self._last_ckpt_wall, self._last_ckpt_step = time.monotonic(), self.step
        last_preview_elapsed, last_preview_step = self.elapsed, self.step
        interval = {"t": 0.0, "samples": 0, "loss": 0.0, "n": 0}
        bar = self._make_bar()
        params_changed = False
        last_loss = last_psnr = None
        first_step = self.step + 1  # always report the first step (also after --resume)
        last_event_wall = time.monotonic()

        while not cfg.finished(self.step, self.elapsed):
            t0 = time.perf_counter()
            frac = cfg.budget_fraction(self.step, self.elapsed)
            if self.model.training_hook(self.step, cfg.max_steps, self.elapsed, cfg.max_seconds):
                self.opt = rebuild_optimizer(self.model, self.opt, self.base_lr * self.lr_scale)
                params_changed = True
            factor = schedule_factor(self.step, frac, self.warmup)
            for g in self.opt.param_groups:
                g["lr"] = g["base_lr"] * factor
            rays_o, rays_d, bg, gt, weight = batcher.sample(cfg.batch_rays, frac)
            if self.model.environment is not None:
                bg = self.model.background(rays_d, bg)
            near, far = self.model.ray_interval(rays_o, rays_d, dataset.near, dataset.far)
            out = self.model.render_rays(rays_o, rays_d, near, far, bg, training=True)
            mse = _masked_mse(out["rgb"], gt, weight)
            loss = mse
            if "rgb_coarse" in out:
                loss = loss + _masked_mse(out["rgb_coarse"], gt, weight)
            if out.get("aux_loss") is not None:
                loss = loss + out["aux_loss"]
            loss_value = float(loss.detach())
            bad = None
            if not math.isfinite(loss_value):
                bad = f"loss is {loss_value}"
            elif (self.loss_ema is not None and self.steps_since_rollback > 200
                  and loss_value > 10.0 * self.loss_ema and loss_value - self.loss_ema > 0.01):
                bad = f"loss {loss_value:.4g} jumped above 10x its running average {self.loss_ema:.4g}"
            if bad is None:
                self.opt.zero_grad(set_to_none=True)
                loss.backward()
                params = [p for g in self.opt.param_groups for p in g["params"] if p.grad is not None]
                gnorm = torch.nn.utils.clip_grad_norm_(params, float("inf")) if params else torch.tensor(0.0)
                if not torch.isfinite(gnorm):
                    bad = "gradient is NaN or inf"
            self.elapsed += time.perf_counter() - t0
            if bad is not None:
                self.opt.zero_grad(set_to_none=True)
                self._rollback(bad)
                continue
            t1 = time.perf_counter()
            self.opt.step()
            self.step += 1
            self.steps_since_rollback += 1
            self.loss_ema = loss_value if self.loss_ema is None else 0.98 * self.loss_ema + 0.02 * loss_value
            self.elapsed += time.perf_counter() - t1
            interval["t"] += time.perf_counter() - t0
            interval["samples"] += int(out.get("n_samples", cfg.batch_rays))
            interval["loss"] += loss_value
            interval["n"] += 1
            last_loss, last_psnr = loss_value, _psnr(float(mse.detach()))
            bar.set(self._bar_done(), info=f"step {self.step} loss {loss_value:.4f} psnr {last_psnr:.2f}")

            if params_changed or self.step % 100 == 0:
                self._snapshot()
                params_changed = False
            done = cfg.finished(self.step, self.elapsed)
            while self._eval_marks and self.elapsed >= self._eval_marks[0]:
                # Speed-against-accuracy curves: evaluate at fixed training times inside one run, so the
                # learning-rate and growth schedules are the real ones. Evaluation time is not training time.
                self._eval_marks.pop(0)
                self._held_out_eval(at_seconds=self.elapsed)
            # Slow steps (big models on a CPU) still report at least every few seconds.
            if (self.step == first_step or self.step % cfg.log_every == 0 or done
                    or time.monotonic() - last_event_wall >= STEP_EVENT_SECONDS):
                last_event_wall = time.monotonic()
                self._emit_step(last_loss, last_psnr, interval)
                interval = {"t": 0.0, "samples": 0, "loss": 0.0, "n": 0}
            if not done and self._preview_due(last_preview_step, last_preview_elapsed):
                self._preview()
                last_preview_step, last_preview_elapsed = self.step, self.elapsed
            if not done and self._checkpoint_due():
                self._save_checkpoint()
        bar.close(info=f"step {self.step} loss {last_loss if last_loss is not None else float('nan'):.4f}")
        self._preview()
        latest = self._save_checkpoint(final=True)
        metrics = self._final_eval()
        self.log.emit("done", step=self.step, elapsed=self.elapsed, checkpoint=str(latest), metrics=metrics)
        return {"step": self.step, "elapsed": self.elapsed, "checkpoint": str(latest), "metrics": metrics,
                "loss": last_loss, "rollbacks": self.rollbacks}

    def _prefit_environment(self) -> None:
        """Fit the learned world to the train pixels whose rays miss the scene box (see
        ``environment.prefit``); counted as training time."""
        from .environment import prefit

        started = time.perf_counter()
        train = self.train
        hw = train.height * train.width
        n = min(PREFIT_RAYS, len(train) * hw)
        flat = torch.randint(0, len(train) * hw, (n,), generator=self.gen)
        view, pix = flat // hw, flat % hw
        j, i = pix // train.width, pix % train.width
        rays_o, rays_d, _ = rays_for_pixels(train.cameras, view, i, j)
        near, far = self.model.ray_interval(rays_o.to(self.device), rays_d.to(self.device), self.dataset.near,
                                            self.dataset.far)
        miss = (far <= near).cpu()
        rgb, _ = train.pixels(view[miss], j[miss], i[miss], torch.ones(3))
        dirs_t, cols_t = rays_d[miss].to(self.device), rgb.to(self.device)
        mse = prefit(self.model.environment, dirs_t, cols_t, steps=PREFIT_STEPS if len(dirs_t) else 0,
                     generator=self.gen)
        took = time.perf_counter() - started
        self.elapsed += took
        share = len(dirs_t) / max(1, n)
        msg = (f"environment: {100 * share:.0f} % of the train rays miss the scene box; fitted the world to them "
               f"in {took:.1f} s" + (f" (psnr {_psnr(mse):.1f})" if mse == mse else ""))
        print(f"train: {msg}", file=sys.stderr)
        self.log.emit("note", message=msg, miss_share=share)

    # ------------------------------------------------------------------ reporting

    def _make_bar(self) -> ProgressBar:
        cfg = self.cfg
        if cfg.max_steps and not cfg.max_seconds:
            total, self._bar_unit = cfg.max_steps, "steps"
        elif cfg.max_seconds and not cfg.max_steps:
            total, self._bar_unit = round(cfg.max_seconds), "seconds"
        else:
            total, self._bar_unit = 100, "percent"
        bar = ProgressBar(total=total, label="train", enabled=cfg.show_bar)
        return bar

    def _bar_done(self) -> float:
        if self._bar_unit == "steps":
            return self.step
        if self._bar_unit == "seconds":
            return round(self.elapsed, 1)
        return round(100 * self.cfg.budget_fraction(self.step, self.elapsed), 1)

    def _eta(self) -> Optional[float]:
        cfg, etas = self.cfg, []
        if cfg.max_steps and self.step > 0:
            etas.append(self.elapsed / self.step * max(0, cfg.max_steps - self.step))
        if cfg.max_seconds:
            etas.append(max(0.0, cfg.max_seconds - self.elapsed))
        return min(etas) if etas else None

    def _emit_step(self, loss: float, psnr: float, interval: dict) -> None:
        lr = [g for g in self.opt.param_groups if g.get("name") != "environment"][-1]["lr"]
        sps = interval["samples"] / interval["t"] if interval["t"] > 0 else 0.0
        self.log.emit("step", step=self.step, loss=loss, psnr=psnr, lr=lr, elapsed=self.elapsed, eta=self._eta(),
                      samples_per_s=sps, loss_avg=interval["loss"] / max(1, interval["n"]),
                      lrs={g.get("name", str(k)): g["lr"] for k, g in enumerate(self.opt.param_groups)})

    def _preview_source(self):
        for name in ("val", "test", "train"):
            sp = self.dataset.splits.get(name)
            if sp is not None and len(sp):
                cams = sp.cameras[0]
                scale = min(1.0, self.cfg.preview_size / max(sp.width, sp.height))
                return cams.scaled(scale) if scale < 1.0 else cams
        return None

    def _preview_due(self, last_step: int, last_elapsed: float) -> bool:
        if self.cfg.preview_every:
            return self.step - last_step >= self.cfg.preview_every
        # A slow method (the classic MLP renders a 200x200 view in ~1 min on 2 cores) would otherwise spend
        # more time on previews than on training: keep previews under ~20% of the training time.
        return self.elapsed - last_elapsed >= max(self.cfg.preview_seconds, 4.0 * self._preview_cost)

    def _checkpoint_due(self) -> bool:
        if self.cfg.checkpoint_every:
            return self.step - self._last_ckpt_step >= self.cfg.checkpoint_every
        return time.monotonic() - self._last_ckpt_wall >= self.cfg.checkpoint_seconds

    def _preview(self) -> None:
        if self.preview_view is None:
            return
        from .imageio import write_png
        from .render import render_view

        started = time.monotonic()
        self.model.eval()
        try:
            res = render_view(self.model, self.preview_view.to("cpu"), 0, background=self.eval_bg,
                              near=self.dataset.near, far=self.dataset.far, chunk=self.cfg.chunk)
        finally:
            self.model.train()
        pv = self.run / "previews"
        pv.mkdir(exist_ok=True)
        path = pv / f"step_{self.step:07d}.png"
        record_written(self.run, path)
        write_png(path, res["rgb"].numpy())
        self._preview_cost = time.monotonic() - started
        self.log.emit("preview", step=self.step, path=str(path))

    def _held_out_eval(self, at_seconds: float) -> None:
        """Evaluate ``eval_views`` evenly spaced held-out views (all when unset) and emit an ``eval`` event."""
        from .evaluate import evaluate_split

        split_name = self.dataset.held_out_split(("test", "val"))
        if split_name is None:
            return
        split = self.dataset.splits[split_name]
        n = len(split)
        k = min(n, self.cfg.eval_views or n)
        views = sorted({round(x * (n - 1) / max(1, k - 1)) for x in range(k)}) if k > 1 else [0]
        self.model.eval()
        try:
            started = time.perf_counter()
            result = evaluate_split(self.model, split, views, background=self.eval_bg, near=self.dataset.near,
                                    far=self.dataset.far, chunk=self.cfg.chunk)
        finally:
            self.model.train()
        self.log.emit("eval", step=self.step, split=split_name, psnr=result["psnr"], ssim=result["ssim"],
                      n_views=result["n_views"], depth_mae=result.get("depth_mae"), elapsed=at_seconds,
                      eval_wall=time.perf_counter() - started, n_params=self.model.num_parameters(),
                      n_bytes=self.model.num_bytes())

    def _final_eval(self) -> dict:
        from .evaluate import evaluate_split, update_metrics_file

        cfg = self.cfg
        split_name = self.dataset.held_out_split(("test", "val"))
        if split_name is None or cfg.eval_views == 0:
            return {}
        split = self.dataset.splits[split_name]
        n = len(split)
        budget = cfg.eval_seconds if cfg.eval_seconds is not None else max(30.0, 0.25 * self.elapsed)
        self.model.eval()
        try:
            t0 = time.perf_counter()
            first = evaluate_split(self.model, split, [0], background=self.eval_bg, near=self.dataset.near,
                                   far=self.dataset.far, chunk=cfg.chunk)
            per_view_s = time.perf_counter() - t0
            if cfg.eval_views is not None:
                k = min(n, cfg.eval_views)
            else:
                k = int(min(n, max(1, budget // max(per_view_s, 1e-3))))
            views = sorted({round(x * (n - 1) / max(1, k - 1)) for x in range(k)}) if k > 1 else [0]
            rest = [v for v in views if v != 0]
            result = first
            if rest:
                more = evaluate_split(self.model, split, rest, background=self.eval_bg, near=self.dataset.near,
                                      far=self.dataset.far, chunk=cfg.chunk)
                per_view = first["per_view"] + more["per_view"]
                result = dict(first, per_view=per_view, n_views=len(per_view))
                for key in ("psnr", "ssim", "depth_mae"):
                    if key in first:
                        result[key] = _mean([e.get(key) for e in per_view])
        finally:
            self.model.train()
        if result["n_views"] < n:
            result["note"] = (f"evaluated {result['n_views']} of {n} {split_name} views at full resolution to stay within "
                              f"{budget:.0f} s; `python -m nerf_core eval {self.run}` evaluates all")
            print(f"train: {result['note']}", file=sys.stderr)
        record_written(self.run, self.run / "metrics.json")
        update_metrics_file(self.run / "metrics.json", split_name, result, self.step)
        self.log.emit("eval", step=self.step, split=split_name, psnr=result["psnr"], ssim=result["ssim"],
                      n_views=result["n_views"], depth_mae=result.get("depth_mae"))
        return {k: v for k, v in result.items() if k != "per_view"} | {"split": split_name}


def _terminate_as_interrupt():
    """Treat SIGTERM (what the add-on's Cancel and most job schedulers send) like Ctrl-C, so the run
    stops with a checkpoint it can resume from. Returns a function restoring the previous handler."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "SIGTERM"):
        return lambda: None

    def handler(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    return lambda: signal.signal(signal.SIGTERM, previous)


def _masked_mse(pred: torch.Tensor, gt: torch.Tensor, weight: Optional[torch.Tensor]) -> torch.Tensor:
    err = ((pred - gt) ** 2).mean(-1)
    if weight is None:
        return err.mean()
    return (err * weight).sum() / weight.sum().clamp_min(1.0)


def _psnr(mse: float) -> float:
    return -10.0 * math.log10(mse) if mse > 0 else float("inf")


def _clone_state(obj):
    if torch.is_tensor(obj):
        return obj.detach().clone()
    if isinstance(obj, dict):
        return {k: _clone_state(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_clone_state(v) for v in obj]
    return obj


def _versions() -> dict:
    # str(): torch.__version__ is a TorchVersion, a class the weights-only checkpoint loader refuses.
    return {"nerf_core": str(__version__), "torch": str(torch.__version__), "numpy": str(np.__version__),
            "python": platform.python_version()}


def train(cfg: TrainConfig) -> dict:
    """Train according to ``cfg``; returns a summary (step, elapsed, checkpoint, metrics)."""
    return Trainer(cfg).fit()

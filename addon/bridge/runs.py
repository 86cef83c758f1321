"""Training run folders (docs/CONTRACTS.md, "Run folder"): listing them with their method, settings and
metrics, and what a folder holds before training into it (``run_folder_state``, ``step_checkpoints``,
``suggest_run_name``).

Reads only ``RUN/config.json``, ``RUN/metrics.json`` and the checkpoint's presence, so listing never
needs torch. A damaged file is reported on its run (``problem``) instead of hiding the run.
"""
from __future__ import annotations

import glob
import json
import math
import os
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional

from .core_contract import contract


@dataclass
class RunInfo:
    path: str
    name: str
    method: str = "?"
    config: Dict[str, Any] = field(default_factory=dict)
    metrics: Dict[str, Any] = field(default_factory=dict)
    has_checkpoint: bool = False
    problem: str = ""
    mtime: float = 0.0

    @property
    def finished(self) -> bool:
        return bool(self.metrics)

    def settings_summary(self) -> str:
        """One line with the budget and seed, e.g. ``'max 60 s, 2000 steps, seed 0'``."""
        cfg = self.config
        parts = []
        budgets = cfg.get("budgets") if isinstance(cfg.get("budgets"), dict) else cfg
        def finite(v):  # json reads Infinity and NaN; int() of them raises
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

        if finite(budgets.get("max_seconds")):
            parts.append(f"max {budgets['max_seconds']:g} s")
        if finite(budgets.get("max_steps")):
            parts.append(f"{int(budgets['max_steps'])} steps")
        if isinstance(cfg.get("seed"), int):
            parts.append(f"seed {cfg['seed']}")
        if isinstance(cfg.get("background_used"), str):
            parts.append(f"background {cfg['background_used']}")
        return ", ".join(parts)

    def metrics_summary(self) -> str:
        """``'PSNR 27.31 dB, SSIM 0.912'`` or ``'unfinished'``."""
        m = self.metrics
        if not m:
            return "unfinished" if self.has_checkpoint else "no checkpoint"
        parts = []
        psnr = _find_metric(m, "psnr")
        ssim = _find_metric(m, "ssim")
        if psnr is not None:
            parts.append(f"PSNR {psnr:.2f} dB")
        if ssim is not None:
            parts.append(f"SSIM {ssim:.3f}")
        split = m.get("split")
        if parts and isinstance(split, str):
            parts[-1] += f" ({split})"
        return ", ".join(parts) or "finished"


def _find_metric(metrics: Dict[str, Any], name: str) -> Optional[float]:
    """``metrics[name]``, else the first ``<split>.<name>`` / ``<split>: {name}`` (test preferred)."""
    value = metrics.get(name)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    for split in ("test", "val", "train"):
        for key in (f"{split}_{name}", f"{name}_{split}"):
            if isinstance(metrics.get(key), (int, float)):
                return float(metrics[key])
        sub = metrics.get(split)
        if isinstance(sub, dict) and isinstance(sub.get(name), (int, float)):
            return float(sub[name])
    return None


def _read_json(path: str) -> Any:
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def read_run(path: str) -> Optional[RunInfo]:
    """A RunInfo for ``path`` when it looks like a run folder (has config.json or checkpoints/), else None."""
    config_path = contract.config_path(path)
    ckpt = contract.latest_checkpoint(path)
    if not (os.path.isfile(config_path) or os.path.isdir(contract.checkpoints_dir(path))):
        return None
    info = RunInfo(path=os.path.abspath(path), name=os.path.basename(os.path.normpath(path)),
                   has_checkpoint=os.path.isfile(ckpt))
    info.mtime = os.path.getmtime(path)
    problems = []
    for attr, file in (("config", config_path), ("metrics", contract.metrics_path(path))):
        if not os.path.isfile(file):
            if attr == "config":
                problems.append(f"{contract.CONFIG} missing")
            continue
        try:
            data = _read_json(file)
        except (OSError, ValueError) as exc:
            problems.append(f"{os.path.basename(file)} unreadable ({exc})")
            continue
        if isinstance(data, dict):
            setattr(info, attr, data)
        else:
            problems.append(f"{os.path.basename(file)} is not a JSON object")
    method = info.config.get("method")
    if isinstance(method, dict):  # tolerate {"method": {"name": ...}}
        method = method.get("name")
    info.method = method if isinstance(method, str) else "?"
    info.problem = "; ".join(problems)
    return info


def list_runs(root: str) -> List[RunInfo]:
    """Runs directly inside ``root`` (and ``root`` itself if it is one), newest first."""
    found: List[RunInfo] = []
    if not root or not os.path.isdir(root):
        return found
    own = read_run(root)
    if own is not None:
        found.append(own)
    for entry in sorted(os.listdir(root)):
        sub = os.path.join(root, entry)
        if os.path.isdir(sub):
            info = read_run(sub)
            if info is not None:
                found.append(info)
    found.sort(key=lambda r: r.mtime, reverse=True)
    return found


def run_dataset(run: str) -> Optional[str]:
    """The dataset folder recorded in ``RUN/config.json`` (key ``dataset`` or ``dataset_path``)."""
    try:
        cfg = _read_json(contract.config_path(run))
    except (OSError, ValueError, RecursionError):
        return None
    return config_dataset(cfg, run) if isinstance(cfg, dict) else None


def config_dataset(cfg: dict, run: str) -> Optional[str]:
    """The dataset folder a run's config dict records, relative paths taken from ``run``; else None."""
    for key in ("dataset", "dataset_path", "data"):
        value = cfg.get(key)
        if isinstance(value, dict):
            value = value.get("path")
        if isinstance(value, str) and value:
            return value if os.path.isabs(value) else os.path.normpath(os.path.join(run, value))
    return None


def run_background(run: str) -> tuple:
    """The background the run's renders are evaluated on (config ``eval_background``, else
    ``background``), white by default: ground truth is composited onto the same colour."""
    try:
        cfg = _read_json(contract.config_path(run))
        bg = (cfg.get("eval_background") or cfg.get("background")) if isinstance(cfg, dict) else None
    except (OSError, ValueError):
        bg = None
    if isinstance(bg, (list, tuple)) and len(bg) >= 3 and all(isinstance(v, (int, float)) for v in bg[:3]):
        return tuple(float(v) for v in bg[:3])
    named = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}
    return named.get(bg, (1.0, 1.0, 1.0)) if isinstance(bg, str) else (1.0, 1.0, 1.0)


# -- a run folder before training into it -------------------------------------------------------
def run_folder_state(run: str) -> str:
    """'new' (absent), 'empty', 'file' (not a folder), 'resumable' (a checkpoint the trainer resumes
    from: ``checkpoints/latest.pt``, else a ``checkpoints/step_*.pt``, as ``--resume`` falls back to
    them) or 'occupied' (other files)."""
    if not os.path.exists(run):
        return "new"
    if not os.path.isdir(run):
        return "file"
    if not os.listdir(run):
        return "empty"
    if os.path.isfile(contract.latest_checkpoint(run)) or step_checkpoints(run):
        return "resumable"
    return "occupied"


def step_checkpoints(run: str) -> List[str]:
    """``RUN/checkpoints/step_*.pt`` files, newest first: what ``train --resume`` falls back to when
    latest.pt is gone (nerf_core.runs.folder.resume_candidates, the same glob and order)."""
    found = glob.glob(os.path.join(glob.escape(run), contract.CHECKPOINTS_DIR, contract.step_glob(".pt")))
    return sorted((p for p in found if os.path.isfile(p)), reverse=True)


def suggest_run_name(run: str) -> str:
    """``run`` itself when free, else the first of ``run_2``, ``run_3``... that does not exist."""
    if run_folder_state(run) in ("new", "empty"):
        return run
    base = run.rstrip("/\\")
    k = 2
    while os.path.exists(f"{base}_{k}"):
        k += 1
    return f"{base}_{k}"

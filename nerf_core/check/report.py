"""What ``check`` reports: each ``Problem`` names its file, frame and field; ``CheckReport`` collects
errors and warnings and prints them (or one JSON object).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional


@dataclass
class Problem:
    file: str
    message: str
    frame: Optional[int] = None
    frame_path: Optional[str] = None
    field: Optional[str] = None

    def __str__(self) -> str:
        where = self.file
        if self.frame is not None:
            where += f": frame {self.frame}" + (f" ({self.frame_path})" if self.frame_path else "")
        if self.field:
            where += f": field '{self.field}'"
        return f"{where}: {self.message}"


@dataclass
class CheckReport:
    root: Path
    errors: List[Problem] = field(default_factory=list)
    warnings: List[Problem] = field(default_factory=list)
    n_frames: Dict[str, int] = field(default_factory=dict)
    plan: List[str] = field(default_factory=list)  # what `train` will decide for a valid dataset
    notes: List[str] = field(default_factory=list)  # what was checked, when it is not the folder given
    trainable: Optional[bool] = None  # train reads the dataset (``dataset_problems`` is empty); None: not asked

    @property
    def ok(self) -> bool:
        return not self.errors

    def error(self, *a, **k) -> None:
        self.errors.append(Problem(*a, **k))

    def warn(self, *a, **k) -> None:
        self.warnings.append(Problem(*a, **k))

    def format(self) -> str:
        lines = [f"NOTE    {n}" for n in self.notes]
        lines += [f"ERROR   {p}" for p in self.errors] + [f"WARNING {p}" for p in self.warnings]
        lines += [f"TRAIN   {line}" for line in self.plan]
        counts = ", ".join(f"{k} {v}" for k, v in self.n_frames.items())
        verdict = "valid" if self.ok else f"INVALID: {len(self.errors)} error(s)"
        lines.append(
            f"{self.root}: {verdict}, {len(self.warnings)} warning(s)" + (f" ({counts} frames)" if counts else "")
        )
        if not self.ok and self.trainable:
            # A dataset of another tool: wrong as an export of ours, and still what train reads.
            lines.append("train reads this dataset as it is: the errors above are conventions of an export "
                         "(`check --for-training` checks it for training only)")
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return {"dataset": str(self.root), "ok": self.ok, "errors": [str(p) for p in self.errors],
                "warnings": [str(p) for p in self.warnings], "frames": self.n_frames, "train_plan": self.plan,
                "trainable": self.trainable, "notes": self.notes}


def shown_path(root: Path, file: str) -> str:
    try:
        return str(Path(file).resolve().relative_to(root.resolve()))
    except ValueError:
        return file

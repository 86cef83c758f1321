"""A private Python environment with PyTorch for the trainer, built by the add-on ("Set up PyTorch").

The add-on never imports torch: training runs in a child interpreter. Artists have no such interpreter,
so the add-on can make one: a virtual environment created with Blender's own Python in the extension's
user folder, into which pip installs torch, numpy and Pillow (and OpenEXR for EXR datasets). nerf_core
itself is not installed: the add-on vendors it and puts it on the child's PYTHONPATH (``core_path``).

This module holds the decisions, free of bpy so that tests and scripts can use them: which build to
offer (``default_device``), the commands (``plan_setup``: create the venv, update pip, install, verify),
reading pip's output into coarse progress (``PipProgress``), what a failure means for the user
(``explain_failure``) and which interpreters already on the machine could run the trainer
(``candidate_interpreters``). The job that runs the plan lives in ``common/torch_setup_ops``.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import sys
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Mapping, Optional, Sequence

from . import child_process
from .child_process import SetupError
from .progress import ProgressParser

ENV_DIRNAME = "torch_env"  # below the extension's user folder
READY_FILE = "nerf_bridge_env.json"  # written once the environment imported torch and nerf_core
PYPI = "https://pypi.org/simple"
PIP_WITH_RAW_PROGRESS = "pip>=24.1"  # ``--progress-bar raw`` prints "Progress N of M" lines we can read
# What nerf_core needs at run time (pyproject's dependencies without the development pins).
# What the vendored nerf_core needs: the same as pyproject.toml's [project] dependencies and its `exr`
# extra (blender_tests/test_torch_setup_plan.py holds them equal).
REQUIREMENTS = ("torch>=2.5", "numpy>=1.24", "pillow>=9.1")
EXR_REQUIREMENT = "openexr>=3.2,<4"  # optional: only EXR datasets and depth maps need it


@dataclass(frozen=True)
class Build:
    """One PyTorch build the user can choose; sizes are what the UI announces before anything starts."""

    key: str
    label: str
    index_url: str
    download: str  # approximate download, for the confirmation dialog
    disk: str  # approximate size of the finished environment


BUILDS = {
    "CPU": Build("CPU", "CPU only", "https://download.pytorch.org/whl/cpu", "about 200 MB", "about 1 GB"),
    # PyTorch's CUDA 12.8 wheels: the same index on Linux and Windows (PyPI's Windows torch is CPU-only).
    "CUDA": Build("CUDA", "NVIDIA GPU (CUDA)", "https://download.pytorch.org/whl/cu128", "about 2.5 GB",
                  "about 5 GB"),
}


def default_device(which: Callable[[str], Optional[str]] = shutil.which,
                   exists: Callable[[str], bool] = os.path.exists, platform: str = sys.platform) -> str:
    """'CUDA' when the machine shows an NVIDIA driver (``nvidia-smi`` on PATH, or /proc/driver/nvidia),
    else 'CPU'. macOS has no CUDA builds of PyTorch."""
    if platform == "darwin":
        return "CPU"
    return "CUDA" if which("nvidia-smi") or exists("/proc/driver/nvidia") else "CPU"


def base_python(executable: str = sys.executable, binary_path_python: str = "") -> str:
    """The Python binary to build the environment with: Blender's own.

    Blender 2.91+ sets ``sys.executable`` to its bundled Python binary; older releases set it to the
    Blender binary and had ``bpy.app.binary_path_python`` instead (pass it as ``binary_path_python``).
    """
    for cand in (executable, binary_path_python):
        if cand and os.path.basename(cand).lower().startswith("python") and os.path.isfile(cand):
            return cand
    raise SetupError(f"Blender's Python interpreter was not found (sys.executable is {executable or 'empty'}): "
                     f"set {child_process.PREFS_HINT} to a Python that has torch instead.")


def env_python(env_dir: str) -> str:
    """The interpreter of the virtual environment at ``env_dir``."""
    if os.name == "nt":
        return os.path.join(env_dir, "Scripts", "python.exe")
    return os.path.join(env_dir, "bin", "python")


def is_ready(env_dir: str) -> bool:
    """Did a setup finish here (the environment imported torch and nerf_core)?"""
    return os.path.isfile(os.path.join(env_dir, READY_FILE)) and os.path.isfile(env_python(env_dir))


def mark_ready(env_dir: str, device: str, probe_message: str) -> None:
    child_process.write_json_atomic(os.path.join(env_dir, READY_FILE),
                                    {"device": device, "probe": probe_message, "python": env_python(env_dir)})


def ready_info(env_dir: str) -> Dict[str, str]:
    """What ``mark_ready`` wrote ({} when absent or unreadable)."""
    try:
        with open(os.path.join(env_dir, READY_FILE), encoding="utf-8") as fh:
            info = json.load(fh)
        return info if isinstance(info, dict) else {}
    except (OSError, ValueError):
        return {}


# -- the plan -----------------------------------------------------------------------------------------
@dataclass
class Step:
    """One command of the setup. ``start``/``end``: the share of the whole bar it covers."""

    name: str  # 'venv', 'pip', 'install', 'verify'
    label: str  # what the panel says while it runs
    cmd: List[str]
    env: Dict[str, str]
    start: float
    end: float


@dataclass
class SetupPlan:
    env_dir: str
    python: str  # the environment's interpreter, once built
    device: str
    wheel_dir: str
    packages: List[str]
    steps: List[Step] = field(default_factory=list)

    def describe(self) -> str:
        """One sentence for the confirmation dialog: what is fetched from where, and how big."""
        names = ", ".join(p.split(">")[0].split("=")[0].split("<")[0] for p in self.packages)
        if self.wheel_dir:
            return f"Install {names} from the folder {self.wheel_dir} (no download) into {self.env_dir}."
        build = BUILDS[self.device]
        return (f"Download {names} ({build.label} build of PyTorch: {build.download}; {build.disk} on disk) "
                f"from download.pytorch.org and pypi.org into {self.env_dir}.")


def step_env(base: Mapping[str, str], offline: bool) -> Dict[str, str]:
    """Environment for the setup commands: none of Blender's PYTHONHOME/PYTHONPATH, no user site-packages.
    ``offline``: no pip configuration either (``PIP_*`` variables and pip.conf), so that the wheel folder
    is really the only source, whatever index or find-links the machine configures."""
    env = {k: v for k, v in base.items() if k not in ("PYTHONHOME", "PYTHONPATH")}
    env.update(PYTHONNOUSERSITE="1", PYTHONUNBUFFERED="1", PYTHONIOENCODING="utf-8", PIP_NO_INPUT="1")
    if offline:
        env = {k: v for k, v in env.items() if not k.startswith("PIP_") or k == "PIP_NO_INPUT"}
        env["PIP_CONFIG_FILE"] = os.devnull  # pip then reads no configuration file at all
    return env


def plan_setup(env_dir: str, base: str, device: str = "CPU", wheel_dir: str = "", openexr: bool = True,
               online: bool = True, environ: Optional[Mapping[str, str]] = None,
               platform: str = sys.platform) -> SetupPlan:
    """The commands that build the environment at ``env_dir`` with the interpreter ``base``.

    Args:
        device: 'CPU' or 'CUDA' (a key of ``BUILDS``).
        wheel_dir: a folder of wheels: install from it alone (``--no-index --find-links``), offline.
        online: Blender's "Allow Online Access"; without it only ``wheel_dir`` installs are allowed.
    Raises:
        SetupError: naming what to change (offline, a missing folder, CUDA on macOS).
    """
    if device not in BUILDS:
        raise SetupError(f"Unknown PyTorch build {device!r}: choose one of {', '.join(BUILDS)}.")
    if wheel_dir:
        wheel_dir = os.path.abspath(os.path.expanduser(wheel_dir))
        if not os.path.isdir(wheel_dir):
            raise SetupError(f"Wheel folder {wheel_dir} does not exist: choose the folder that holds the .whl files.")
        if not any(name.endswith(".whl") for name in os.listdir(wheel_dir)):
            raise SetupError(f"Wheel folder {wheel_dir} holds no .whl files: fill it with `pip download` "
                             "(see the user guide), or clear the field to download.")
    elif not online:
        raise SetupError("Blender's online access is off (Preferences > System > Network > Allow Online Access): "
                         "allow it to download PyTorch, or choose a folder of wheels to install from.")
    if device == "CUDA" and platform == "darwin" and not wheel_dir:
        raise SetupError("PyTorch has no CUDA builds for macOS: choose CPU (Apple GPUs are used through it).")
    python = env_python(env_dir)
    packages = list(REQUIREMENTS) + ([EXR_REQUIREMENT] if openexr else [])
    env = step_env(os.environ if environ is None else environ, offline=bool(wheel_dir))
    pip = [python, "-m", "pip", "install", "--disable-pip-version-check", "--no-input"]
    steps = [Step("venv", "Creating the environment", [base, "-m", "venv", "--clear", env_dir], env, 0.0, 0.05)]
    if wheel_dir:
        # --no-compile: pip would byte-compile torch's 10 000 modules (a minute on a small machine);
        # Python compiles what it imports on first use instead.
        source = ["--no-index", "--find-links", wheel_dir, "--progress-bar", "off", "--no-compile"]
        steps.append(Step("install", "Installing from the wheel folder", pip + source + packages, env, 0.05, 0.9))
    else:
        build = BUILDS[device]
        steps.append(Step("pip", "Updating pip", pip + ["--upgrade", PIP_WITH_RAW_PROGRESS], env, 0.05, 0.08))
        source = ["--index-url", build.index_url, "--extra-index-url", PYPI, "--progress-bar", "raw", "--no-compile"]
        steps.append(Step("install", "Downloading", pip + source + packages, env, 0.08, 0.9))
    # The trainer's own check (child_process.probe_command), with nerf_core on the path as for training.
    steps.append(Step("verify", "Checking that torch and nerf_core import",
                      child_process.probe_command(python), child_process.child_env(), 0.9, 1.0))
    return SetupPlan(env_dir, python, device, wheel_dir, packages, steps)


# -- reading pip's output -------------------------------------------------------------------------------
_COLLECT = re.compile(r"^(?:Collecting|Processing|Requirement already satisfied:) (\S+)")
_DOWNLOAD = re.compile(r"^Downloading (\S+) \(([\d.]+ [kMG]?B)\)")
_RAW = re.compile(r"^Progress (\d+) of (\d+)")
_INSTALLING = re.compile(r"^Installing collected packages: (.*)")


class PipProgress(ProgressParser):
    """pip's output as coarse progress: which phase, which file, how far the current download is.

    Attributes:
        phase: 'collect' (resolving, downloading), 'install', 'installed', or None before any line.
        collected: how many requirements pip has collected so far.
        current: the file being downloaded, with its size ("torch-2.13.0...whl (190.0 MB)").
        file_fraction: the current download's fraction from ``--progress-bar raw``, or None.
        installing: the number of packages pip is installing.
        pip_errors: pip's ``ERROR:`` lines, first first.
    """

    def __init__(self, tail_lines: int = 30):
        super().__init__(tail_lines)
        self.phase: Optional[str] = None
        self.collected = 0
        self.current = ""
        self.file_fraction: Optional[float] = None
        self.installing = 0
        self.pip_errors: List[str] = []

    def feed_line(self, line: str):
        event = super().feed_line(line)
        self.observe(line.strip())
        return event

    def observe(self, line: str) -> None:
        raw = _RAW.match(line)
        if raw:
            total = int(raw.group(2))
            self.file_fraction = min(1.0, int(raw.group(1)) / total) if total > 0 else None
            return
        if _COLLECT.match(line):
            self.phase, self.collected = "collect", self.collected + 1
        elif _DOWNLOAD.match(line):
            m = _DOWNLOAD.match(line)
            current = f"{os.path.basename(m.group(1))} ({m.group(2)})"
            self.phase, self.current, self.file_fraction = "collect", current, 0.0
        elif _INSTALLING.match(line):
            self.phase, self.current, self.file_fraction = "install", "", None
            self.installing = len([p for p in _INSTALLING.match(line).group(1).split(",") if p.strip()])
        elif line.startswith("Successfully installed"):
            self.phase = "installed"
        elif line.startswith("ERROR:"):
            self.pip_errors.append(line)

    def status(self) -> str:
        """What pip is doing, in a few words for the panel."""
        if self.phase == "install":
            return f"Installing {self.installing} packages (this takes a while for torch)"
        if self.phase == "installed":
            return "Installed"
        if self.current:
            pct = "" if self.file_fraction is None else f" {100 * self.file_fraction:.0f}%"
            return f"Downloading {self.current}{pct}"
        return f"Collecting packages ({self.collected})" if self.collected else "Starting pip"

    def share(self) -> float:
        """How far the install step is, in [0, 1]: collecting fills the first 80%, installing the rest."""
        if self.phase in ("install", "installed"):
            return 0.8 if self.phase == "install" else 1.0
        # Each collected requirement moves the bar a little; a download's own progress moves it within.
        return min(0.75, 0.05 * self.collected + 0.6 * (self.file_fraction or 0.0))


def explain_failure(step: Step, lines: Sequence[str], plan: SetupPlan) -> str:
    """A message for the user when ``step`` failed, from the last lines of its output."""
    errors = [ln for ln in lines if ln.startswith("ERROR:")]
    detail = errors[0][len("ERROR:"):].strip() if errors else (lines[-1] if lines else "no output")
    if step.name == "venv":
        hint = ("Blender's Python could not create a virtual environment (some Linux distributions' Blender "
                "packages lack ensurepip/venv): set Python with torch to an interpreter you made instead.")
        return f"{hint} ({detail})"
    if step.name == "install" and plan.wheel_dir and ("No matching distribution" in detail
                                                       or "Could not find a version" in detail):
        return (f"The wheel folder {plan.wheel_dir} lacks a wheel this Python can use: {detail}. It needs "
                f"wheels for Python {sys.version_info[0]}.{sys.version_info[1]} on this platform, e.g. from "
                f"`pip download {' '.join(repr(p) for p in plan.packages)} -d FOLDER`.")
    if step.name in ("pip", "install") and not plan.wheel_dir and any(
            word in " ".join(lines) for word in ("NewConnectionError", "Temporary failure", "Max retries")):
        return f"Could not reach the package index (no network, or a proxy in the way): {detail}"
    return f"{step.label} failed: {detail}"


# -- interpreters already on the machine -----------------------------------------------------------------
@dataclass(frozen=True)
class Candidate:
    label: str  # where it came from, e.g. "Private environment (Set up PyTorch)"
    python: str


def candidate_interpreters(addon_dir: str = child_process.ADDON_DIR, environ: Optional[Mapping[str, str]] = None,
                           private_env: str = "") -> List[Candidate]:
    """Interpreters that may run the trainer, most likely first, each an existing file, no path twice:
    the private environment, the repository's .venv (add-on run from a checkout), an active virtualenv
    ($VIRTUAL_ENV) and an active conda environment ($CONDA_PREFIX). Not probed: the caller does that."""
    environ = os.environ if environ is None else environ
    found = [("Private environment (Set up PyTorch)", env_python(private_env) if private_env else ""),
             ("This checkout's .venv", env_python(os.path.join(os.path.dirname(addon_dir), ".venv"))),
             ("Active virtualenv ($VIRTUAL_ENV)", env_python(environ["VIRTUAL_ENV"]) if environ.get("VIRTUAL_ENV")
              else ""),
             ("Active conda environment ($CONDA_PREFIX)", _conda_python(environ.get("CONDA_PREFIX", "")))]
    out: List[Candidate] = []
    seen = set()
    for label, python in found:
        # abspath, not realpath: every venv's python links to the same base binary, yet each venv differs.
        if python and os.path.isfile(python) and os.path.abspath(python) not in seen:
            seen.add(os.path.abspath(python))
            out.append(Candidate(label, os.path.abspath(python)))
    return out


def _conda_python(prefix: str) -> str:
    if not prefix:
        return ""
    return os.path.join(prefix, "python.exe") if os.name == "nt" else os.path.join(prefix, "bin", "python")

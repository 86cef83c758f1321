"""Build a small C source file into a shared library at first use, and load it with ctypes.

For CPU kernels that need no torch headers (they take raw float pointers), so the build is one
``cc`` call of about a second, not a ``torch.utils.cpp_extension`` build with ninja and a minute of
compiling. The library is cached under ``$NERF_CORE_CACHE`` (default ``$XDG_CACHE_HOME/nerf_bridge``
or ``~/.cache/nerf_bridge``) by a hash of the source, the compiler command and the machine, so an
edit or another CPU architecture rebuilds it, and concurrent processes (torchrun ranks, farm jobs
sharing a home folder) never load a half-written file: each builds into its own temporary name and
renames it into place.

Nothing here is required: :func:`load` returns None with a reason when there is no compiler, the
build fails or the library does not load, and callers fall back to plain PyTorch.
Set ``NERF_CORE_NATIVE=0`` to turn native kernels off (for A/B runs, or to rule them out).
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from pathlib import Path

_FLAGS = ("-O3", "-shared", "-fPIC", "-pthread", "-std=c99")
_loaded: dict[str, tuple[ctypes.CDLL | None, str]] = {}


def enabled() -> bool:
    """False when ``NERF_CORE_NATIVE`` is set to 0/false/no/off."""
    return os.environ.get("NERF_CORE_NATIVE", "1").strip().lower() not in ("0", "false", "no", "off")


def cache_dir() -> Path:
    root = os.environ.get("NERF_CORE_CACHE")
    if root:
        return Path(root)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "nerf_bridge"


def _compiler() -> str | None:
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def _build(source: Path, cc: str) -> Path:
    """Compile ``source`` unless a library of the same key is cached; returns the library's path."""
    text = source.read_bytes()
    key = hashlib.sha256(text + " ".join((cc, *_FLAGS, platform.machine(), platform.system())).encode())
    target_dir = cache_dir()
    target = target_dir / f"{source.stem}-{key.hexdigest()[:16]}.so"
    if target.exists():
        return target
    target_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=target.stem + ".", suffix=".so.tmp", dir=target_dir)
    os.close(fd)
    try:
        proc = subprocess.run([cc, *_FLAGS, str(source), "-o", tmp, "-lm"], capture_output=True, text=True,
                              timeout=120)
        if proc.returncode != 0:
            raise OSError(f"{Path(cc).name} failed on {source.name}: {(proc.stderr or proc.stdout).strip()[:500]}")
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return target


def load(source: str | os.PathLike) -> tuple[ctypes.CDLL | None, str]:
    """(library, "") once built and loaded, else (None, why not). Cached per process and per source."""
    if not enabled():
        return None, "turned off by NERF_CORE_NATIVE"
    source = Path(source)
    key = str(source.resolve())
    if key in _loaded:
        return _loaded[key]
    if platform.system() == "Windows":
        result: tuple[ctypes.CDLL | None, str] = (None, "native kernels are not built on Windows")
    else:
        cc = _compiler()
        if cc is None:
            result = (None, "no C compiler (cc, gcc or clang) on PATH")
        else:
            try:
                result = (ctypes.CDLL(str(_build(source, cc))), "")
            except (OSError, subprocess.SubprocessError) as exc:
                result = (None, str(exc))
    _loaded[key] = result
    return result

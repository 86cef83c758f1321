"""The one home of "how much memory may this process still take", and of the one line an allocation that
failed anyway becomes.

``available_memory`` is the smallest of three limits, because each alone has approved work that then
died in a ``MemoryError`` traceback:

- the machine's free memory (``MemAvailable`` in ``/proc/meminfo``);
- the address-space limit (``ulimit -v``, ``RLIMIT_AS``) minus the address space already mapped
  (``VmSize``): the kernel refuses a mapping past it whatever the free memory;
- a container's memory limit: cgroup v2 ``memory.max`` minus ``memory.current`` (v1:
  ``memory.limit_in_bytes`` minus ``memory.usage_in_bytes``) of this process's own cgroup.

Every size check (``export.grid.check_fits``, ``render.memory.check_view_memory``) reads this, and
``named_out_of_memory`` turns what slips past them (``MemoryError``, torch's allocator errors) into one
line naming the flag that sets the size.
"""
from __future__ import annotations

import contextlib
import os
import resource
from pathlib import Path
from typing import Iterator, Optional

PROC = Path("/proc")
CGROUP = Path("/sys/fs/cgroup")
_UNLIMITED_CGROUP = 1 << 60  # cgroup v1 writes "no limit" as a number near 2^63


def _meminfo(proc: Path) -> Optional[int]:
    try:
        with open(proc / "meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _mapped(proc: Path) -> int:
    """Bytes of address space this process has mapped (``VmSize``), 0 when unknown."""
    try:
        with open(proc / "self" / "status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def _address_space(proc: Path) -> Optional[int]:
    try:
        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ValueError, OSError):
        return None
    if soft == resource.RLIM_INFINITY or soft < 0:
        return None
    return max(0, soft - _mapped(proc))


def _read_int(path: Path) -> Optional[int]:
    try:
        text = path.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None
    return int(text) if text.isdigit() else None  # "max" (no limit) and anything odd: no limit


def _cgroup_dirs(proc: Path, cgroup: Path) -> Iterator[tuple[Path, str, str]]:
    """(folder, limit file, usage file) of this process's memory cgroup, v2 then v1 (each at its path in
    ``/proc/self/cgroup`` and at the root, which is what a container sees)."""
    paths = {"v2": [], "v1": []}
    try:
        for line in (proc / "self" / "cgroup").read_text(encoding="ascii").splitlines():
            num, controllers, rel = line.split(":", 2)
            if num == "0" and controllers == "":
                paths["v2"].append(rel.lstrip("/"))
            elif "memory" in controllers.split(","):
                paths["v1"].append(rel.lstrip("/"))
    except (OSError, ValueError, UnicodeDecodeError):
        pass
    for rel in paths["v2"] + [""]:
        yield cgroup / rel, "memory.max", "memory.current"
    for rel in paths["v1"] + [""]:
        yield cgroup / "memory" / rel, "memory.limit_in_bytes", "memory.usage_in_bytes"


def _cgroup_room(proc: Path, cgroup: Path) -> Optional[int]:
    for folder, limit_name, usage_name in _cgroup_dirs(proc, cgroup):
        limit = _read_int(folder / limit_name)
        if limit is None or limit >= _UNLIMITED_CGROUP:
            continue
        return max(0, limit - (_read_int(folder / usage_name) or 0))
    return None


def available_memory(proc: Path = PROC, cgroup: Path = CGROUP) -> Optional[int]:
    """Bytes a new allocation may still take: the smallest of the free memory, the address-space limit
    left and the cgroup's limit left (module docstring); None when none of them can be read."""
    known = [v for v in (_meminfo(proc), _address_space(proc), _cgroup_room(proc, cgroup)) if v is not None]
    return min(known) if known else None


def size_text(n: float) -> str:
    """``n`` bytes for a person: "512 B", "3.2 MB", "1.5 GB"."""
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if n < 1024 or unit == "TB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} TB"


def is_out_of_memory(exc: BaseException) -> bool:
    """True for ``MemoryError`` and torch's allocator failures (``torch.OutOfMemoryError`` is a
    RuntimeError; the CPU allocator's reads "DefaultCPUAllocator: can't allocate memory")."""
    if isinstance(exc, MemoryError):
        return True
    if not isinstance(exc, RuntimeError):
        return False
    text = str(exc).lower()
    return type(exc).__name__ == "OutOfMemoryError" or "out of memory" in text or "can't allocate memory" in text


class OutOfMemory(ValueError):
    """An allocation failed although the size checks let the work start; the message names the flag."""


@contextlib.contextmanager
def named_out_of_memory(what: str, advice: str) -> Iterator[None]:
    """Turn an allocation that fails inside the block into OutOfMemory: "``what``: not enough memory
    (...); ``advice``" (``what``: the flag and its value, ``--resolution 512``; ``advice``: which flag
    to turn down). Other errors pass unchanged."""
    try:
        yield
    except (MemoryError, RuntimeError) as exc:
        if not is_out_of_memory(exc):
            raise
        have = available_memory()
        left = f", {size_text(have)} available now" if have is not None else ""
        detail = (str(exc).splitlines() or [type(exc).__name__])[0][:160] or type(exc).__name__
        raise OutOfMemory(f"{what}: not enough memory ({detail}{left}); {advice}") from None

"""Choosing the torch device: CUDA when available, else CPU; ``--device`` overrides."""
from __future__ import annotations

import torch

SUPPORTED = ("cpu", "cuda", "mps")  # torch names more (meta, xla, hpu...): nothing here runs on them


def pick_device(name: str | torch.device | None = None, flag: str = "--device") -> torch.device:
    """``None``/``"auto"`` -> ``cuda`` if available else ``cpu``; otherwise the named device (a name or a
    ``torch.device``, checked alike: ``torch.device("meta")`` is refused here, not deep inside a load).

    Raises ValueError naming ``flag`` when the named device is unavailable, instead of the deep CUDA
    initialisation error torch would give on first use.
    """
    if isinstance(name, torch.device):
        name = str(name)
    if name in (None, "", "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except RuntimeError as exc:
        raise ValueError(f"{flag} {name!r} is not a torch device name (try cpu, cuda, cuda:1)") from exc
    if dev.type not in SUPPORTED:
        raise ValueError(f"{flag} {name}: nerf_core trains and renders on {', '.join(SUPPORTED)} devices, "
                         f"not {dev.type!r}")
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"{flag} {name}: CUDA is not available in this torch build/machine; use --device cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"{flag} {name}: only {torch.cuda.device_count()} CUDA device(s) present")
    if dev.type == "mps" and not (hasattr(torch.backends, "mps") and torch.backends.mps.is_available()):
        raise ValueError(f"{flag} {name}: MPS is not available on this machine")
    return dev

"""The rules every public function of ``nerf_core.__all__`` applies to its arguments, in one place.
What counts as a number or a whole number is ``nerf_core.contract.numbers``' (the readers below this
layer need it too); this module builds the messages on it.

The command line checks its flags with argparse types; the Python API checks the same things here,
at the boundary, before any work or write: a wrong type raises TypeError, a value out of range
ValueError, both naming the function, the argument and what it must be. The domain rules (a pose,
a focal length, a scene box) are the loaders' own (``nerf_core.contract``, ``nerf_core.data.validation``);
the modules that own those types call them.

    n = integer("render_view", "chunk", chunk, low=1)
    rgb = tensor("psnr", "pred", pred, floating=True, last_dim=3)
"""
from __future__ import annotations

import math
import os
from typing import Iterable, Optional

import numpy as np
import torch

from nerf_core.contract.numbers import is_real, is_whole


def _shown(value, limit: int = 60) -> str:
    text = f"a {type(value).__name__} of shape {tuple(value.shape)}" if hasattr(value, "shape") else repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def integer(func: str, name: str, value, low: Optional[int] = None, high: Optional[int] = None) -> int:
    """``value`` as an int (a Python or numpy integer, not a bool) in ``low..high``."""
    if not is_whole(value):
        raise TypeError(f"{func}: {name} must be an integer, got {_shown(value)}")
    value = int(value)
    if (low is not None and value < low) or (high is not None and value > high):
        span = f">= {low}" if high is None else f"in {low}..{high}" if low is not None else f"<= {high}"
        raise ValueError(f"{func}: {name} must be an integer {span}, got {value}")
    return value


def number(func: str, name: str, value, low: Optional[float] = None, above: Optional[float] = None,
           high: Optional[float] = None) -> float:
    """``value`` as a finite float, >= ``low``, > ``above`` and <= ``high`` where given."""
    if isinstance(value, torch.Tensor) and value.numel() == 1 and not value.dtype == torch.bool:
        value = value.item()
    if not is_real(value):
        raise TypeError(f"{func}: {name} must be a number, got {_shown(value)}")
    value = float(value)
    want = " and ".join(s for s in (f">= {low}" if low is not None else "", f"> {above}" if above is not None else "",
                                    f"<= {high}" if high is not None else "") if s)
    if (not math.isfinite(value) or (low is not None and value < low) or (above is not None and value <= above)
            or (high is not None and value > high)):
        raise ValueError(f"{func}: {name} must be a finite number{' ' + want if want else ''}, got {value}")
    return value


def choice(func: str, name: str, value, choices: Iterable[str]) -> str:
    """``value`` when it is one of the strings ``choices``."""
    choices = tuple(choices)
    if not isinstance(value, str):
        raise TypeError(f"{func}: {name} must be one of {', '.join(map(repr, choices))}, got {_shown(value)}")
    if value not in choices:
        raise ValueError(f"{func}: {name} must be one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def path(func: str, name: str, value) -> str:
    """``value`` as a str path: a non-empty str or os.PathLike that the file system can encode."""
    if not isinstance(value, (str, os.PathLike)):
        raise TypeError(f"{func}: {name} must be a path (str or pathlib.Path), got {_shown(value)}")
    text = os.fspath(value)
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"{func}: {name} must be a non-empty path, got {value!r}")
    try:
        os.fsencode(text)
    except UnicodeError:
        raise ValueError(f"{func}: {name} {text!r} holds a character no file name can (a lone surrogate)") from None
    if "\0" in text:
        raise ValueError(f"{func}: {name} {text!r} holds a NUL character")
    return text


def tensor(func: str, name: str, value, floating: bool = True, last_dim: Optional[int] = None,
           ndim: Optional[int] = None, finite: bool = True, dtype_hint: str = "") -> torch.Tensor:
    """``value`` (a tensor, numpy array or nested list of numbers) as a tensor, checked.

    Args:
        floating: it must hold floats (an integer or bool array is refused: 8-bit images are not colours
            in [0, 1]).
        last_dim, ndim: the size of its last dimension and its number of dimensions, where given.
        finite: refuse NaN and inf.
        dtype_hint: added to the message for a wrong dtype.
    """
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise TypeError(f"{func}: {name} must be a tensor or array of numbers, got {_shown(value)}")
    if not isinstance(value, torch.Tensor):
        try:
            arr = np.asarray(value)
            if arr.dtype == object or arr.dtype.kind in "USV":
                raise TypeError
            value = torch.as_tensor(arr)
        except (TypeError, ValueError, OverflowError, RuntimeError):
            raise TypeError(f"{func}: {name} must be a tensor or array of numbers, got {_shown(value)}") from None
    if value.is_complex():
        raise TypeError(f"{func}: {name} must hold real numbers, got {value.dtype}")
    if floating and not value.is_floating_point():
        raise TypeError(f"{func}: {name} must hold floats, got {value.dtype}{dtype_hint}")
    if ndim is not None and value.dim() != ndim:
        raise ValueError(f"{func}: {name} must have {ndim} dimension(s), got shape {tuple(value.shape)}")
    if last_dim is not None and (value.dim() == 0 or value.shape[-1] != last_dim):
        raise ValueError(f"{func}: {name} must have shape (..., {last_dim}), got {tuple(value.shape)}")
    if finite and value.is_floating_point() and value.numel() and not bool(torch.isfinite(value).all()):
        raise ValueError(f"{func}: {name} holds NaN or inf")
    return value


def same_shape(func: str, a_name: str, a: torch.Tensor, b_name: str, b: torch.Tensor) -> None:
    """Refuse two arrays of different shapes (broadcasting one against the other would compare wrong pixels)."""
    if tuple(a.shape) != tuple(b.shape):
        raise ValueError(f"{func}: {a_name} {tuple(a.shape)} and {b_name} {tuple(b.shape)} must have the same shape")


def colour(func: str, name: str, value) -> torch.Tensor:
    """A (3,) float colour with every channel in [0, 1]."""
    if isinstance(value, str):
        raise TypeError(f"{func}: {name} must be an (r, g, b) colour in [0, 1], got the string {value!r}")
    c = tensor(func, name, value, floating=False, ndim=1).float()
    if c.shape != (3,) or bool(((c < 0) | (c > 1)).any()):
        raise ValueError(f"{func}: {name} must be an (r, g, b) colour in [0, 1], got {c.tolist()}")
    return c


def instance(func: str, name: str, value, cls, what: str):
    """``value`` when it is a ``cls`` (TypeError naming ``what`` it must be otherwise)."""
    if not isinstance(value, cls):
        raise TypeError(f"{func}: {name} must be {what}, got {_shown(value)}")
    return value

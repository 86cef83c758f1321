"""One ``register()``/``unregister()`` pair for a package made of parts that each register their own
classes: the parts in order, and in reverse order when the add-on is disabled."""
from __future__ import annotations

from typing import Callable, Sequence, Tuple


def registrar(parts: Sequence) -> Tuple[Callable[[], None], Callable[[], None]]:
    """(register, unregister) calling each part's own, ``parts`` in order and then in reverse.

    Args:
        parts: modules or packages, each with ``register()`` and ``unregister()``.
    """
    def register() -> None:
        for part in parts:
            part.register()

    def unregister() -> None:
        for part in reversed(parts):
            part.unregister()

    return register, unregister

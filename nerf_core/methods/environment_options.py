"""``EnvironmentOptions``: the ``environment`` option every method takes (the learned world behind the
scene, ``nerf_core.fields.environment.EnvironmentMap``), declared and bounded like a method's own.

``--set environment='{"width": 100000}'`` asked for a 60 GB texture and ended in advice to lower
``--batch-rays``; the width is now bounded by what a texture and its Adam moments may sensibly take.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Mapping

from nerf_core.fields.environment import MIN_WIDTH, EnvironmentMap
from nerf_core.methods.options import MethodOptions, OptionError, option

# 8192 x 4096 texels x 3 channels in float32 is 400 MB, 1.2 GB with Adam's two moments: more than any
# camera resolves (``size_for_focal`` picks at most ``fields.environment.MAX_WIDTH``).
MAX_ENVIRONMENT_WIDTH = 8192
MAX_LEVELS = 8  # each level is 4x narrower: 8 levels go from 8192 to below MIN_WIDTH


@dataclasses.dataclass
class EnvironmentOptions(MethodOptions):
    """The options of the learned world (``--set environment='{"width": 512}'``)."""

    width: int = option(512, "finest texture width in texels (height: half of it)", low=MIN_WIDTH,
                        high=MAX_ENVIRONMENT_WIDTH)
    levels: int = option(4, "pyramid levels, each 4x narrower", low=1, high=MAX_LEVELS)

    def check_together(self, method: str) -> None:
        if self.width % 2:
            raise OptionError("environment", f"{method}: option 'width' must be an even number, got {self.width}")


def checked_environment(method: str, value: Any) -> Mapping[str, Any] | None:
    """``value`` of the ``environment`` option (a dict of ``EnvironmentMap`` options, or None), checked;
    OptionError naming ``environment`` and the entry otherwise."""
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise OptionError("environment", f"{method}: option 'environment' must be a dict of EnvironmentMap options "
                                         f"such as {{\"width\": 512}}, got {value!r}")
    try:
        return EnvironmentOptions.parse(f"{method}: environment", value).to_dict()
    except OptionError as exc:
        raise OptionError("environment", str(exc)) from None


def build_environment(method: str, value: Any) -> EnvironmentMap | None:
    """The ``EnvironmentMap`` that option ``environment`` asks for, or None."""
    opts = checked_environment(method, value)
    return None if opts is None else EnvironmentMap(**opts)

"""What the add-on's panels share: the N-panel placement (one mixin instead of a copied header per
panel) and its property-split layout, an operator's error report, time formatting, the error box,
wrapped notes, and the redraw/status-bar helpers the job follower uses."""
from __future__ import annotations

import os
import textwrap
from typing import Optional

import bpy

from ..bridge.child_process import SetupError


class NerfPanel:
    """Mixin for every NeRF panel: 3D viewport > sidebar (N) > NeRF tab."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "NeRF"


def property_split(layout):
    """``layout`` as every NeRF panel draws its settings: labels left of the fields, no animate dots."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    return layout


def report_and_cancel(op, error) -> set:
    """What an operator returns when it cannot go on: ``error`` (its message says what to fix) goes
    to Blender's report as an error, and the operator is cancelled."""
    op.report({"ERROR"}, str(error))
    return {"CANCELLED"}


FORMAT_SECONDS_MAX_DAYS = 99  # beyond this a duration is shown as "more than 99 days"


def format_seconds(seconds: Optional[float]) -> str:
    """``75.2`` -> ``'1:15'``, ``90061`` -> ``'1d 1:01:01'``; None, NaN, inf or negative -> ``'?'``;
    beyond 99 days ``'> 99 days'`` (a trainer's ETA for a huge step budget is a number, but no
    27-digit clock). nerf_core.utils.progressbar is not importable from an installed extension, where
    nerf_core lives in the vendored folder for the child only."""
    if seconds is None or seconds != seconds or seconds in (float("inf"), float("-inf")) or seconds < 0:
        return "?"
    if seconds >= FORMAT_SECONDS_MAX_DAYS * 86400:
        return f"> {FORMAT_SECONDS_MAX_DAYS} days"
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    days, hours = divmod(hours, 24)
    if days:
        return f"{days}d {hours}:{minutes:02d}:{secs:02d}"
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def draw_error(layout, text: str) -> None:
    """The headline and the END of the log (where the cause is); the full text is in the console."""
    lines = text.splitlines()
    if len(lines) > 12:
        lines = lines[:2] + ["..."] + lines[-9:]
    box = layout.box()
    for i, line in enumerate(lines):
        box.label(text=line[:120], icon="ERROR" if i == 0 else "BLANK1")


def draw_wrapped(layout, text: str, icon: str, width: int = 60) -> None:
    """``text`` in a box, wrapped at ``width`` characters (a label does not wrap), ``icon`` on its
    first line; the others are indented to match."""
    box = layout.box()
    for k, line in enumerate(textwrap.wrap(text, width) or [text]):
        box.label(text=line, icon=icon if k == 0 else "BLANK1")


def path_options() -> set:
    """StringProperty options for a folder or file setting: Blender 4.5+ warns about "//" paths unless
    the property says it supports them; older versions lack the flag (and refuse it only when the
    class registers, so ask RNA whether properties know it)."""
    if "is_path_supports_blend_relative" not in bpy.types.Property.bl_rna.properties:
        return set()
    return {"PATH_SUPPORTS_BLEND_RELATIVE"}


def abs_path(path: str) -> str:
    """A settings path as an absolute path ('' stays ''): ``//`` is the .blend's folder and ``~`` the
    home folder, never a folder of that name under Blender's working directory. A ``//`` path of an
    unsaved .blend has no folder to be relative to: SetupError."""
    if not path:
        return ""
    if path.startswith("//") and not bpy.data.filepath:
        raise SetupError(f"{path!r} is relative to the .blend, which is not saved yet: save the file or choose an "
                         "absolute folder.")
    return os.path.abspath(os.path.expanduser(bpy.path.abspath(path)))


def tag_redraw(context) -> None:
    """Redraw every 3D viewport, where the NeRF panels live, and the preferences (Set up PyTorch's
    progress), in every window."""
    wm = context.window_manager
    for window in getattr(wm, "windows", []):
        for area in window.screen.areas:
            if area.type in ("VIEW_3D", "PREFERENCES"):
                area.tag_redraw()


def status_bar(context, text: Optional[str]) -> None:
    """Show (or with None, clear) a line in Blender's status bar, where users look for long jobs."""
    workspace = getattr(context, "workspace", None)
    if workspace is not None:
        workspace.status_text_set(text)

"""What the add-on's panels share: the N-panel placement (one mixin instead of a copied header per
panel), time formatting, the error box, and the redraw/status-bar helpers the job follower uses."""
from __future__ import annotations

import os
from typing import Optional

import bpy


class NerfPanel:
    """Mixin for every NeRF panel: 3D viewport > sidebar (N) > NeRF tab."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "NeRF"


def format_seconds(seconds: Optional[float]) -> str:
    """``75.2`` -> ``'1:15'``; None -> ``'?'`` (nerf_core.progressbar is not importable from an
    installed extension, where nerf_core lives in the vendored folder for the child only)."""
    if seconds is None or seconds != seconds or seconds in (float("inf"), float("-inf")):
        return "?"
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def draw_error(layout, text: str) -> None:
    """The headline and the END of the log (where the cause is); the full text is in the console."""
    lines = text.splitlines()
    if len(lines) > 12:
        lines = lines[:2] + ["..."] + lines[-9:]
    box = layout.box()
    for i, line in enumerate(lines):
        box.label(text=line[:120], icon="ERROR" if i == 0 else "BLANK1")


def abs_path(path: str) -> str:
    """A settings path (possibly ``//``-relative to the .blend) as an absolute path; '' stays ''."""
    return os.path.abspath(bpy.path.abspath(path)) if path else ""


def tag_redraw(context) -> None:
    """Redraw every 3D viewport, where the NeRF panels live, in every window."""
    wm = context.window_manager
    for window in getattr(wm, "windows", []):
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def status_bar(context, text: Optional[str]) -> None:
    """Show (or with None, clear) a line in Blender's status bar, where users look for long jobs."""
    workspace = getattr(context, "workspace", None)
    if workspace is not None:
        workspace.status_text_set(text)

"""What a capture is asked for (``CaptureSettings``), and the render engine and film filter it renders with."""
from __future__ import annotations

from dataclasses import dataclass, field

import bpy

from ...bridge.core_contract import contract
from .frame_plan import CaptureError

ENGINE_ALIASES = {
    "cycles": ("CYCLES",),
    "eevee": ("BLENDER_EEVEE_NEXT", "BLENDER_EEVEE"),  # 4.2-4.4 call it EEVEE Next; 5.0 BLENDER_EEVEE
    "workbench": ("BLENDER_WORKBENCH",),
}
MAX_RESOLUTION = 65536  # Blender's largest render resolution per axis


@dataclass
class CaptureSettings:
    out_dir: str
    engine: str = "cycles"  # cycles | eevee | workbench (or a Blender engine identifier)
    samples: int = 16
    res_x: int = 200
    res_y: int = 200
    film_transparent: bool = True
    denoise: bool = False
    depth: bool = False
    normals: bool = False
    masks: bool = False
    points: bool = False
    n_points: int = 100_000
    overwrite: bool = False
    target: str = "SCENE"  # mask objects: SCENE (everything that renders) or SELECTION
    normalize_camera_scale: bool = False
    layout: dict = field(default_factory=dict)  # LayoutSpec.to_dict(), recorded in the manifest
    seed: int = 0
    shard: tuple | None = None  # (K, N), 1 <= K <= N: render only shard K's share (plan.frame_plan)


def resolve_engine(name: str) -> str:
    """'cycles' / 'eevee' / 'workbench' (any case) or a Blender identifier -> the identifier 5.0 accepts."""
    candidates = ENGINE_ALIASES.get(name.lower(), (name.upper(),))
    probe = bpy.context.scene.render
    current = probe.engine
    for ident in candidates:
        try:
            probe.engine = ident
        except TypeError:
            continue
        probe.engine = current
        return ident
    raise CaptureError(f"unknown render engine {name!r}; choose cycles, eevee or workbench")


def film_filter(scene, engine: str) -> dict:
    """The ``pixel_filter`` field (``contract.film``) of what ``engine`` renders with ``scene``'s settings:
    Cycles' Film > Pixel Filter (type and width); EEVEE's and Workbench's Film > Filter Size, a
    Blackman-Harris filter; none when Workbench renders without anti-aliasing."""
    if engine == "CYCLES":
        return contract.film_filter_field(scene.cycles.pixel_filter_type, scene.cycles.filter_width)
    if engine == "BLENDER_WORKBENCH" and scene.display.render_aa == "OFF":
        return contract.film_filter_field("NONE")
    return contract.film_filter_field("BLACKMAN_HARRIS", scene.render.filter_size)


class RenderView:
    """The scene's render settings seen at the capture's resolution (for intrinsics before rendering)."""

    def __init__(self, render, res_x, res_y):
        self.resolution_x, self.resolution_y = res_x, res_y
        self.resolution_percentage = 100
        self.pixel_aspect_x, self.pixel_aspect_y = render.pixel_aspect_x, render.pixel_aspect_y

"""The "NeRF" render engine: F12, Render Animation and the rendered viewport, through a trained run.

Choose *NeRF* as the render engine and a run folder in Render Properties > NeRF Run. F12 and
Render Animation then render the active camera at the scene's resolution (x percentage) and frame
range into Blender's own render result (Combined pass; the Depth pass when the view layer's Z pass
is on), so the usual output formats, video encoding and compositor apply. Cameras come from
Blender's camera data: the intrinsics from ``cameras.camera_intrinsics`` (the rule the capture
uses: lens, sensor fit, shift, pixel aspect), the pose from ``cameras.scale_free_matrix``.

torch never loads here: cameras go to a ``nerf_core serve`` process (``render_client``) that stays
alive between frames and renders. Colours: the NeRF learned display-referred (sRGB-encoded) values;
they are converted to scene-linear, so that with the Standard view transform the saved PNG holds
exactly the NeRF's values (another view transform would be applied on top; the panel warns).

The viewport (shading mode Rendered) shows a progressive preview: a low-resolution image first, then
finer ones while the view stays still. Requests are asynchronous (a newer view replaces a queued or
running one); a timer polls the process and redraws the 3D views when an image arrives.
"""
from __future__ import annotations

import os
import weakref
from typing import Optional

import bpy
import numpy as np
from bpy.props import IntProperty, PointerProperty, StringProperty

from ..bridge import child_process, render_client, runs
from ..common import prefs
from ..common.ui_common import draw_wrapped, path_options
from ..dataset import cameras
from ..dataset.errors import ExportError

ENGINE_ID = "NERF_BRIDGE"
PREVIEW_LEVELS = (8, 4, 2, 1)  # the viewport preview's downscale factors, coarse to fine
TIMER_INTERVAL_S = 0.05
_PATCHED_PANELS: list = []
_VIEWPORTS: "weakref.WeakSet" = weakref.WeakSet()


# -- settings ---------------------------------------------------------------------------------------
class NerfRenderSettings(bpy.types.PropertyGroup):
    run_dir: StringProperty(
        name="Run", subtype="DIR_PATH", default="", options=path_options(),
        description="Run folder written by `python -m nerf_core train` (has config.json and checkpoints/latest.pt)")
    checkpoint: StringProperty(
        name="Checkpoint", subtype="FILE_PATH", default="", options=path_options(),
        description="Checkpoint to render instead of the run's checkpoints/latest.pt (optional)")
    preview_percentage: IntProperty(
        name="Viewport Resolution", subtype="PERCENTAGE", default=50, min=5, max=100,
        description="Resolution of the finest viewport preview, in percent of the viewport's size")



def _path(path: str) -> str:
    """A run or checkpoint setting as a path: ``//`` is the .blend's folder, ``~`` the home folder (an
    unsaved .blend's ``//`` stays as Blender resolves it, and the run check names it)."""
    return os.path.expanduser(bpy.path.abspath(path))

def settings_problem(scene) -> Optional[str]:
    """Why the scene cannot render through the NeRF (a message for the user), else None."""
    s = scene.nerf_render
    return render_client.run_problem(_path(s.run_dir), _path(s.checkpoint) if s.checkpoint else "")


def colour_warning(scene) -> Optional[str]:
    """A warning when Blender's colour management would change the NeRF's colours on output."""
    vs = scene.view_settings
    if vs.view_transform != "Standard" or vs.look not in ("None", "") or vs.exposure != 0.0 or vs.gamma != 1.0:
        return (f"View transform {vs.view_transform!r} (look {vs.look}, exposure {vs.exposure:g}, gamma {vs.gamma:g}) "
                "is applied on top of the NeRF's colours; use Standard, no look, exposure 0, gamma 1 "
                "to get them as trained")
    return None


def _client_for(scene) -> render_client.RenderClient:
    """The scene's render process (started, or the live one reused). Raises SetupError/RenderClientError."""
    problem = settings_problem(scene)
    if problem:
        raise child_process.SetupError(problem)
    python = child_process.resolve_interpreter(prefs.python_preference() or os.environ.get("NERF_PYTHON", ""))
    s = scene.nerf_render
    return render_client.get_client(python, _path(s.run_dir), _path(s.checkpoint) if s.checkpoint else "")


# -- cameras --------------------------------------------------------------------------------------
def camera_request(cam_obj, render) -> dict:
    """The render request for a Blender camera object at the scene's render settings.

    Intrinsics: ``cameras.camera_intrinsics``, pose: ``cameras.scale_free_matrix`` (one rule each with
    the capture and the camera-path export, so their renders match pixel for pixel). near/far: the camera's
    clip range, as Blender clips.
    """
    intr = cameras.camera_intrinsics(cam_obj, render)
    c2w = cameras.scale_free_matrix(cam_obj)  # the capture's and the camera-path export's rule, bit for bit
    cam = cam_obj.data
    # pixel_filter: a final render draws edge pixels through the capture's film filter, as Cycles did
    # for the images the run learnt from (the viewport's previews keep one ray a pixel, for speed)
    return {"c2w": [[float(v) for v in row] for row in c2w], "fx": intr["fl_x"], "fy": intr["fl_y"],
            "cx": intr["cx"], "cy": intr["cy"], "w": intr["w"], "h": intr["h"],
            "near": float(cam.clip_start), "far": float(cam.clip_end), "pixel_filter": True}


def resolution_problem(render, w: int, h: int) -> Optional[str]:
    """Why a ``w`` x ``h`` px frame (Blender's size: Resolution x %) is too large for the NeRF, naming
    the user's setting; else None."""
    if max(w, h) <= render_client.MAX_SIDE:
        return None
    return (f"Output Properties > Resolution asks for {w}x{h} px ({render.resolution_x}x{render.resolution_y} at "
            f"{render.resolution_percentage}%); the NeRF renders at most {render_client.MAX_SIDE} px a side: lower "
            "Resolution X/Y or the %")


def border_window(render, w: int, h: int) -> Optional[tuple]:
    """The Render Region (border) of a ``w`` x ``h`` frame in pixels, as Blender's pipeline cuts it:
    (x0, y0, width, height) with (x0, y0) its bottom-left pixel, each edge truncated from the border
    fraction times the size in float32, as Blender does; None without a border."""
    if not render.use_border:
        return None
    f = np.float32
    x0, x1 = int(f(render.border_min_x) * f(w)), int(f(render.border_max_x) * f(w))
    y0, y1 = int(f(render.border_min_y) * f(h)), int(f(render.border_max_y) * f(h))
    if x1 <= x0 or y1 <= y0:
        raise ExportError(f"the Render Region covers no pixel of the {w}x{h} px frame: draw a larger region "
                                 "(Ctrl+B in the camera view) or turn Render Region off")
    return x0, y0, x1 - x0, y1 - y0


def crop_request(request: dict, window: tuple) -> dict:
    """``request`` narrowed to the pixels of ``window`` (``border_window``): the same camera, with its
    principal point moved into the crop (rows of a request count from the top, Blender's from the bottom)."""
    x0, y0, bw, bh = window
    top = request["h"] - (y0 + bh)
    return dict(request, cx=request["cx"] - x0, cy=request["cy"] - top, w=bw, h=bh)


def viewport_request(region, rv3d, space, scale: float = 1.0) -> Optional[dict]:
    """The request for what a 3D view shows, at ``scale`` x its size; None for an orthographic view.

    From the view's OpenGL projection P (``window_matrix``): fx = W P00 / 2, cx = W (1 - P02) / 2,
    fy = H P11 / 2, cy = H (1 + P12) / 2 (rows from the top); this includes camera-view zoom and offset.
    """
    if not rv3d.is_perspective:
        return None
    W, H = region.width, region.height
    w, h = max(1, round(W * scale)), max(1, round(H * scale))
    P = rv3d.window_matrix
    sx, sy = w / W, h / H
    c2w = rv3d.view_matrix.inverted()
    if rv3d.view_perspective == "CAMERA" and space.camera is not None:
        near, far = space.camera.data.clip_start, space.camera.data.clip_end
    else:
        near, far = space.clip_start, space.clip_end
    return {"c2w": [[float(v) for v in row] for row in c2w],
            "fx": W * P[0][0] / 2 * sx, "fy": H * P[1][1] / 2 * sy,
            "cx": W * (1 - P[0][2]) / 2 * sx, "cy": H * (1 + P[1][2]) / 2 * sy,
            "w": w, "h": h, "near": float(near), "far": float(far)}


# -- the viewport's asynchronous preview ------------------------------------------------------------
class ViewportState:
    """What one rendered viewport asked for and got (plain Python: the timer may touch it safely)."""

    def __init__(self):
        self.client: Optional[render_client.RenderClient] = None
        self.view_key = None  # the view (matrix, projection, size, settings) the images are for
        self.requests: list = []  # one request per PREVIEW_LEVELS entry, for the current view
        self.pending: Optional[tuple] = None  # (request id, view key, level)
        self.image = None  # (h, w, 4) straight sRGB RGBA of the finest level so far
        self.image_key = None
        self.image_version = 0
        self.level = -1
        self.message: Optional[str] = None

    def want(self, client, key, requests) -> None:
        """The view is ``key``; ``requests`` = one request per PREVIEW_LEVELS entry. Starts the coarsest."""
        if client is not self.client:  # a new process (another run or checkpoint): start over
            self.client, self.view_key, self.pending, self.image = client, None, None, None
        if key == self.view_key:
            return
        self.view_key, self.requests = key, requests
        self._submit(0)

    def _submit(self, level: int) -> None:
        if self.pending is not None and self.client is not None:
            self.client.discard(self.pending[0])
        try:
            rid = self.client.submit(self.requests[level], group="viewport")
        except render_client.RenderClientError as exc:
            self.message, self.pending = str(exc), None
            return
        self.pending = (rid, self.view_key, level)

    def tick(self) -> bool:
        """Poll the process; True when there is something new to draw. Refines while the view is still."""
        if self.pending is None or self.client is None:
            return False
        rid, key, level = self.pending
        try:
            got = self.client.take(rid)
        except render_client.RenderClientError as exc:
            self.pending = None
            if "replaced by a newer one" in str(exc):
                return False
            self.message = str(exc)
            return True
        if got is None:
            return False
        self.pending = None
        self.message = None
        if key == self.view_key:
            self.image, self.image_key, self.level = got[0], key, level
            self.image_version += 1
            if level + 1 < len(PREVIEW_LEVELS):
                self._submit(level + 1)  # the view has not moved since this level was asked for: refine
        return True

    def status(self) -> str:
        if self.message:
            return self.message
        if self.client is not None and self.client.info is None:
            return "NeRF: loading the model"
        if self.pending is not None:
            return f"NeRF: preview {self.pending[2] + 1}/{len(PREVIEW_LEVELS)}"
        return f"NeRF: step {self.client.info.get('step')}" if self.client and self.client.info else "NeRF"


def _viewport_timer() -> float:
    changed = False
    for state in list(_VIEWPORTS):
        try:
            changed |= state.tick()
        except Exception as exc:  # a timer that raises is removed by Blender: keep it alive, show the error
            state.message, state.pending = f"NeRF preview failed: {exc}", None
            changed = True
    if changed:
        for window in getattr(bpy.context.window_manager, "windows", ()):
            for area in window.screen.areas:
                if area.type == "VIEW_3D":
                    area.tag_redraw()
    return TIMER_INTERVAL_S


# -- the engine ---------------------------------------------------------------------------------------
class NerfRenderEngine(bpy.types.RenderEngine):
    bl_idname = ENGINE_ID
    bl_label = "NeRF"
    bl_use_preview = False  # material previews would need a NeRF of the preview scene
    bl_use_postprocess = True  # the compositor and sequencer apply to our render result

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._viewport: Optional[ViewportState] = None
        self._texture = None
        self._texture_version = -1

    def __del__(self):
        # Blender frees the engine object; the state must not outlive it in the timer's set.
        try:
            state = getattr(self, "_viewport", None)
        except ReferenceError:  # Blender removed the engine's RNA first: nothing of ours to free
            return
        if state is not None:
            _VIEWPORTS.discard(state)
            if state.pending is not None and state.client is not None:
                state.client.discard(state.pending[0])

    def update_render_passes(self, scene=None, renderlayer=None):
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", "COLOR")
        if renderlayer.use_pass_z:
            self.register_pass(scene, renderlayer, "Depth", 1, "Z", "VALUE")

    # F12 / Render Animation
    def render(self, depsgraph):
        scene = depsgraph.scene
        cam = self.camera_override or scene.camera
        try:
            if cam is None:
                raise ExportError(f"scene {scene.name!r} has no active camera: set one (Ctrl+Numpad 0)")
            w, h = self.resolution_x, self.resolution_y
            size_problem = resolution_problem(scene.render, w, h)
            if size_problem:
                raise ExportError(size_problem)
            request = camera_request(cam, scene.render)
            if (request["w"], request["h"]) != (w, h):
                raise ExportError(f"camera {cam.name!r}: intrinsics are for {request['w']}x{request['h']} px "
                                         f"but Blender renders {w}x{h} px")
            window = border_window(scene.render, w, h)
            if window is not None:  # Render Region: Blender's result holds the region's pixels only
                request = crop_request(request, window)
            want_depth = bool(depsgraph.view_layer.use_pass_z)
            client = _client_for(scene)
            got = client.render(request, depth=want_depth, should_stop=self.test_break,
                                on_progress=lambda f, text: (self.update_progress(f), self.update_stats("", text)))
        except (child_process.SetupError, render_client.RenderClientError, ExportError) as exc:
            self.report({"ERROR"}, f"NeRF render, frame {scene.frame_current}: {exc}")
            return
        if got is None:  # cancelled (Esc)
            return
        rgba, depth = got
        result = self.begin_result(0, 0, request["w"], request["h"])
        layer = result.layers[0]
        have = len(layer.passes["Combined"].rect)
        if have != request["w"] * request["h"]:
            self.end_result(result, cancel=True)
            self.report({"ERROR"}, f"NeRF render, frame {scene.frame_current}: Blender's result holds {have} "
                                   f"pixels, not the {request['w']}x{request['h']} rendered (an "
                                   f"unusual Render Region?)")
            return
        layer.passes["Combined"].rect = render_client.blender_rect(rgba)
        if depth is not None and "Depth" in layer.passes:
            layer.passes["Depth"].rect = render_client.blender_depth_rect(depth)
        self.end_result(result)
        self.update_progress(1.0)

    # rendered viewport
    def view_update(self, context, depsgraph):
        if self._viewport is not None and depsgraph.id_type_updated("SCENE"):
            self._viewport.view_key = None  # the run or its settings may have changed: ask again

    def view_draw(self, context, depsgraph):
        import gpu  # imported here: the gpu module is unavailable in background mode
        from gpu_extras.presets import draw_texture_2d

        scene = depsgraph.scene
        region, rv3d, space = context.region, context.region_data, context.space_data
        if self._viewport is None:
            self._viewport = ViewportState()
            _VIEWPORTS.add(self._viewport)
        state = self._viewport
        try:
            client = _client_for(scene)
            pct = scene.nerf_render.preview_percentage / 100.0
            requests = [viewport_request(region, rv3d, space, pct / f) for f in PREVIEW_LEVELS]
            if requests[0] is None:
                state.message = "NeRF: the preview needs a perspective view (orthographic views are not rendered)"
            else:
                key = (tuple(map(tuple, rv3d.view_matrix)), tuple(map(tuple, rv3d.window_matrix)),
                       region.width, region.height, pct, client.key)
                state.want(client, key, requests)
        except (child_process.SetupError, render_client.RenderClientError) as exc:
            state.message = f"NeRF: {exc}"
        self.update_stats("", state.status())
        if state.image is None:
            return
        if self._texture_version != state.image_version:
            h, w = state.image.shape[:2]
            pixels = render_client.blender_rect(state.image).ravel()
            self._texture = gpu.types.GPUTexture((w, h), format="RGBA16F",
                                                 data=gpu.types.Buffer("FLOAT", pixels.size, pixels.tolist()))
            self._texture_version = state.image_version
        gpu.state.blend_set("ALPHA_PREMULT")
        self.bind_display_space_shader(scene)
        draw_texture_2d(self._texture, (0, 0), region.width, region.height)
        self.unbind_display_space_shader()
        gpu.state.blend_set("NONE")


# -- UI -----------------------------------------------------------------------------------------------
class NERF_PT_render_run(bpy.types.Panel):
    bl_label = "NeRF Run"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE_ID}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        s = scene.nerf_render
        layout.prop(s, "run_dir")
        layout.prop(s, "checkpoint")
        problem = settings_problem(scene)
        if problem:
            draw_wrapped(layout, problem, "ERROR")
        else:
            info = runs.read_run(_path(s.run_dir))
            if info is not None:
                layout.label(text=f"{info.method or 'method ?'} · {info.metrics_summary()}", icon="CHECKMARK")
        layout.prop(context.view_layer, "use_pass_z", text="Depth Pass (Z)")
        layout.prop(s, "preview_percentage")
        warning = colour_warning(scene)
        if warning:
            draw_wrapped(layout, warning, "INFO")


def _patch_standard_panels(add: bool) -> None:
    """Show Blender's output, format, frame range and colour management panels for this engine too
    (they list the engines they serve in COMPAT_ENGINES)."""
    if add:
        for name in dir(bpy.types):
            cls = getattr(bpy.types, name, None)
            engines = getattr(cls, "COMPAT_ENGINES", None)
            if not isinstance(engines, set) or "BLENDER_WORKBENCH" not in engines or ENGINE_ID in engines:
                continue
            if getattr(cls, "bl_context", "") == "output" or name.startswith("RENDER_PT_color_management") \
                    or name.startswith("RENDER_PT_format") or name.startswith("RENDER_PT_frame_range"):
                engines.add(ENGINE_ID)
                _PATCHED_PANELS.append(cls)
    else:
        for cls in _PATCHED_PANELS:
            cls.COMPAT_ENGINES.discard(ENGINE_ID)
        _PATCHED_PANELS.clear()


def attach() -> None:
    """What registering the classes does not: the settings on every scene, Blender's own panels shown
    for this engine, and the viewport timer."""
    bpy.types.Scene.nerf_render = PointerProperty(type=NerfRenderSettings)
    _patch_standard_panels(True)
    if not bpy.app.timers.is_registered(_viewport_timer):
        bpy.app.timers.register(_viewport_timer, first_interval=TIMER_INTERVAL_S, persistent=True)


def detach() -> None:
    if bpy.app.timers.is_registered(_viewport_timer):
        bpy.app.timers.unregister(_viewport_timer)
    _VIEWPORTS.clear()
    render_client.shutdown_all()  # no render process outlives the add-on
    _patch_standard_panels(False)
    del bpy.types.Scene.nerf_render

"""A capture's plan: the settings checked against the scene, then one frame per camera of the "NeRF
Cameras" collection with its pose, intrinsics and hash (``CapturePlanning.plan``), the same on every
machine of a farm (``frame_plan.make_plan``)."""
from __future__ import annotations

import os

import bpy

from ...bridge.core_contract import contract
from ...dataset import cameras, capture_manifest
from ...dataset.errors import ExportError
from ...scene import camera_checks, scene_appearance, scene_bounds
from ..layout import collection, positions
from . import frame_plan
from .frame_plan import CaptureError
from .notes import capture_notes, clipping_notes, depth_png_notes
from .settings import MAX_RESOLUTION, CaptureSettings, RenderView, film_filter, resolve_engine
from .world import world_description


def scene_box(scene, settings) -> tuple:
    """((min, max), surroundings): the box that the dataset's ``aabb`` and near/far come from.

    The whole scene, except for a capture looking in at a scene whose floor, dome or backdrop dwarfs
    its subject (``scene_bounds.subject_bounds``): then the subject with a margin
    (``scene_bounds.subject_box``), so that the NeRF's grid is spent on it rather than on a 100 m
    floor. A room captured from inside, and a selection, keep the whole scene. A flat box gets some
    thickness (``scene_bounds.with_thickness``).
    """
    lo, hi = scene_bounds.scene_bounds(scene)
    if (settings.layout or {}).get("layout") == "inside" or settings.target == "SELECTION":
        return scene_bounds.with_thickness(lo, hi), []
    s_lo, s_hi, around = scene_bounds.subject_bounds(scene)
    if not around:
        return scene_bounds.with_thickness(lo, hi), []
    return scene_bounds.with_thickness(*scene_bounds.subject_box(scene, s_lo, s_hi)), around


class CapturePlanning:
    """The settings of one capture of ``scene`` into ``settings.out_dir``, checked against the scene
    (``__init__`` raises CaptureError), and its plan (``plan()``): the first part of ``CaptureJob``."""

    def __init__(self, scene, settings: CaptureSettings, progress=None):
        self.scene = scene
        self.s = settings
        self.progress = progress or (lambda done, total, info: None)
        if not settings.out_dir:
            raise CaptureError("no output folder given")
        if settings.out_dir.startswith("//") and not bpy.data.filepath:
            raise CaptureError(f"output folder {settings.out_dir!r} is relative to the .blend, which is not saved yet; "
                               "save the file or choose an absolute folder")
        self.out = os.path.abspath(os.path.expanduser(bpy.path.abspath(settings.out_dir)))  # "~": the home folder
        self.shard = None
        if settings.shard is not None:
            k, n = settings.shard
            try:
                self.shard = frame_plan.parse_shard(f"{k}/{n}")
            except ValueError as exc:
                raise CaptureError(str(exc)) from exc
            if settings.overwrite:
                raise CaptureError("--overwrite cannot go with --shard: shards share the folder and one would delete "
                                   "another's frames; empty the folder once before starting the shards")
        self.engine = resolve_engine(settings.engine)
        if settings.normals and self.engine == "BLENDER_WORKBENCH":
            raise CaptureError("normals need the Cycles or EEVEE engine (Workbench has no normal pass)")
        if not (1 <= settings.res_x <= MAX_RESOLUTION and 1 <= settings.res_y <= MAX_RESOLUTION):
            # Blender clamps at 65536 while the manifest would record the size asked for.
            raise CaptureError(f"resolution {settings.res_x}x{settings.res_y}: each axis must lie in "
                               f"1..{MAX_RESOLUTION} (Blender's limit)")
        if settings.samples < 1:
            raise CaptureError(f"samples must be at least 1 (got {settings.samples})")
        try:
            self.bounds, self.surroundings = scene_box(scene, settings)
        except scene_bounds.BoundsError as exc:
            raise CaptureError(str(exc)) from exc
        self.mask_objects = []
        if settings.masks:
            # Cycles gives an instance the pass index of the object it shows, not its instancer's, and
            # that object often lives in an excluded collection (a linked asset): the objects that the
            # masked instancers show are masked too. One shown by a masked and by an unmasked
            # instancer is masked in both.
            only = settings.target == "SELECTION"
            self.mask_objects = (scene_bounds.renderable_objects(scene, only_selected=only)
                                 + scene_bounds.instanced_objects(scene, only_selected=only))
            if not self.mask_objects:
                raise CaptureError("masks for the selection: nothing visible is selected")
            unseen = scene_bounds.unindexed_pieces(scene, only_selected=only) if self.engine == "CYCLES" else []
            if unseen:
                shown = ", ".join(repr(n) for n in unseen[:5]) + (f" and "
                                                                  f"{len(unseen) - 5} more" if len(unseen) > 5 else "")
                raise CaptureError(
                    f"object masks: Cycles' object index pass never marks {shown}, so every mask would call "
                    "their pixels background and training would ignore them. Capture without masks"
                    + ("" if only else ", or render the masks from the alpha: EEVEE or Workbench "
                                       "with a transparent film"))
            if settings.target == "SELECTION" and self.engine != "CYCLES":
                raise CaptureError("object masks of a selection need Cycles (its object index pass)")
            if not settings.film_transparent and self.engine != "CYCLES":
                # Without Cycles' object index pass the mask is the alpha, which an opaque film makes 1.
                raise CaptureError("object masks with an opaque film need Cycles (its object index pass): "
                                   "EEVEE and Workbench masks come from the alpha, which an opaque "
                                   "film sets everywhere")
        self.notes = capture_notes(scene)
        self.start_frame = scene.frame_current  # views without a frame of their own render at this one
        self.render_sig = None
        self.scene_sig = None  # scene_bounds.scene_signature at plan(): resuming an edited scene is a conflict
        self.appearance_sig = None  # scene_appearance.appearance_signature at plan(): materials, world, lights
        self.world = None
        self.frames = []
        self.plan_doc = None  # frame_plan.make_plan: the JSON plan every shard computes alike
        self.plan_hash = None
        self.share = set()  # keys of the frames this job renders (all, or its shard's)
        self.pending = []
        self.done_keys = set()
        self.file_sha256 = {}  # frame key -> {file key: sha256 of the file as written}
        self.kept = 0
        self._restore = []
        self._started = False
        self._finished = False
        self.status = "idle"

    def _render_signature(self) -> dict:
        sc = self.scene
        vs, ds = sc.view_settings, sc.display_settings
        sig = {
            "engine": self.engine, "samples": self.s.samples, "resolution": [self.s.res_x, self.s.res_y],
            "pixel_aspect": [sc.render.pixel_aspect_x, sc.render.pixel_aspect_y],
            "film_transparent": self.s.film_transparent, "denoise": self.s.denoise,
            "passes": {"depth": self.s.depth, "normals": self.s.normals, "masks": self.s.masks},
            "mask_target": self.s.target if self.s.masks else None,
            "color_management": {
                "display_device": ds.display_device, "view_transform": vs.view_transform, "look": vs.look,
                "exposure": vs.exposure, "gamma": vs.gamma,
                "sequencer_colorspace": sc.sequencer_colorspace_settings.name,
            },
        }
        film = film_filter(sc, self.engine)
        if film != contract.film_filter_field(contract.DEFAULT_FILTER_KIND):
            # Only a filter other than Blender's default is part of the signature, so the hashes of
            # earlier captures (and the folders they resume) stay what they were; the transforms
            # always record it (files.write).
            sig["pixel_filter"] = film
        if not self.s.film_transparent:
            # The world is in every pixel behind the scene. Only opaque captures carry it, so the
            # hashes of transparent captures (and the folders they resume) stay what they were.
            sig["world"] = world_description(sc.world, self.engine)
        return sig

    def plan(self) -> list[dict]:
        """Frames to capture, from the "NeRF Cameras" collection; raises CaptureError on bad cameras."""
        cams = collection.capture_cameras(self.scene)
        if not cams["train"]:
            raise CaptureError(f"no train cameras in the {positions.COLLECTION_NAME!r} collection; "
                               "generate a camera layout first")
        self.render_sig = self._render_signature()
        self.scene_sig = scene_bounds.scene_signature(self.scene)
        self.appearance_sig = scene_appearance.appearance_signature(self.scene)
        self.world = world_description(self.scene.world, self.engine)
        # Intrinsics use the capture resolution, not the scene's: compute on a stand-in render struct.
        render = RenderView(self.scene.render, self.s.res_x, self.s.res_y)
        frames = []
        with scene_bounds.fresh_matrices(self.scene, [o for split in positions.SPLITS for o in cams[split]]):
            self._plan_frames(cams, render, frames)
        self.frames = frames
        # Legal, and written exactly, but some peer loaders misplace these views: say so before rendering.
        self.notes += [msg for _, msg in contract.angle_only_caveats([fr["intrinsics"] for fr in frames])]
        self.notes += clipping_notes(frames, self.bounds)
        if self.s.depth:
            self.notes += depth_png_notes(frames, self.bounds)
        if any(fr["frame"] is not None for fr in frames):
            # Views at their own frames (the animation layout): the scene at the current frame is not
            # what they show, and resuming at another frame must not look like an edit.
            self.scene_sig = None
        self.plan_doc = frame_plan.make_plan(frames, settings=self.s, render_sig=self.render_sig, world=self.world,
                                               bounds=self.bounds, scene_name=self.scene.name,
                                               blender_version=bpy.app.version_string,
                                               surroundings=self.surroundings)
        self.plan_hash = frame_plan.plan_hash(self.plan_doc)
        own = frame_plan.shard_frames(frames, *self.shard) if self.shard else frames
        self.share = {fr["key"] for fr in own}
        return frames

    def _plan_frames(self, cams: dict, render, frames: list) -> None:
        """Append a frame dict per camera of ``cams`` to ``frames`` (inside ``fresh_matrices``)."""
        for split in positions.SPLITS:
            for k, obj in enumerate(cams[split]):
                err = camera_checks.camera_scale_error(obj)
                scale_removed = None
                if err:
                    if not self.s.normalize_camera_scale or camera_checks.camera_shape_error(obj):
                        raise CaptureError(err)
                    scale_removed = [round(c.length, 6) for c in (obj.matrix_world.col[i].xyz for i in range(3))]
                try:
                    intr = cameras.camera_intrinsics(obj, render)
                except ExportError as exc:
                    raise CaptureError(str(exc)) from exc
                c2w = [[float(v) for v in row] for row in cameras.scale_free_matrix(obj)]
                frame = obj.get("nerf_frame")
                fr = {
                    "index": len(frames), "key": f"{split}/r_{k}", "split": split, "name": f"r_{k}",
                    "camera": obj.name, "transform_matrix": c2w, "intrinsics": intr,
                    "frame": int(frame) if frame is not None else None, "scale_removed": scale_removed,
                }
                fr["hash"] = frame_plan.stable_hash({"render": self.render_sig, "c2w": c2w, "intr": intr,
                                                       "frame": fr["frame"]})
                fr.update(frame_plan.frame_files(split, fr["name"], self.s.depth, self.s.normals, self.s.masks,
                                                   self.s.points, capture_manifest.MANIFEST_DIR))
                frames.append(fr)

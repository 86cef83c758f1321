"""Render the cameras of the "NeRF Cameras" collection into a NeRF dataset folder.

``CaptureJob`` is the one engine behind the panel's modal operator (one ``step()`` per timer tick)
and ``scripts/capture.py`` (a loop). It never imports nerf_core: progress goes through a callback
``progress(done, total, info)``.

Safety rules it enforces:
- A folder holding anything else (or a capture whose frames differ) is refused unless
  ``overwrite``; overwrite deletes only the dataset's own paths (``DATASET_PATHS``).
- Frames are written under a temporary name and renamed, so a frame file is whole or absent.
- Resume: a frame whose settings hash (render settings + camera pose + intrinsics) is in the
  manifest (or a shard's state) and whose files are the ones written is kept, not re-rendered.
- Cancel (or an error) writes the JSON of the frames done so far; the manifest says "incomplete".
- The background is recorded: ``film_transparent`` and ``world`` (``world_description``) at the top
  of the manifest and of every transforms file. With an opaque film the world is part of the
  picture, so it joins the render signature (and the frame hashes): a changed world re-renders.
- The user's render settings, active camera and frame are restored afterwards.

Sharded (``settings.shard = (K, N)``, a render farm): the job renders only shard K's share of the
plan (``capture_plan``) and records it in its own state file (``capture_shards``); it writes no
manifest, transforms file or point cloud: ``capture_merge`` does, once every shard is done.
"""
from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from . import capture_plan, capture_render, capture_shards, capture_verify, capture_write, layouts
from . import camera_collection
from ..scene import camera_checks
from ..dataset import aabb, cameras, capture_manifest, transforms
from ..dataset.errors import ExportError
from ..scene import passes
from ..scene import scene_appearance, scene_bounds, scene_files
from .capture_plan import CaptureError
from ..bridge.core_contract import contract
from .capture_world import world_description  # noqa: F401  (public: the panel and tests describe worlds)

ENGINE_ALIASES = {
    "cycles": ("CYCLES",),
    "eevee": ("BLENDER_EEVEE_NEXT", "BLENDER_EEVEE"),  # 4.2-4.4 call it EEVEE Next; 5.0 BLENDER_EEVEE
    "workbench": ("BLENDER_WORKBENCH",),
}
# Paths a capture owns inside its folder; the only ones --overwrite removes.
DATASET_PATHS = ("train", "val", "test", "depth", "normals", "masks", "points3d.ply", "transforms.json",
                 "transforms_train.json", "transforms_val.json", "transforms_test.json", capture_manifest.MANIFEST_DIR,
                 transforms.NERFSTUDIO_DIR)
FORMAT = capture_write.FORMAT


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
    shard: tuple | None = None  # (K, N), 1 <= K <= N: render only shard K's share (capture_plan)


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


def _empty_tree(path: str) -> bool:
    """True for a folder holding nothing but (nested) empty folders."""
    if not os.path.isdir(path) or os.path.islink(path):
        return False
    return all(_empty_tree(os.path.join(path, e)) for e in os.listdir(path))


def _box_depths(fr: dict, corners: np.ndarray) -> tuple[float, float]:
    """(nearest, farthest) planar depth of the box ``corners`` (8, 3) along a planned frame's view axis
    (the camera looks down -Z); negative where a corner is behind the camera."""
    c2w = np.asarray(fr["transform_matrix"], float)
    depths = -(corners - c2w[:3, 3]) @ c2w[:3, 2]
    return float(depths.min()), float(depths.max())


def clipping_notes(frames: list, bounds) -> list:
    """A warning when cameras' clipping planes cut into the scene box (empty when none).

    Generated layouts set clipping to fit the box (``layout_cameras.create_cameras``); cameras the user set
    up keep theirs, and a clip_end short of the far side (or a clip_start beyond the near side of a
    box in front of the camera) leaves part of the scene out of some pictures only: views that
    disagree about what is there, which a radiance field turns into floaters or holes. The planes are
    the user's choice (clipping into a room is a way to look inside), so this is said, not changed.
    """
    if bounds is None:
        return []
    corners = aabb.box_corners(*bounds)
    cut = []
    for fr in frames:
        obj = bpy.data.objects.get(fr["camera"])
        if obj is None or obj.type != "CAMERA":
            continue
        near, far = _box_depths(fr, corners)
        if far <= 0:
            continue  # the box is behind this camera
        start, end = obj.data.clip_start, obj.data.clip_end
        if end < far or (near > 0 and start > near):
            cut.append((obj.name, start, end, max(near, 0.0), far))
    if not cut:
        return []
    name, start, end, near, far = cut[0]
    return [f"{len(cut)} camera(s) clip the scene box, e.g. {name!r}: clip {start:g}-{end:g}, the box lies "
            f"{near:.3g}-{far:.3g} away along its view; parts of the scene will be missing from some views "
            "only, which a NeRF learns as holes or floaters. Widen Clip Start/End (Camera properties) unless "
            "the cut is meant"]


def capture_notes(scene) -> list:
    """Warnings about what the scene will render that no radiance field can learn (empty when none);
    the panel reports them and ``scripts/capture.py`` prints them before rendering."""
    notes = scene_files.missing_file_notes(scene)
    held = scene_bounds.holdout_objects(scene)
    if not held:
        return notes
    shown = ", ".join(repr(n) for n in held[:5]) + (f" and {len(held) - 5} more" if len(held) > 5 else "")
    return notes + [f"{shown} render(s) as holdout: a holdout cuts a transparent hole (alpha 0) through everything "
            "behind it, blocking what lies behind yet adding no opacity, which a radiance field cannot represent, "
            "so the NeRF will show gaps or fog there. Turn Holdout off for the capture (object or collection "
            "visibility, or the material's Holdout shader), or leave them out of the render"]


# Fewer millimetre levels than this across the scene make a depth map of a few steps.
NERFSTUDIO_DEPTH_MIN_LEVELS = 256


def depth_png_notes(frames: list, bounds) -> list:
    """A warning when the scene box lies (partly) where nerfstudio's millimetre depth PNGs cannot
    hold it: farther than 65.535 units from a camera (written as 0, no depth) or so close and small
    that its depth takes under 256 millimetre steps. The EXR depth maps hold every depth; only the
    PNGs under nerfstudio/depth/ are affected."""
    if bounds is None or not frames:
        return []
    corners = aabb.box_corners(*bounds)
    far = max(_box_depths(fr, corners)[1] for fr in frames)
    top = passes.MAX_DEPTH_MM / 1000.0
    if far > top:
        return [f"the scene box reaches {far:.4g} units from the cameras, but nerfstudio's depth PNGs hold "
                f"millimetres in 16 bits (up to {top:g} units): depth farther away is written there as 0 (no "
                "depth), so nerfstudio learns no depth for it (the EXR depth maps keep all of it). Scale the "
                "scene down for nerfstudio's depth supervision"]
    levels = far * 1000.0
    if levels < NERFSTUDIO_DEPTH_MIN_LEVELS:
        return [f"the scene box lies within {far:.3g} units of the cameras: nerfstudio's millimetre depth PNGs "
                f"hold its depth in at most {max(int(levels), 0)} steps (the EXR depth maps keep full precision). "
                "Scale the scene up for nerfstudio's depth supervision"]
    return []


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


class CaptureJob:
    """One capture of ``scene`` into ``settings.out_dir``: ``prepare()``, ``step()`` until False, ``finish()``.

    ``run()`` does all three; ``cancel()`` stops early leaving a consistent, resumable folder.
    """

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
                self.shard = capture_plan.parse_shard(f"{k}/{n}")
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
                shown = ", ".join(repr(n) for n in unseen[:5]) + (f" and {len(unseen) - 5} more" if len(unseen) > 5 else "")
                raise CaptureError(
                    f"object masks: Cycles' object index pass never marks {shown}, so every mask would call "
                    "their pixels background and training would ignore them. Capture without masks"
                    + ("" if only else ", or render the masks from the alpha: EEVEE or Workbench with a transparent film"))
            if settings.target == "SELECTION" and self.engine != "CYCLES":
                raise CaptureError("object masks of a selection need Cycles (its object index pass)")
            if not settings.film_transparent and self.engine != "CYCLES":
                # Without Cycles' object index pass the mask is the alpha, which an opaque film makes 1.
                raise CaptureError("object masks with an opaque film need Cycles (its object index pass): "
                                   "EEVEE and Workbench masks come from the alpha, which an opaque film sets everywhere")
        self.notes = capture_notes(scene)
        self.start_frame = scene.frame_current  # views without a frame of their own render at this one
        self.render_sig = None
        self.scene_sig = None  # scene_bounds.scene_signature at plan(): resuming an edited scene is a conflict
        self.appearance_sig = None  # scene_appearance.appearance_signature at plan(): materials, world, lights
        self.world = None
        self.frames = []
        self.plan_doc = None  # capture_plan.make_plan: the JSON plan every shard computes alike
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

    # ------------------------------------------------------------------ planning

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
            # always record it (capture_write).
            sig["pixel_filter"] = film
        if not self.s.film_transparent:
            # The world is in every pixel behind the scene. Only opaque captures carry it, so the
            # hashes of transparent captures (and the folders they resume) stay what they were.
            sig["world"] = world_description(sc.world, self.engine)
        return sig

    def plan(self) -> list[dict]:
        """Frames to capture, from the "NeRF Cameras" collection; raises CaptureError on bad cameras."""
        cams = camera_collection.capture_cameras(self.scene)
        if not cams["train"]:
            raise CaptureError(f"no train cameras in the {layouts.COLLECTION_NAME!r} collection; "
                               "generate a camera layout first")
        self.render_sig = self._render_signature()
        self.scene_sig = scene_bounds.scene_signature(self.scene)
        self.appearance_sig = scene_appearance.appearance_signature(self.scene)
        self.world = world_description(self.scene.world, self.engine)
        # Intrinsics use the capture resolution, not the scene's: compute on a stand-in render struct.
        render = RenderView(self.scene.render, self.s.res_x, self.s.res_y)
        frames = []
        with scene_bounds.fresh_matrices(self.scene, [o for split in layouts.SPLITS for o in cams[split]]):
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
        self.plan_doc = capture_plan.make_plan(frames, settings=self.s, render_sig=self.render_sig, world=self.world,
                                               bounds=self.bounds, scene_name=self.scene.name,
                                               blender_version=bpy.app.version_string,
                                               surroundings=self.surroundings)
        self.plan_hash = capture_plan.plan_hash(self.plan_doc)
        own = capture_plan.shard_frames(frames, *self.shard) if self.shard else frames
        self.share = {fr["key"] for fr in own}
        return frames

    def _plan_frames(self, cams: dict, render, frames: list) -> None:
        """Append a frame dict per camera of ``cams`` to ``frames`` (inside ``fresh_matrices``)."""
        for split in layouts.SPLITS:
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
                c2w = [[float(v) for v in row] for row in obj.matrix_world.normalized()]
                frame = obj.get("nerf_frame")
                fr = {
                    "index": len(frames), "key": f"{split}/r_{k}", "split": split, "name": f"r_{k}",
                    "camera": obj.name, "transform_matrix": c2w, "intrinsics": intr,
                    "frame": int(frame) if frame is not None else None, "scale_removed": scale_removed,
                }
                fr["hash"] = capture_plan.stable_hash({"render": self.render_sig, "c2w": c2w, "intr": intr,
                                                       "frame": fr["frame"]})
                fr.update(capture_plan.frame_files(split, fr["name"], self.s.depth, self.s.normals, self.s.masks,
                                                   self.s.points, capture_manifest.MANIFEST_DIR))
                frames.append(fr)

    # ------------------------------------------------------------------ folder checks

    def inspect_folder(self) -> tuple[dict | None, str | None]:
        """(manifest to resume from, conflict message) without touching the disk.

        The conflict message is set when the folder holds something a capture would overwrite:
        foreign files, a capture whose frames differ, or shards planned with other settings.
        ``overwrite`` makes it proceed anyway (shards never overwrite).
        """
        if not self.frames:
            self.plan()
        out = self.out
        if os.path.exists(out) and not os.path.isdir(out):
            raise CaptureError(f"output {out} exists and is not a folder")
        if not os.path.isdir(out):
            return None, None
        # Empty folders hold nothing to overwrite; a concurrent shard makes its frame folders a moment
        # before its state file, and must not look like foreign content to the others.
        entries = sorted(e for e in os.listdir(out) if e != capture_manifest.MANIFEST_DIR and not _empty_tree(os.path.join(out, e)))
        try:
            manifest = capture_manifest.read_manifest(out)
            states = capture_shards.read_states(out, capture_manifest.MANIFEST_DIR)
        except (ExportError, CaptureError) as exc:
            return None, str(exc)
        if manifest is not None and manifest.get("format") != FORMAT:
            manifest = None
        conflict = capture_shards.conflict(out, capture_manifest.MANIFEST_DIR, self.plan_doc, self.plan_hash, self.shard,
                                           manifest, states)
        if conflict:
            return manifest, conflict
        if manifest is None:
            if entries and not states:
                shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
                # Say what an overwrite deletes: the dataset's own names (DATASET_PATHS), whoever wrote them.
                doomed = [e for e in entries if e in DATASET_PATHS]
                fate = (f"overwrite deletes {', '.join(doomed)} (the dataset's names) and keeps the rest" if doomed
                        else "overwrite keeps all of it")
                return None, (f"output folder {out} is not empty and holds no capture of ours ({shown}); "
                              f"choose an empty folder or confirm overwrite (--overwrite): {fate}")
            return None, None
        old = manifest.get("frames", {})
        new = {f["key"]: f["hash"] for f in self.frames}
        recorded = manifest.get("scene_signature")
        if recorded and self.scene_sig and recorded != self.scene_sig and any(v.get("done") for v in old.values()):
            # Frame hashes cover the cameras and render settings, not the scene: resuming would keep
            # pictures of the scene as it was beside a box and near/far computed for it as it is.
            return manifest, (f"output folder {out} holds frames of this scene as it was before it changed (objects "
                              "added, removed, moved or edited since); choose another folder or confirm overwrite "
                              "(--overwrite) to render them again")
        differing = sorted(k for k, v in old.items() if new.get(k) != v.get("hash"))
        if differing:
            same_render = manifest.get("render") == capture_plan.round6(self.render_sig)
            reason = "cameras changed" if same_render else "render settings changed"
            return manifest, (f"output folder {out} holds a different capture ({reason}: {len(differing)} of "
                              f"{len(old)} frames differ, e.g. {differing[0]}); choose another folder or "
                              "confirm overwrite (--overwrite)")
        # After the frame hashes, whose message is more precise: an opaque film's world is in them.
        looked = manifest.get("appearance_signature")  # absent in captures made before it was recorded
        if looked and self.appearance_sig and looked != self.appearance_sig and any(v.get("done") for v in old.values()):
            return manifest, (f"output folder {out} holds frames of this scene as it looked before it changed "
                              "(materials, world or lights edited since); choose another folder or confirm "
                              "overwrite (--overwrite) to render them again")
        return manifest, None

    def _check_folder(self) -> dict | None:
        """Make the folder usable; returns the existing manifest to resume from (or None)."""
        manifest, conflict = self.inspect_folder()
        if conflict and (self.shard or not self.s.overwrite):
            raise CaptureError(conflict)
        try:
            os.makedirs(os.path.join(self.out, capture_manifest.MANIFEST_DIR), exist_ok=True)
            probe = os.path.join(self.out, capture_manifest.MANIFEST_DIR, f".write_probe.{capture_shards.unique_suffix()}")
            with open(probe, "w") as fh:
                fh.write("ok")
            os.remove(probe)
        except OSError as exc:
            raise CaptureError(f"output folder {self.out} is not writable: {exc.strerror or exc}") from exc
        if self.s.overwrite and not self.shard:
            self._delete_dataset()
            return None
        return manifest

    def _delete_dataset(self) -> None:
        for rel in DATASET_PATHS:
            path = os.path.join(self.out, rel)
            if os.path.isdir(path):
                shutil.rmtree(path)
            elif os.path.exists(path):
                os.remove(path)
        os.makedirs(os.path.join(self.out, capture_manifest.MANIFEST_DIR), exist_ok=True)

    # ------------------------------------------------------------------ lifecycle

    def prepare(self) -> int:
        """Validate, choose the frames still to render, apply render settings; returns how many remain."""
        if not self.frames:
            self.plan()
        manifest = self._check_folder()
        kept = set()
        self.file_sha256 = {}
        records = capture_shards.done_records(self.out, capture_manifest.MANIFEST_DIR, self.frames, self.plan_hash, manifest)
        for key, rec in records.items():
            fr = next((f for f in self.frames if f["key"] == key), None)
            if fr is None or key not in self.share or rec["hash"] != fr["hash"]:
                continue
            if capture_verify.frame_problem(self.out, fr, rec["sha256"], self.s.res_x, self.s.res_y) is None:
                kept.add(key)
                # a manifest from before per-file hashes: record them now that the files check out
                self.file_sha256[key] = dict(rec["sha256"]) if rec["sha256"] else capture_verify.file_hashes(self.out, fr)
        self.done_keys = set(kept)
        self.kept = len(kept)
        self.pending = [fr for fr in self.frames if fr["key"] in self.share and fr["key"] not in kept]
        for rel in {os.path.dirname(v) for fr in self.frames for k, v in fr.items()
                    if k in capture_verify.FRAME_FILE_KEYS}:
            os.makedirs(os.path.join(self.out, rel), exist_ok=True)
        self.blend_sha256 = capture_verify.sha256_file(bpy.data.filepath)
        self.created = (manifest or {}).get("created") or time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        self._apply_settings()
        self._started = True
        self.status = "incomplete"
        self._write_record()
        self.progress(len(self.done_keys), len(self.share), f"resuming: {self.kept} kept" if self.kept else "")
        return len(self.pending)

    def _set(self, owner, attr, value) -> None:
        self._restore.append((owner, attr, getattr(owner, attr)))
        setattr(owner, attr, value)

    def _apply_settings(self) -> None:
        sc, r = self.scene, self.scene.render
        self._set(r, "engine", self.engine)
        self._set(r, "resolution_x", self.s.res_x)
        self._set(r, "resolution_y", self.s.res_y)
        self._set(r, "resolution_percentage", 100)
        self._set(r, "film_transparent", self.s.film_transparent)
        self._set(r, "use_border", False)
        self._set(r, "use_compositing", False)  # a user's compositor must not alter the dataset
        self._set(r, "use_sequencer", False)
        self._set(r, "use_motion_blur", False)  # a NeRF needs a static instant per view
        # ... and one eye: stereoscopy renders a left and a right image per view, which neither saves
        # as the one PNG a frame names nor matches the frame's single pose.
        self._set(r, "use_multiview", False)
        # ... and a pinhole: depth of field blurs each view by its own focus, which no radiance field
        # reproduces (a scene or animation camera copied by the layout keeps the user's setting).
        for name in {f["camera"] for f in self.frames}:
            obj = bpy.data.objects.get(name)
            if obj is not None and obj.type == "CAMERA" and obj.data.dof.use_dof:
                self._set(obj.data.dof, "use_dof", False)
        self._set(r, "use_single_layer", True)  # one view layer: the one whose passes we enable
        if self.engine == "CYCLES":
            self._set(sc.cycles, "samples", self.s.samples)
            self._set(sc.cycles, "use_denoising", self.s.denoise)
            self._set(sc.cycles, "use_adaptive_sampling", False)
        elif self.engine.startswith("BLENDER_EEVEE"):
            self._set(sc.eevee, "taa_render_samples", self.s.samples)
        vl = scene_bounds.render_view_layer(sc)
        self.view_layer = vl
        # The layer the bounds, framing and masks were read from must be the one rendered and saved.
        # use_single_layer is ignored in background mode: every layer used for rendering renders and
        # the first is saved, so a file whose active layer had "Use for Rendering" off gave pictures of
        # another layer (or, with no other, none and a failed save). Only this layer is used.
        for layer in sc.view_layers:
            self._set(layer, "use", layer == vl)
        want_passes = self.s.depth or self.s.points
        self._set(vl, "use_pass_z", bool(want_passes) or vl.use_pass_z)
        if self.engine != "BLENDER_WORKBENCH":
            # the point cloud's normals come from the Normal pass where the engine has one
            self._set(vl, "use_pass_normal", self.s.normals or self.s.points or vl.use_pass_normal)
        if self.s.masks and self.engine == "CYCLES":
            self._set(vl, "use_pass_object_index", True)
            masked = {o.as_pointer() for o in self.mask_objects}
            everything = {o.as_pointer(): o for o in scene_bounds.renderable_objects(sc, vl)
                          + scene_bounds.instanced_objects(sc, vl)}
            for ptr, obj in everything.items():
                self._set(obj, "pass_index", 1 if ptr in masked else 0)
        self._set(sc, "camera", sc.camera)
        self._set(sc, "frame_current", sc.frame_current)
        img = r.image_settings
        # Restored in reverse: the media type first (setting it resets the format), then the format,
        # then what the format allows. The other way round, a JPEG or EXR output came back as PNG.
        for attr in ("compression", "use_exr_interleave", "exr_codec", "color_depth", "color_mode", "file_format",
                     "media_type"):
            if hasattr(img, attr):
                self._restore.append((img, attr, getattr(img, attr)))
        # Cameras bound to timeline markers take over the scene camera at every render: each view
        # would show the marker's camera while its pose says otherwise.
        for marker in sc.timeline_markers:
            if marker.camera is not None:
                self._set(marker, "camera", None)

    def _restore_settings(self) -> None:
        for owner, attr, value in reversed(self._restore):
            try:
                setattr(owner, attr, value)
            except (AttributeError, TypeError, ReferenceError):
                pass  # an object deleted meanwhile has nothing to restore
        self._restore = []
        if self.scene.frame_current is not None:
            self.scene.frame_set(self.scene.frame_current)

    def _needs_passes(self) -> bool:
        return self.s.depth or self.s.normals or self.s.masks or self.s.points

    def step(self) -> bool:
        """Render the next pending frame; returns True while frames remain."""
        if not self.pending:
            return False
        fr = self.pending[0]
        obj = bpy.data.objects.get(fr["camera"])
        if obj is None:
            raise CaptureError(f"camera {fr['camera']!r} was deleted during the capture")
        sc = self.scene
        sc.camera = obj
        # Every view renders at its planned frame, or the one the capture started at: while the panel
        # captures, the user may scrub or play the timeline.
        frame = fr["frame"] if fr["frame"] is not None else self.start_frame
        if sc.frame_current != frame:
            sc.frame_set(frame)
        try:
            capture_render.render_still()
        except RuntimeError as exc:  # Blender's own refusal, e.g. "Failed to allocate GPU buffers"
            reason = str(exc).replace("Error: ", "").strip()
            raise CaptureError(f"{fr['key']}: Blender could not render this view at {self.s.res_x}x{self.s.res_y} px "
                               f"with {self.engine} ({reason}); a lower resolution may fit. The frames rendered so "
                               "far are kept, and capturing again resumes") from exc
        result = bpy.data.images["Render Result"]
        capture_render.save_png(sc, result, os.path.join(self.out, fr["image"]))
        if self._needs_passes():
            n_train = sum(f["split"] == "train" for f in self.frames)
            capture_render.save_passes(sc, result, fr, self.out, self.s, self.engine,
                                       os.path.join(self.out, capture_manifest.MANIFEST_DIR),
                                       max(1, self.s.n_points // max(1, n_train)))
        self.file_sha256[fr["key"]] = capture_verify.file_hashes(self.out, fr)
        self.pending.pop(0)
        self.done_keys.add(fr["key"])
        self._write_record()
        self.progress(len(self.done_keys), len(self.share), fr["key"])
        return bool(self.pending)

    def finish(self) -> dict:
        """Write the JSON (and point cloud), mark the manifest complete, restore settings.

        A shard writes only its state file ("done" when its share is): the merge writes the rest."""
        try:
            if self.shard:
                self.status = "done" if not self.pending else "incomplete"
                self._write_record()
            else:
                self._write_dataset(complete=not self.pending)
        finally:
            self._restore_settings()
            self._finished = True
        return self.summary()

    def cancel(self) -> dict:
        """Stop now: JSON for the frames done, manifest "incomplete", settings restored; resumable."""
        if self._started and not self._finished:
            try:
                folder = os.path.join(self.out, capture_manifest.MANIFEST_DIR)
                mine = capture_shards.unique_suffix()
                for name in os.listdir(folder):
                    # a shard removes only its own leftovers: the others may be writing theirs
                    if capture_render.PARTIAL_TAG in name and (not self.shard or mine in name):
                        os.remove(os.path.join(folder, name))
                if self.shard:
                    self._write_record()
                else:
                    self._write_dataset(complete=False)
            finally:
                self._restore_settings()
                self._finished = True
        return self.summary()

    def run(self) -> dict:
        """prepare + step until done + finish; Ctrl+C and errors leave a resumable folder."""
        self.prepare()
        try:
            while self.step():
                pass
        except BaseException:
            self.cancel()
            raise
        return self.finish()

    def summary(self) -> dict:
        out = {"out": self.out, "status": self.status, "frames": len(self.share),
               "rendered": len(self.done_keys) - self.kept, "kept": self.kept,
               "pending": len(self.pending)}
        if self.shard:
            out.update(shard=f"{self.shard[0]}/{self.shard[1]}", planned=len(self.frames), plan_hash=self.plan_hash)
        return out

    # ------------------------------------------------------------------ writing

    def _manifest_info(self) -> dict:
        return {"created": self.created, "blend_file": bpy.data.filepath or None, "blend_sha256": self.blend_sha256,
                "blend_unsaved_changes": bool(bpy.data.is_dirty), "plan_hash": self.plan_hash,
                "scene_signature": self.scene_sig, "appearance_signature": self.appearance_sig,
                "file_sha256": {k: v for k, v in self.file_sha256.items() if k in self.done_keys}}

    def _write_dataset(self, complete: bool) -> None:
        self.status = "complete" if complete else "incomplete"
        self.near, self.far = capture_write.write_dataset(self.out, self.plan_doc, self.done_keys, complete,
                                                          self._manifest_info())

    def _write_record(self) -> None:
        """After each frame: the manifest (one machine) or this shard's own state file (a farm)."""
        if not self.shard:
            capture_manifest.write_manifest(self.out, capture_write.manifest(
                self.plan_doc, self.done_keys, dict(self._manifest_info(), status=self.status,
                                                    near=getattr(self, "near", None), far=getattr(self, "far", None))))
            return
        k, n = self.shard
        state = {"format": FORMAT, "shard": k, "shards": n, "status": self.status, "hash": self.plan_hash,
                 "assignment": capture_plan.SHARD_ASSIGNMENT, "plan": self.plan_doc,
                 "manifest_info": {key: v for key, v in self._manifest_info().items() if key != "file_sha256"},
                 "done": {key: self.file_sha256[key] for key in sorted(self.done_keys) if key in self.file_sha256}}
        capture_shards.write_state(capture_shards.state_path(self.out, capture_manifest.MANIFEST_DIR, k, n), state)


class RenderView:
    """The scene's render settings seen at the capture's resolution (for intrinsics before rendering)."""

    def __init__(self, render, res_x, res_y):
        self.resolution_x, self.resolution_y = res_x, res_y
        self.resolution_percentage = 100
        self.pixel_aspect_x, self.pixel_aspect_y = render.pixel_aspect_x, render.pixel_aspect_y

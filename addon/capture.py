"""Render the cameras of the "NeRF Cameras" collection into a NeRF dataset folder.

``CaptureJob`` is the one engine behind the panel's modal operator (one ``step()`` per timer tick)
and ``scripts/capture.py`` (a loop). It never imports nerf_core: progress goes through a callback
``progress(done, total, info)``.

Safety rules it enforces:
- A folder holding anything else (or a capture whose frames differ) is refused unless
  ``overwrite``; overwrite deletes only the dataset's own paths (``DATASET_PATHS``).
- Frames are written under a temporary name and renamed, so a frame file is whole or absent.
- Resume: a frame whose settings hash (render settings + camera pose + intrinsics) is in the
  manifest and whose files exist is kept, not re-rendered.
- Cancel (or an error) writes the JSON of the frames done so far; the manifest says "incomplete".
- The background is recorded: ``film_transparent`` and ``world`` (``world_description``) at the top
  of the manifest and of every transforms file. With an opaque film the world is part of the
  picture, so it joins the render signature (and the frame hashes): a changed world re-renders.
- The user's render settings, active camera and frame are restored afterwards.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from . import export, layouts, passes, scene_bounds

ENGINE_ALIASES = {
    "cycles": ("CYCLES",),
    "eevee": ("BLENDER_EEVEE_NEXT", "BLENDER_EEVEE"),  # 4.2-4.4 call it EEVEE Next; 5.0 BLENDER_EEVEE
    "workbench": ("BLENDER_WORKBENCH",),
}
# Paths a capture owns inside its folder; the only ones --overwrite removes.
DATASET_PATHS = ("train", "val", "test", "depth", "normals", "masks", "points3d.ply", "transforms.json",
                 "transforms_train.json", "transforms_val.json", "transforms_test.json", export.MANIFEST_DIR)
FORMAT = "nerf_bridge_capture"


MAX_RESOLUTION = 65536  # Blender's largest render resolution per axis


class CaptureError(RuntimeError):
    """A capture cannot start or continue; the message names the file, camera or setting."""


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


def _round_color(values) -> list[float]:
    return [round(float(v), 6) for v in list(values)[:3]]


def _linked_from(socket):
    """The node feeding ``socket`` (through reroutes), or None when it is not linked."""
    while socket is not None and socket.is_linked:
        link = socket.links[0]
        if not link.is_valid or link.is_muted:
            return None
        node = link.from_node
        if node.type != "REROUTE":
            return node
        socket = node.inputs[0]
    return None


def _background_node(node, depth=0):
    """The Background node behind a world's Surface: itself, or the first one inside mix/add shaders."""
    if node is None or depth > 8:
        return None
    if node.type == "BACKGROUND":
        return node
    if node.type in ("MIX_SHADER", "ADD_SHADER"):
        for sock in node.inputs:
            if sock.type == "SHADER":
                found = _background_node(_linked_from(sock), depth + 1)
                if found is not None:
                    return found
    return None


def world_description(world) -> dict:
    """What the scene's world shows behind everything (what an opaque film renders), as JSON.

    ``{"name", "kind", "image", "color", "strength"}`` with ``kind`` one of:
    ``environment_texture`` (``image``: the image file's name), ``sky_texture``, ``color`` (``color``:
    linear RGB), ``other`` (a Background fed by other nodes, or a surface that is not a Background),
    ``none`` (no world, or nothing linked to the World Output: renders black). ``strength`` is the
    Background's Strength (null when driven by a link). The World Output is the active one.
    """
    out = {"name": world.name if world is not None else None, "kind": "none", "image": None, "color": None,
           "strength": None}
    if world is None:
        return out
    tree = world.node_tree
    if tree is None or (bpy.app.version < (5, 0, 0) and not world.use_nodes):  # 5.0 worlds always use nodes
        out.update(kind="color", color=_round_color(world.color), strength=1.0)
        return out
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_WORLD"]
    active = [n for n in outputs if n.is_active_output] or outputs
    if not active:
        return out
    surface = _linked_from(active[0].inputs["Surface"])
    bg = _background_node(surface)
    if bg is None:
        if surface is not None:
            out["kind"] = "other"
        return out
    strength = bg.inputs["Strength"]
    out["strength"] = None if strength.is_linked else round(float(strength.default_value), 6)
    color_in = bg.inputs["Color"]
    src = _linked_from(color_in)
    if not color_in.is_linked:
        out.update(kind="color", color=_round_color(color_in.default_value))
    elif src is not None and src.type == "TEX_ENVIRONMENT":
        image = src.image
        name = None
        if image is not None:
            name = os.path.basename(bpy.path.abspath(image.filepath)) if image.filepath else image.name
        out.update(kind="environment_texture", image=name)
    elif src is not None and src.type == "TEX_SKY":
        out["kind"] = "sky_texture"
    else:
        out["kind"] = "other"
    return out


def _sha256(path: str) -> str | None:
    if not path or not os.path.isfile(path):
        return None
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _decodes_at(path: str, width: int, height: int) -> bool:
    """Whether Blender decodes the image at ``path`` (PNG or EXR) to ``width`` x ``height`` pixels."""
    try:
        img = bpy.data.images.load(path, check_existing=False)
    except RuntimeError:
        return False
    try:
        if tuple(img.size) != (width, height):
            return False
        return len(img.pixels) == width * height * img.channels
    except RuntimeError:
        return False
    finally:
        bpy.data.images.remove(img)


def _round(obj):
    if isinstance(obj, float):
        return round(obj, 6)
    if isinstance(obj, (list, tuple)):
        return [_round(v) for v in obj]
    if isinstance(obj, dict):
        return {k: _round(v) for k, v in obj.items()}
    return obj


def _hash(data) -> str:
    return hashlib.sha256(json.dumps(_round(data), sort_keys=True).encode()).hexdigest()[:16]


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
        self.out = os.path.abspath(bpy.path.abspath(settings.out_dir))
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
            self.bounds = scene_bounds.scene_bounds(scene)
        except scene_bounds.BoundsError as exc:
            raise CaptureError(str(exc)) from exc
        self.mask_objects = []
        if settings.masks:
            self.mask_objects = scene_bounds.renderable_objects(scene, only_selected=settings.target == "SELECTION")
            if not self.mask_objects:
                raise CaptureError("masks for the selection: nothing visible is selected")
            if settings.target == "SELECTION" and self.engine != "CYCLES":
                raise CaptureError("object masks of a selection need Cycles (its object index pass)")
        self.render_sig = None
        self.world = None
        self.frames = []
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
        if not self.s.film_transparent:
            # The world is in every pixel behind the scene. Only opaque captures carry it, so the
            # hashes of transparent captures (and the folders they resume) stay what they were.
            sig["world"] = world_description(sc.world)
        return sig

    def plan(self) -> list[dict]:
        """Frames to capture, from the "NeRF Cameras" collection; raises CaptureError on bad cameras."""
        cams = layouts.capture_cameras(self.scene)
        if not cams["train"]:
            raise CaptureError(f"no train cameras in the {layouts.COLLECTION_NAME!r} collection; "
                               "generate a camera layout first")
        self.render_sig = self._render_signature()
        self.world = world_description(self.scene.world)
        # Intrinsics use the capture resolution, not the scene's: compute on a stand-in render struct.
        render = _RenderView(self.scene.render, self.s.res_x, self.s.res_y)
        frames = []
        for split in layouts.SPLITS:
            for k, obj in enumerate(cams[split]):
                err = layouts.camera_scale_error(obj)
                scale_removed = None
                if err:
                    if not self.s.normalize_camera_scale or "sheared" in err:
                        raise CaptureError(err + " (or let the capture normalise camera scale)")
                    scale_removed = [round(c.length, 6) for c in (obj.matrix_world.col[i].xyz for i in range(3))]
                try:
                    intr = export.camera_intrinsics(obj, render)
                except export.ExportError as exc:
                    raise CaptureError(str(exc)) from exc
                c2w = [[float(v) for v in row] for row in obj.matrix_world.normalized()]
                frame = obj.get("nerf_frame")
                key = f"{split}/r_{k}"
                fr = {
                    "key": key, "split": split, "name": f"r_{k}", "camera": obj.name, "obj": obj,
                    "transform_matrix": c2w, "intrinsics": intr, "frame": int(frame) if frame is not None else None,
                    "scale_removed": scale_removed,
                }
                fr["hash"] = _hash({"render": self.render_sig, "c2w": c2w, "intr": intr, "frame": fr["frame"]})
                fr.update(self._frame_files(split, fr["name"]))
                frames.append(fr)
        self.frames = frames
        return frames

    def _frame_files(self, split: str, name: str) -> dict:
        files = {"image": f"{split}/{name}.png"}
        if self.s.depth:
            files["depth_file_path"] = f"depth/{split}/{name}.exr"
        if self.s.normals:
            files["normal_file_path"] = f"normals/{split}/{name}.exr"
        if self.s.masks:
            files["mask_path"] = f"masks/{split}/{name}.png"
        if self.s.points and split == "train":
            files["points_cache"] = f"{export.MANIFEST_DIR}/points/{split}_{name}.npz"
        return files

    # ------------------------------------------------------------------ folder checks

    def inspect_folder(self) -> tuple[dict | None, str | None]:
        """(manifest to resume from, conflict message) without touching the disk.

        The conflict message is set when the folder holds something a capture would overwrite:
        foreign files, or a capture whose frames differ. ``overwrite`` makes it proceed anyway.
        """
        if not self.frames:
            self.plan()
        out = self.out
        if os.path.exists(out) and not os.path.isdir(out):
            raise CaptureError(f"output {out} exists and is not a folder")
        if not os.path.isdir(out):
            return None, None
        entries = sorted(e for e in os.listdir(out) if e != export.MANIFEST_DIR)
        try:
            manifest = export.read_manifest(out)
        except export.ExportError as exc:
            return None, str(exc)
        if manifest is not None and manifest.get("format") != FORMAT:
            manifest = None
        if manifest is None:
            if entries:
                shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
                return None, (f"output folder {out} is not empty and holds no capture of ours ({shown}); "
                              "choose an empty folder or confirm overwrite (--overwrite)")
            return None, None
        old = manifest.get("frames", {})
        new = {f["key"]: f["hash"] for f in self.frames}
        differing = sorted(k for k, v in old.items() if new.get(k) != v.get("hash"))
        if differing:
            reason = "render settings changed" if manifest.get("render") != _round(self.render_sig) else "cameras changed"
            return manifest, (f"output folder {out} holds a different capture ({reason}: {len(differing)} of "
                              f"{len(old)} frames differ, e.g. {differing[0]}); choose another folder or "
                              "confirm overwrite (--overwrite)")
        return manifest, None

    def _check_folder(self) -> dict | None:
        """Make the folder usable; returns the existing manifest to resume from (or None)."""
        manifest, conflict = self.inspect_folder()
        if conflict and not self.s.overwrite:
            raise CaptureError(conflict)
        try:
            os.makedirs(os.path.join(self.out, export.MANIFEST_DIR), exist_ok=True)
            probe = os.path.join(self.out, export.MANIFEST_DIR, ".write_probe")
            with open(probe, "w") as fh:
                fh.write("ok")
            os.remove(probe)
        except OSError as exc:
            raise CaptureError(f"output folder {self.out} is not writable: {exc.strerror or exc}") from exc
        if self.s.overwrite:
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
        os.makedirs(os.path.join(self.out, export.MANIFEST_DIR), exist_ok=True)

    # ------------------------------------------------------------------ lifecycle

    def prepare(self) -> int:
        """Validate, choose the frames still to render, apply render settings; returns how many remain."""
        if not self.frames:
            self.plan()
        manifest = self._check_folder()
        kept = set()
        self.file_sha256 = {}  # frame key -> {file key: sha256 of the file as written}
        if manifest:
            old = manifest.get("frames", {})
            for fr in self.frames:
                entry = old.get(fr["key"])
                if (entry and entry.get("hash") == fr["hash"] and entry.get("done") and self._files_exist(fr)
                        and self._frame_intact(fr, entry)):
                    kept.add(fr["key"])
                    if isinstance(entry.get("sha256"), dict):
                        self.file_sha256[fr["key"]] = dict(entry["sha256"])
                    else:  # a manifest from before per-file hashes: record them now that the files check out
                        self._record_hashes(fr)
        self.done_keys = set(kept)
        self.kept = len(kept)
        self.pending = [fr for fr in self.frames if fr["key"] not in kept]
        for rel in {os.path.dirname(v) for fr in self.frames for k, v in fr.items()
                    if k in ("image", "depth_file_path", "normal_file_path", "mask_path", "points_cache")}:
            os.makedirs(os.path.join(self.out, rel), exist_ok=True)
        self.blend_sha256 = _sha256(bpy.data.filepath)
        self.created = (manifest or {}).get("created") or time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        self._apply_settings()
        self._started = True
        self.status = "incomplete"
        self._write_manifest()
        self.progress(len(self.done_keys), len(self.frames), f"resuming: {self.kept} kept" if self.kept else "")
        return len(self.pending)

    FRAME_FILE_KEYS = ("image", "depth_file_path", "normal_file_path", "mask_path", "points_cache")

    def _frame_intact(self, fr, entry) -> bool:
        """A kept frame must be the one written: each file's sha256 equals the one recorded when it was
        written (manifests from before that record: no hash to compare), and each image decodes at the
        capture's size. A truncated PNG or an empty EXR fails and is rendered again."""
        recorded = entry.get("sha256") if isinstance(entry.get("sha256"), dict) else None
        for k in self.FRAME_FILE_KEYS:
            if k not in fr:
                continue
            path = os.path.join(self.out, fr[k])
            if recorded is not None and recorded.get(k) != _sha256(path):
                return False
            if k != "points_cache" and not _decodes_at(path, self.s.res_x, self.s.res_y):
                return False
        return True

    def _record_hashes(self, fr) -> None:
        self.file_sha256[fr["key"]] = {k: _sha256(os.path.join(self.out, fr[k]))
                                       for k in self.FRAME_FILE_KEYS if k in fr}

    def _files_exist(self, fr) -> bool:
        return all(os.path.isfile(os.path.join(self.out, fr[k]))
                   for k in ("image", "depth_file_path", "normal_file_path", "mask_path", "points_cache") if k in fr)

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
        self._set(r, "use_single_layer", True)  # one view layer: the one whose passes we enable
        if self.engine == "CYCLES":
            self._set(sc.cycles, "samples", self.s.samples)
            self._set(sc.cycles, "use_denoising", self.s.denoise)
            self._set(sc.cycles, "use_adaptive_sampling", False)
        elif self.engine.startswith("BLENDER_EEVEE"):
            self._set(sc.eevee, "taa_render_samples", self.s.samples)
        vl = bpy.context.view_layer if bpy.context.scene == sc else sc.view_layers[0]
        self.view_layer = vl
        want_passes = self.s.depth or self.s.points
        self._set(vl, "use_pass_z", bool(want_passes) or vl.use_pass_z)
        if self.engine != "BLENDER_WORKBENCH":
            self._set(vl, "use_pass_normal", self.s.normals or vl.use_pass_normal)
        if self.s.masks and self.engine == "CYCLES":
            self._set(vl, "use_pass_object_index", True)
            ids = {o.name for o in self.mask_objects}
            for obj in scene_bounds.renderable_objects(sc):
                self._set(obj, "pass_index", 1 if obj.name in ids else 0)
        self._set(sc, "camera", sc.camera)
        self._set(sc, "frame_current", sc.frame_current)
        img = r.image_settings
        for attr in ("media_type", "file_format", "color_mode", "color_depth", "exr_codec", "use_exr_interleave",
                     "compression"):
            if hasattr(img, attr):
                self._restore.append((img, attr, getattr(img, attr)))

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
        if fr["frame"] is not None and sc.frame_current != fr["frame"]:
            sc.frame_set(fr["frame"])
        bpy.ops.render.render()
        result = bpy.data.images["Render Result"]
        self._save_png(result, os.path.join(self.out, fr["image"]))
        if self._needs_passes():
            self._save_passes(result, fr)
        self._record_hashes(fr)
        self.pending.pop(0)
        self.done_keys.add(fr["key"])
        self._write_manifest()
        self.progress(len(self.done_keys), len(self.frames), fr["key"])
        return bool(self.pending)

    def _save_png(self, result, path: str) -> None:
        img = self.scene.render.image_settings
        if hasattr(img, "media_type"):  # Blender 5.0 split the format into media type + file format
            img.media_type = "IMAGE"
        img.file_format = "PNG"
        img.color_mode = "RGBA"
        img.color_depth = "8"
        tmp = path[:-4] + ".partial.png"
        result.save_render(tmp, scene=self.scene)
        os.replace(tmp, path)

    def _save_passes(self, result, fr) -> None:
        img = self.scene.render.image_settings
        if hasattr(img, "media_type"):
            img.media_type = "MULTI_LAYER_IMAGE"
        else:
            img.file_format = "OPEN_EXR_MULTILAYER"
        img.color_depth = "32"
        img.exr_codec = "NONE"  # passes.read_exr_channels reads uncompressed, single-part files
        if hasattr(img, "use_exr_interleave"):
            img.use_exr_interleave = True
        tmp = os.path.join(self.out, export.MANIFEST_DIR, "render_passes.partial.exr")
        result.save_render(tmp, scene=self.scene)
        try:
            ch = passes.read_exr_channels(tmp)
        finally:
            os.remove(tmp)
        depth = None
        if self.s.depth or self.s.points:
            z = passes.find_pass(ch, "Depth", "Z")
            if z is None:
                raise CaptureError(f"{fr['key']}: the render has no Depth pass ({self.engine})")
            depth = passes.planar_depth(z[..., 0])
        if self.s.depth:
            passes.write_exr(os.path.join(self.out, fr["depth_file_path"]), {"Z": depth})
        if self.s.normals:
            n = passes.find_pass(ch, "Normal", "XYZ")
            if n is None:
                raise CaptureError(f"{fr['key']}: the render has no Normal pass ({self.engine})")
            passes.write_exr(os.path.join(self.out, fr["normal_file_path"]),
                             {"X": n[..., 0], "Y": n[..., 1], "Z": n[..., 2]})
        if self.s.masks:
            if self.engine == "CYCLES":
                idx = passes.find_pass(ch, "Object Index", "X")
                if idx is None:
                    idx = passes.find_pass(ch, "IndexOB", "X")
                mask = np.abs(idx[..., 0] - 1.0) < 0.5
            else:
                alpha = passes.find_pass(ch, "Combined", "A")
                mask = alpha[..., 0] > 0.5
            passes.write_png_gray(os.path.join(self.out, fr["mask_path"]), mask.astype(np.uint8) * 255)
        if self.s.points and fr["split"] == "train":
            rgb = self._read_png_rgb(os.path.join(self.out, fr["image"]))
            alpha_ok = rgb[..., 3] > 127
            d = np.where(alpha_ok, depth, np.inf)
            pts, cols = export.backproject(d, rgb[..., :3], fr["intrinsics"], fr["transform_matrix"])
            budget = max(1, self.s.n_points // max(1, sum(f["split"] == "train" for f in self.frames)))
            if len(pts) > budget:
                pick = np.random.default_rng(self.s.seed + len(self.done_keys)).choice(len(pts), budget, replace=False)
                pts, cols = pts[pick], cols[pick]
            path = os.path.join(self.out, fr["points_cache"])
            with open(path + ".partial", "wb") as fh:
                np.savez(fh, points=pts, colors=cols)
            os.replace(path + ".partial", path)

    @staticmethod
    def _read_png_rgb(path: str) -> np.ndarray:
        """(h, w, 4) uint8 of a PNG via Blender's loader (rows flipped to top-first)."""
        image = bpy.data.images.load(path, check_existing=False)
        try:
            w, h = image.size
            buf = np.empty(w * h * 4, np.float32)
            image.pixels.foreach_get(buf)
        finally:
            bpy.data.images.remove(image)
        return np.round(buf.reshape(h, w, 4)[::-1] * 255).astype(np.uint8)

    def finish(self) -> dict:
        """Write the JSON (and point cloud), mark the manifest complete, restore settings."""
        try:
            self._write_dataset(complete=not self.pending)
        finally:
            self._restore_settings()
            self._finished = True
        return self.summary()

    def cancel(self) -> dict:
        """Stop now: JSON for the frames done, manifest "incomplete", settings restored; resumable."""
        if self._started and not self._finished:
            try:
                for name in os.listdir(os.path.join(self.out, export.MANIFEST_DIR)):
                    if ".partial" in name:
                        os.remove(os.path.join(self.out, export.MANIFEST_DIR, name))
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
        return {"out": self.out, "status": self.status, "frames": len(self.frames),
                "rendered": len(self.done_keys) - self.kept, "kept": self.kept,
                "pending": len(self.pending)}

    # ------------------------------------------------------------------ writing

    def _done_frames(self) -> list[dict]:
        return [fr for fr in self.frames if fr["key"] in self.done_keys]

    def _write_dataset(self, complete: bool) -> None:
        done = self._done_frames()
        cams = [fr["transform_matrix"] for fr in self.frames]
        near, far = export.near_far([[m[0][3], m[1][3], m[2][3]] for m in cams], *self.bounds)
        self.near, self.far = near, far
        common = {"aabb": [list(map(float, self.bounds[0])), list(map(float, self.bounds[1]))],
                  "near": near, "far": far, "aabb_scale": export.ngp_aabb_scale(*self.bounds),
                  "film_transparent": bool(self.s.film_transparent), "world": self.world}
        if self.s.depth:
            common["depth_unit_scale_factor"] = 1.0  # EXR depth is already in scene units, not millimetres
        if self.s.points and complete:
            pts, cols = [], []
            for fr in done:
                if "points_cache" in fr:
                    with np.load(os.path.join(self.out, fr["points_cache"])) as z:
                        pts.append(z["points"])
                        cols.append(z["colors"])
            if pts:
                export.write_ply(os.path.join(self.out, "points3d.ply"), np.concatenate(pts), np.concatenate(cols))
                common["ply_file_path"] = "points3d.ply"
        if any(fr["split"] == "train" for fr in done):
            export.write_transforms(self.out, [dict(fr, name=fr["name"]) for fr in done], common)
        self.status = "complete" if complete else "incomplete"
        self._write_manifest()

    def _write_manifest(self) -> None:
        lo, hi = self.bounds
        frames = {}
        for fr in self.frames:
            frames[fr["key"]] = {
                "hash": fr["hash"], "camera": fr["camera"], "done": fr["key"] in self.done_keys,
                "frame": fr["frame"],
                "files": {k: fr[k] for k in ("image", "depth_file_path", "normal_file_path", "mask_path") if k in fr},
            }
            if fr["key"] in self.done_keys and self.file_sha256.get(fr["key"]):
                frames[fr["key"]]["sha256"] = self.file_sha256[fr["key"]]
            if fr["scale_removed"]:
                frames[fr["key"]]["camera_scale_removed"] = fr["scale_removed"]
        manifest = {
            "format": FORMAT, "format_version": 1, "status": self.status,
            "created": self.created, "updated": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "blender_version": bpy.app.version_string,
            "blend_file": bpy.data.filepath or None, "blend_sha256": self.blend_sha256,
            "blend_unsaved_changes": bool(bpy.data.is_dirty),
            "scene": self.scene.name,
            "render": _round(self.render_sig),
            "film_transparent": bool(self.s.film_transparent), "world": self.world,
            "seed": self.s.seed, "layout": self.s.layout,
            "normalization": {"scale": 1.0, "offset": [0.0, 0.0, 0.0], "applied": False,
                              "note": "coordinates are Blender world coordinates, unchanged"},
            "bounds": {"min": list(map(float, lo)), "max": list(map(float, hi))},
            "near": getattr(self, "near", None), "far": getattr(self, "far", None),
            "conventions": {
                "camera": "OpenGL (+X right, +Y up, looks along -Z); transform_matrix = matrix_world without scale",
                "depth": "planar z-depth along -Z in scene units, float32 EXR channel Z, inf = no surface "
                         "(nerfstudio: set its depth-unit-scale-factor to 1, it assumes millimetres)",
                "normals": "world-space unit normals, float32 EXR channels X, Y, Z; 0 = no surface",
                "mask": "8-bit PNG, 255 = pixel of the target objects, 0 = elsewhere",
            },
            "counts": {s: sum(f["split"] == s for f in self.frames) for s in layouts.SPLITS},
            "frames": frames,
        }
        export.write_manifest(self.out, manifest)


class _RenderView:
    """The scene's render settings seen at the capture's resolution (for intrinsics before rendering)."""

    def __init__(self, render, res_x, res_y):
        self.resolution_x, self.resolution_y = res_x, res_y
        self.resolution_percentage = 100
        self.pixel_aspect_x, self.pixel_aspect_y = render.pixel_aspect_x, render.pixel_aspect_y

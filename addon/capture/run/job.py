"""Render the cameras of the "NeRF Cameras" collection into a NeRF dataset folder.

``CaptureJob`` is the one engine behind the panel's modal operator (one ``step()`` per timer tick)
and ``scripts/capture.py`` (a loop). It never imports nerf_core: progress goes through a callback
``progress(done, total, info)``.

Safety rules it enforces:
- A folder holding anything else (or a capture whose frames differ) is refused unless
  ``overwrite``; overwrite deletes only the dataset's own paths (``files.folder.DATASET_PATHS``).
- Frames are written under a temporary name and renamed, so a frame file is whole or absent.
- Resume: a frame whose settings hash (render settings + camera pose + intrinsics) is in the
  manifest (or a shard's state) and whose files are the ones written is kept, not re-rendered.
- Cancel (or an error) writes the JSON of the frames done so far; the manifest says "incomplete".
- The background is recorded: ``film_transparent`` and ``world`` (``world_description``) at the top
  of the manifest and of every transforms file. With an opaque film the world is part of the
  picture, so it joins the render signature (and the frame hashes): a changed world re-renders.
- The user's render settings, active camera and frame are restored afterwards.

Sharded (``settings.shard = (K, N)``, a render farm): the job renders only shard K's share of the
plan (``plan.frame_plan``) and records it in its own state file (``files.shards``); it writes no
manifest, transforms file or point cloud: ``run.merge`` does, once every shard is done.
"""
from __future__ import annotations

import os
import time

import bpy

from ...dataset import capture_manifest
from ..files import frame_files, shards, verify, write
from ..files.folder import FolderInspection
from ..files.write import FORMAT
from ..plan import frame_plan
from ..plan.frame_plan import CaptureError
from ..plan.planning import CapturePlanning
from .render_settings import RenderSettingsOverride


class CaptureJob(CapturePlanning, FolderInspection, RenderSettingsOverride):
    """One capture of ``scene`` into ``settings.out_dir``: ``prepare()``, ``step()`` until False, ``finish()``.

    ``run()`` does all three; ``cancel()`` stops early leaving a consistent, resumable folder.

    Planning (``CapturePlanning``), the folder checks (``FolderInspection``) and the render settings
    (``RenderSettingsOverride``) live in their own modules; this class is the step loop and the records.
    """

    # ------------------------------------------------------------------ lifecycle

    def prepare(self) -> int:
        """Validate, choose the frames still to render, apply render settings; returns how many remain."""
        if not self.frames:
            self.plan()
        manifest = self._check_folder()
        kept = set()
        self.file_sha256 = {}
        records = shards.done_records(self.out, capture_manifest.MANIFEST_DIR, self.frames, self.plan_hash, manifest)
        for key, rec in records.items():
            fr = next((f for f in self.frames if f["key"] == key), None)
            if fr is None or key not in self.share or rec["hash"] != fr["hash"]:
                continue
            if verify.frame_problem(self.out, fr, rec["sha256"], self.s.res_x, self.s.res_y) is None:
                kept.add(key)
                # a manifest from before per-file hashes: record them now that the files check out
                self.file_sha256[key] = dict(rec["sha256"]) if rec["sha256"] else verify.file_hashes(self.out, fr)
        self.done_keys = set(kept)
        self.kept = len(kept)
        self.pending = [fr for fr in self.frames if fr["key"] in self.share and fr["key"] not in kept]
        for rel in {os.path.dirname(v) for fr in self.frames for k, v in fr.items()
                    if k in frame_plan.FRAME_FILE_KEYS}:
            os.makedirs(os.path.join(self.out, rel), exist_ok=True)
        self.blend_sha256 = verify.sha256_file(bpy.data.filepath)
        self.created = (manifest or {}).get("created") or time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        self._apply_settings()
        self._started = True
        self.status = "incomplete"
        self._write_record()
        self.progress(len(self.done_keys), len(self.share), f"resuming: {self.kept} kept" if self.kept else "")
        return len(self.pending)

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
            frame_files.render_still()
        except RuntimeError as exc:  # Blender's own refusal, e.g. "Failed to allocate GPU buffers"
            reason = str(exc).replace("Error: ", "").strip()
            raise CaptureError(f"{fr['key']}: Blender could not render this view at {self.s.res_x}x{self.s.res_y} px "
                               f"with {self.engine} ({reason}); a lower resolution may fit. The frames rendered so "
                               "far are kept, and capturing again resumes") from exc
        result = bpy.data.images["Render Result"]
        frame_files.save_png(sc, result, os.path.join(self.out, fr["image"]))
        if self._needs_passes():
            n_train = sum(f["split"] == "train" for f in self.frames)
            frame_files.save_passes(sc, result, fr, self.out, self.s, self.engine,
                                       os.path.join(self.out, capture_manifest.MANIFEST_DIR),
                                       max(1, self.s.n_points // max(1, n_train)))
        self.file_sha256[fr["key"]] = verify.file_hashes(self.out, fr)
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
                mine = shards.unique_suffix()
                for name in os.listdir(folder):
                    # a shard removes only its own leftovers: the others may be writing theirs
                    if frame_files.PARTIAL_TAG in name and (not self.shard or mine in name):
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
        self.near, self.far = write.write_dataset(self.out, self.plan_doc, self.done_keys, complete,
                                                          self._manifest_info())

    def _write_record(self) -> None:
        """After each frame: the manifest (one machine) or this shard's own state file (a farm)."""
        if not self.shard:
            capture_manifest.write_manifest(self.out, write.manifest(
                self.plan_doc, self.done_keys, dict(self._manifest_info(), status=self.status,
                                                    near=getattr(self, "near", None), far=getattr(self, "far", None))))
            return
        k, n = self.shard
        state = {"format": FORMAT, "shard": k, "shards": n, "status": self.status, "hash": self.plan_hash,
                 "assignment": frame_plan.SHARD_ASSIGNMENT, "plan": self.plan_doc,
                 "manifest_info": {key: v for key, v in self._manifest_info().items() if key != "file_sha256"},
                 "done": {key: self.file_sha256[key] for key in sorted(self.done_keys) if key in self.file_sha256}}
        shards.write_state(shards.state_path(self.out, capture_manifest.MANIFEST_DIR, k, n), state)



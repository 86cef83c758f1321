"""The capture's output folder: what it holds (``FolderInspection.inspect_folder``: a capture to resume, or
a conflict) and making it ready (refusing, or deleting only the dataset's own paths on overwrite)."""
from __future__ import annotations

import os
import shutil

import bpy

from ...bridge.core_contract import contract
from ...dataset import capture_manifest, transforms
from ...dataset.errors import ExportError
from ...file_writes import partial_file
from ..plan import frame_plan
from ..plan.frame_plan import CaptureError
from . import shards
from .write import FORMAT

# Paths a capture owns inside its folder; the only ones --overwrite removes.
DATASET_PATHS = ("train", "val", "test", "depth", "normals", "masks", "points3d.ply", "transforms.json",
                 "transforms_train.json", "transforms_val.json", "transforms_test.json", capture_manifest.MANIFEST_DIR,
                 transforms.NERFSTUDIO_DIR, "colmap")  # colmap: capture.py --colmap


def _empty_tree(path: str) -> bool:
    """True for a folder holding nothing but (nested) empty folders."""
    if not os.path.isdir(path) or os.path.islink(path):
        return False
    return all(_empty_tree(os.path.join(path, e)) for e in os.listdir(path))


class FolderInspection:
    """``CaptureJob``'s checks of its output folder (``self.out``) against its plan."""

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
        entries = sorted(e for e in os.listdir(out)
                         if e != capture_manifest.MANIFEST_DIR and not _empty_tree(os.path.join(out, e)))
        try:
            manifest = capture_manifest.read_manifest(out)
            states = shards.read_states(out, capture_manifest.MANIFEST_DIR)
        except (ExportError, CaptureError) as exc:
            return None, str(exc)
        if manifest is not None and manifest.get("format") != FORMAT:
            manifest = None
        conflict = shards.conflict(out, capture_manifest.MANIFEST_DIR, self.plan_doc, self.plan_hash, self.shard,
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
            same_render = manifest.get("render") == frame_plan.round6(self.render_sig)
            reason = "cameras changed" if same_render else "render settings changed"
            return manifest, (f"output folder {out} holds a different capture ({reason}: {len(differing)} of "
                              f"{len(old)} frames differ, e.g. {differing[0]}); choose another folder or "
                              "confirm overwrite (--overwrite)")
        # After the frame hashes, whose message is more precise: an opaque film's world is in them.
        looked = manifest.get("appearance_signature")  # absent in captures made before it was recorded
        if (looked and self.appearance_sig and looked != self.appearance_sig
                and any(v.get("done") for v in old.values())):
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
            probe = os.path.join(self.out, capture_manifest.MANIFEST_DIR, f".write_probe.{shards.unique_suffix()}")
            with partial_file(probe, binary=False) as fh:
                fh.write("ok")
            os.remove(probe)
        except OSError as exc:
            raise CaptureError(f"output folder {self.out} is not writable: {exc.strerror or exc}") from exc
        if self.s.overwrite and not self.shard:
            self._delete_dataset()
            return None
        return manifest

    def _delete_dataset(self) -> None:
        doomed = [os.path.join(self.out, rel) for rel in DATASET_PATHS]
        try:  # the output rule: never through a link, never an input (the open scene, by identity)
            contract.outputs.refuse_deleting_inputs(doomed, {"the scene being captured": bpy.data.filepath},
                                                     flag="output folder")
        except contract.outputs.OutputError as exc:
            raise CaptureError(str(exc)) from None
        for path in doomed:
            if os.path.isdir(path):
                shutil.rmtree(path)
            elif os.path.exists(path):
                os.remove(path)
        os.makedirs(os.path.join(self.out, capture_manifest.MANIFEST_DIR), exist_ok=True)

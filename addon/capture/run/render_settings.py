"""The render settings a capture applies for its frames and restores afterwards (``RenderSettingsOverride``):
engine, resolution, film, passes, one view layer, no compositor, motion blur, stereo or depth of field."""
from __future__ import annotations

import bpy

from ...scene import scene_bounds


class RenderSettingsOverride:
    """``CaptureJob``'s changes to the scene's render settings, each recorded to be restored."""

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

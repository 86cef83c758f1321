"""The scene's "NeRF Cameras" collection: finding or making it, the cameras a capture renders
(``capture_cameras``), clearing a layout's cameras, and the record of the settings they were laid out
with (``stale_layout_note``)."""
from __future__ import annotations

import json

import bpy

from .positions import COLLECTION_NAME, SPLITS, LayoutError, LayoutSpec


def _is_camera_collection(coll) -> bool:
    return "nerf_cameras" in coll or coll.name == COLLECTION_NAME or coll.name.startswith(COLLECTION_NAME + ".")


def nerf_collection(scene, create: bool = True):
    """The scene's own "NeRF Cameras" collection: one inside its scene collection (at any depth), else,
    with ``create``, a new one linked there, else None. Collections are shared by name across a file's
    scenes, and a layout made in one scene (a demo scene, say) replaced and cleared another's cameras:
    each scene has its own, named "NeRF Cameras.001" and so on after the first."""
    for coll in scene.collection.children_recursive:
        if _is_camera_collection(coll):
            return coll
    if not create:
        return None
    coll = bpy.data.collections.new(COLLECTION_NAME)
    coll["nerf_cameras"] = True
    scene.collection.children.link(coll)
    return coll


def clear_cameras(scene) -> int:
    """Delete the cameras a layout made in the "NeRF Cameras" collection; return how many.

    Only camera objects tagged ``nerf_split`` go: anything else a user put in the collection stays.
    """
    coll = nerf_collection(scene, create=False)
    if coll is None:
        return 0
    objs = [o for o in coll.objects if o.type == "CAMERA" and "nerf_split" in o]
    if LAYOUT_RECORD in coll:
        del coll[LAYOUT_RECORD]  # cameras the user adds later were not laid out by these settings
    for obj in objs:
        data = obj.data
        bpy.data.objects.remove(obj, do_unlink=True)
        if data is not None and data.users == 0:
            bpy.data.cameras.remove(data)
    return len(objs)


def capture_cameras(scene) -> dict[str, list]:
    """The cameras a capture renders, by split, each sorted by name (order = frame index)."""
    coll = nerf_collection(scene, create=False)
    out = {s: [] for s in SPLITS}
    if coll is None:
        return out
    for obj in coll.all_objects:
        if obj.type == "CAMERA":
            out[obj.get("nerf_split", "train") if obj.get("nerf_split") in SPLITS else "train"].append(obj)
    for s in SPLITS:
        out[s].sort(key=lambda o: o.name)
    return out


def held_out_problem(cams: dict[str, list]) -> str | None:
    """Why a camera set (``capture_cameras``) cannot make a dataset our tools accept, or None.

    ``train`` and ``check`` refuse an empty split (the original NeRF loader and 3DGS read every split),
    so a capture with no val or no test camera would write a dataset nobody can train on.
    """
    empty = [s for s in ("val", "test") if not cams.get(s)]
    if not empty:
        return None
    return (f"the {COLLECTION_NAME!r} collection has no {' and no '.join(empty)} camera: a dataset needs at least "
            "1 view in each split (train, val, test), or `train` and `check` refuse it. Generate the layout again "
            f"with Val and Test of 1 or more, or tag a camera with nerf_split = {empty[0]!r}")


LAYOUT_RECORD = "nerf_layout"  # the collection's record of the settings its cameras were laid out with
# The settings each layout's cameras depend on (names as the panel gives them: "focal length", "train count").
_AROUND = ("train", "radius", "elevation_min", "elevation_max", "focal_length", "target", "margin")
_LAYOUT_USES = {"hemisphere": _AROUND, "sphere": _AROUND, "random": _AROUND, "rings": _AROUND + ("rings",),
                "spiral": _AROUND + ("turns",),
                "inside": ("train", "elevation_min", "elevation_max", "focal_length", "target"),
                "scene-cameras": (), "animation": ("frame_step",)}


def layout_record(spec: LayoutSpec, res_x: int, res_y: int) -> dict:
    return dict(spec.to_dict(), resolution=[int(res_x), int(res_y)])


def stale_layout_note(scene, spec: LayoutSpec, res_x: int, res_y: int, cams: dict | None = None) -> str | None:
    """A sentence when the "NeRF Cameras" were laid out with other settings than ``spec`` asks for now
    (the panel's Radius, Focal Length, counts ... changed after Generate Cameras, or after a capture
    made them): a capture renders the cameras as they are, so the new values would be silently
    ignored. None when they agree, when there are no cameras, or when the collection holds no record
    (cameras the user placed). Only the settings the layout uses are compared (``_LAYOUT_USES``).
    ``cams``: ``capture_cameras(scene)`` when the caller has it already (the panel, on every redraw).
    """
    coll = nerf_collection(scene, create=False)
    if cams is None:
        cams = capture_cameras(scene)
    if coll is None or not any(cams.values()) or not isinstance(coll.get(LAYOUT_RECORD), str):
        return None
    try:
        was = json.loads(coll[LAYOUT_RECORD])
        now = layout_record(spec, res_x, res_y)
    except (ValueError, LayoutError):
        return None
    keys = ("layout", "val", "test", "seed", "resolution") + _LAYOUT_USES.get(spec.layout, ())
    names = {"train": "train count", "val": "val count", "test": "test count"}
    changed = [f"{names.get(k, k.replace('_', ' '))} {_show(was.get(k))} -> {_show(now[k])}" for k in keys
               if _show(was.get(k)) != _show(now[k])]
    if not changed:
        return None
    return (f"the cameras in {coll.name!r} were laid out with other settings ({', '.join(changed)}): a capture "
            "renders them as they are. Press Generate Cameras to lay them out with the panel's settings")


def _show(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        return "x".join(str(v) for v in value)
    return str(value)

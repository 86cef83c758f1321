"""What the panel and ``scripts/capture.py`` say after laying out cameras: objects a generated layout
leaves out of its framing (``framing_note``) and objects that move under the animation layout
(``motion_note``)."""
from __future__ import annotations

from ...scene import scene_bounds
from .positions import GENERATED_LAYOUTS, LayoutSpec


def framing_bounds(scene, spec: LayoutSpec) -> tuple:
    """(min, max, surroundings) that a generated layout looking in frames: the selection, or the
    scene without the floor, dome or backdrop that dwarfs its subject (``scene_bounds.subject_bounds``;
    their names, else [])."""
    if spec.target == "SELECTION":
        # with_thickness refuses a selection that spans no space (an empty curve, a lone vertex): its
        # cameras would all stand at one point
        return (*scene_bounds.with_thickness(*scene_bounds.scene_bounds(scene, only_selected=True)), [])
    return scene_bounds.subject_bounds(scene)


def framing_note(scene, spec: LayoutSpec) -> str | None:
    """What the panel and the script say when a generated layout that looks in leaves objects out of
    its framing (``framing_bounds``), else None."""
    if spec.layout not in GENERATED_LAYOUTS or spec.layout == "inside":
        return None
    names = framing_bounds(scene, spec)[2]
    if not names:
        return None
    shown = ", ".join(repr(n) for n in names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    return (f"framed on the subject without {shown}: much larger than it and flat or around it (a floor, dome or "
            "backdrop); they still render. Select the subject and use Target: Selection to choose otherwise")


# How many of an animation layout's frames are compared for moving objects (evenly spread, ends included).
MOTION_PROBE_FRAMES = 12


def moving_objects(scene, frames) -> list:
    """Names of renderable objects (and instances) whose world box changes between ``frames`` (at most
    ``MOTION_PROBE_FRAMES`` of them are compared); the scene's current frame is restored."""
    frames = list(frames)
    if len(frames) > MOTION_PROBE_FRAMES:
        frames = [frames[round(i * (len(frames) - 1) / (MOTION_PROBE_FRAMES - 1))] for i in range(MOTION_PROBE_FRAMES)]
    current, first, moved = scene.frame_current, None, set()
    try:
        for f in frames:
            scene.frame_set(f)
            boxes = {name: box for box, name in scene_bounds.renderable_boxes(scene)}
            if first is None:
                first = boxes
                # Motion below a ten-thousandth of the scene's size is rounding, not motion.
                tol = 1e-4 * scene_bounds.box_size(scene_bounds.box_union(list(boxes.values()))) if boxes else 0.0
                continue
            for name in set(first) ^ set(boxes):  # appears or disappears
                moved.add(name)
            for name in set(first) & set(boxes):
                a, b = first[name], boxes[name]
                if any(abs(a[k][i] - b[k][i]) > tol for k in range(2) for i in range(3)):
                    moved.add(name)
    finally:
        scene.frame_set(current)
    return sorted(moved)


def motion_note(scene, spec: LayoutSpec) -> str | None:
    """For the animation layout: a warning naming the objects that move between its frames, else None.
    Each view is rendered at its own frame, and a NeRF assumes one still scene: what moves comes out as
    a ghost."""
    if spec.layout != "animation":
        return None
    names = moving_objects(scene, range(scene.frame_start, scene.frame_end + 1, max(1, spec.frame_step)))
    if not names:
        return None
    shown = ", ".join(repr(n) for n in names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    return (f"{shown} move(s) between the animation's frames, and each view is rendered at its own frame: a NeRF "
            "assumes a still scene, so they will come out blurred or as ghosts. Hold them still while capturing "
            "(mute their animation), or leave them out of the render")


def layout_notes(scene, spec: LayoutSpec) -> list:
    """Every warning the panel and the script give after laying out cameras (``framing_note``, ``motion_note``)."""
    return [n for n in (framing_note(scene, spec), motion_note(scene, spec)) if n]

"""The one validation pass that lists every problem of a dataset (``dataset_problems``), shared by
``load_dataset`` (which stops at the first) and ``python -m nerf_core check`` (which lists them all).
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, List, Optional

from nerf_core.contract.errors import DatasetError
from nerf_core.contract.transforms import SPLITS, FrameInfo, frame_infos
from nerf_core.data import validation
from nerf_core.data.loading import load_split


def dataset_problems(path: Path | str, downscale: int = 1, min_train_views: int = 2,
                     visit: Optional[Callable[[str, FrameInfo, object], None]] = None) -> List[str]:
    """Every problem that makes ``load_dataset`` refuse ``path``, one message each (file, frame, field).

    The one validation pass behind ``train`` and ``check``: it runs the loader's own rules
    (``frame_infos``, ``validation.scene_fields``, ``validation.check_train_count`` and ``load_split``
    frame by frame, which decodes every image, depth, normal and mask file and checks its size against the JSON and the
    split), collecting the errors that ``load_dataset`` raises at the first of. An empty list means
    ``train`` accepts the dataset. Pixels are read one frame at a time and dropped; ``visit(split,
    frame, one-frame Split)`` sees each frame that loads first (``check`` looks at its pixels there
    rather than decode every image twice).
    """

    try:
        layout, root, infos, scene = frame_infos(path, SPLITS)
    except DatasetError as exc:
        return [str(exc)]
    problems: List[str] = []
    for check in (
        lambda: validation.check_train_count(root, infos, min_train_views),
        lambda: validation.scene_fields(scene),
        lambda: validation.check_duplicate_images(infos),
        lambda: validation.parse_aabb(scene["aabb"], str(scene["aabb_file"])) if "aabb" in scene else None,
        lambda: validation.check_near_far(scene, infos),
    ):
        try:
            check()
        except DatasetError as exc:
            problems.append(str(exc))
    try:
        scale = validation.depth_scale(scene)
    except DatasetError as exc:
        problems.append(str(exc))
        scale = 1e-3
    for name in SPLITS:
        first = None
        # Some pixel left to learn (and some pixel that shows the scene): a frame without a mask keeps
        # every pixel. A broken frame leaves both unknown, and is reported instead: with every frame
        # broken, "all train images are fully transparent" was added to the real errors.
        pixels_left = False
        shows_something = False
        lit = False
        for fr in infos[name]:
            try:
                sp = load_split(name, [fr], downscale, scale)
            except DatasetError as exc:
                problems.append(str(exc))
                pixels_left = shows_something = lit = True  # unknown: the frame's own error is what to fix
                continue
            if visit is not None:
                visit(name, fr, sp)
            pixels_left = pixels_left or not sp.masks_select_nothing()
            shows_something = shows_something or not sp.shows_nothing()
            lit = lit or not sp.is_black()
            shape = (sp.width, sp.height, sp.images.shape[-1])
            if first is None:
                first = (fr, shape)
                continue
            try:
                if shape[:2] != first[1][:2]:
                    raise DatasetError(
                        f"{fr.where}: field 'file_path': {fr.image} is {shape[0]}x{shape[1]} but the first "
                        f"{name} image ({first[0].image.name}) is {first[1][0]}x{first[1][1]}; all images of a "
                        "split must have one size"
                    )
                if shape[2] != first[1][2]:
                    lacking = fr if shape[2] == 3 else first[0]
                    raise DatasetError(
                        f"{lacking.where}: field 'file_path': {lacking.image} has no alpha channel while other {name} "
                        "images do; the alpha channel is the mask of the object, export every image as RGBA")
            except DatasetError as exc:
                problems.append(str(exc))
        if name == "train" and infos[name] and not shows_something:
            problems.append(validation.transparent_train_problem(infos[name]))
        elif name == "train" and infos[name] and not lit:
            problems.append(validation.black_train_problem(infos[name]))
        elif name == "train" and not pixels_left and any(f.mask is not None for f in infos[name]):
            problems.append(validation.empty_masks_problem(infos[name]))
    return problems

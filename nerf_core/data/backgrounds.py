"""What stands behind the scene during training, and how ``--background auto`` picks it.

Modes (``train --background``):

* ``environment``: a learned world, light from infinity (``nerf_core.fields.environment``). The right model
  for opaque captures: a Blender world (HDRI, sky, colour) or photographs whose background is real.
* ``random``: a random colour per ray behind the images' alpha. The right model for captures on a
  transparent film: it stops the scene from explaining the background with semi-transparent fog.
* ``white``, ``black``: a fixed colour; ``white-then-random``: white for the first 20 % of the
  budget, then random (bootstraps geometry for methods that start too empty to feel random colours).

``auto`` decides from what the dataset says about itself (``choose``), so a capture trains right
without flags: the capture records ``film_transparent`` in its transforms files, and for datasets
made elsewhere the images' alpha tells.
"""
from __future__ import annotations

from typing import Optional, Tuple

import torch

from nerf_core.errors import TrainError

# The names of the backgrounds, listed once; the other lists are built from this one.
# Modes that cannot show an opaque image's background (a photograph, a world): they would have to
# explain it with geometry inside the box.
FIXED_BACKGROUNDS = ("random", "white", "black", "white-then-random")
# What a RayBatcher composites ground truth onto ("auto" is decided before training: ``choose``).
TRAINING_BACKGROUNDS = ("environment",) + FIXED_BACKGROUNDS
BACKGROUNDS = ("auto",) + TRAINING_BACKGROUNDS  # ``train --background`` and ``check --background``
AUTO_WHITE_FRACTION = 0.2  # white-then-random: white for this share of the training budget

# An RGBA image counts as opaque when fewer than this share of its pixels are less than fully opaque
# (anti-aliased edges of a cut-out object alone are ~1 % of a 100 px image; an opaque render has none).
TRANSPARENT_SHARE = 1e-3
ALPHA_OPAQUE = 0.98


def transparent_share(images: torch.Tensor) -> float:
    """Share of pixels whose alpha is below ``ALPHA_OPAQUE`` in (n, h, w, c) images; 0 without alpha.

    Partly transparent pixels count: a subject's anti-aliased outline, and the whole of a see-through
    one (a Principled Volume cloud captured on a transparent film had 96.8 % of its pixels below).
    """
    if images.shape[-1] != 4 or images.numel() == 0:
        return 0.0
    alpha = images[..., 3]
    limit = ALPHA_OPAQUE * 255.0 if alpha.dtype == torch.uint8 else ALPHA_OPAQUE
    return float((alpha.float() < limit).float().mean())


def percent_text(share: float) -> str:
    """``share`` in [0, 1] as "12.3 %", never rounded to "100.0 %" or "0.0 %" unless it is exactly that:
    a train log said "100.0 % of the pixels are transparent" of a subject it then trained on."""
    p, digits = 100.0 * share, 1
    while 0.0 < share < 1.0 and round(p, digits) in (0.0, 100.0) and digits < 8:
        digits += 1  # one more decimal until the text is neither 0 nor 100
    return f"{p:.{digits}f} %"


# A cut-out whose subject (the mean alpha) covers less than this share of the train pixels gives the
# subject few rays and a whole-image score that counts mostly background: a 170-degree lens framing a
# 2-unit object at radius 4 gave it 1.3 % of the frame and a "33.6 dB" run that drew it as a smudge.
SMALL_SUBJECT_SHARE = 0.02


def small_subject_note(images: torch.Tensor) -> Optional[str]:
    """A note when the subject of (n, h, w, 4) cut-out images covers less than ``SMALL_SUBJECT_SHARE``
    of the pixels; None for opaque images, images without alpha, or a subject that fills enough."""
    if images.shape[-1] != 4 or images.numel() == 0 or transparent_share(images) < TRANSPARENT_SHARE:
        return None
    alpha = images[..., 3]
    if alpha.dtype == torch.uint8:  # summed as integers: no float copy of a large split
        share = float(alpha.sum(dtype=torch.int64)) / (255.0 * alpha.numel())
    else:
        share = float(alpha.mean())
    if share == 0.0 or share >= SMALL_SUBJECT_SHARE:
        return None  # nothing at all is refused elsewhere (dataset_checks.transparent_train_problem)
    return (f"the subject covers only {percent_text(share)} of the train pixels: it gets few rays, and a "
            "whole-image PSNR counts mostly the empty background; frame it tighter (a longer focal length, "
            "cameras nearer) for a model and a score of the subject")


def images_are_opaque(images: torch.Tensor) -> bool:
    """True when (n, h, w, c) images have no alpha channel or (almost) no transparent pixel."""
    return transparent_share(images) < TRANSPARENT_SHARE


def choose(images: torch.Tensor, film_transparent: Optional[bool], where: str = "dataset",
           cameras_inside: bool = False) -> Tuple[str, str]:
    """``--background auto``: the mode for a train split's (n, h, w, c) images, and why.

    ``film_transparent`` is what the dataset's transforms files declare (None when they do not);
    ``cameras_inside``: the cameras stand inside the scene box (an interior).
    """
    has_alpha = images.shape[-1] == 4
    share = transparent_share(images)
    if cameras_inside and has_alpha and share < TRANSPARENT_SHARE:
        # Measured on the interior demo scene: with a learned world the run painted the whole room onto
        # it as a panorama (opacity 0.005 everywhere, no geometry, 21.0 dB); random colours behind the
        # leftover transparency make every ray end on a surface instead.
        return "random", ("the cameras stand inside the scene box and the images are opaque (an interior): every "
                          "ray should end on a surface, so leftover transparency meets random colours rather than "
                          "a learned world that could hold the whole room as a panorama")
    if film_transparent is False:
        return "environment", (f"{where} declares film_transparent: false (an opaque capture showing the world): "
                               "the background is learned as light from infinity")
    if film_transparent is True:
        if has_alpha and share >= TRANSPARENT_SHARE:
            return "random", (f"{where} declares film_transparent: true: random background colours behind the alpha "
                              f"({percent_text(share)} of the pixels are at least partly transparent)")
        return "environment", (f"{where} declares film_transparent: true, but its images have "
                               f"{'no transparent pixels' if has_alpha else 'no alpha channel'}: "
                               "the background is learned as light from infinity")
    if not has_alpha:
        return "environment", ("the images have no alpha channel (RGB): their background is part of the picture, "
                               "learned as light from infinity")
    if share < TRANSPARENT_SHARE:
        return "environment", ("the images' alpha is opaque everywhere: their background is part of the picture, "
                               "learned as light from infinity")
    return "random", (
        f"{percent_text(share)} of the pixels are at least partly transparent (a cut-out on a transparent film): "
        "random background colours behind the alpha"
    )


def for_run(requested: str, recorded: Optional[str], dataset) -> Tuple[str, str]:
    """The mode a run trains with, and why, for ``requested`` (``train --background``) on a loaded
    ``data.Dataset``. ``recorded``: the mode a resumed run started with (None for a new run); ``auto``
    keeps it, so a run never changes its background halfway (also runs from before the environment).
    """
    if requested == "auto" and recorded in BACKGROUNDS:
        return recorded, "as recorded when the run started"
    if requested == "auto":
        return choose(dataset.split("train").images, dataset.film_transparent, where=f"{dataset.root}",
                      cameras_inside=dataset.cameras_inside)
    return requested, "as recorded when the run started" if recorded == requested else "--background given"


def for_training(requested: str, ckpt: Optional[dict], dataset) -> Tuple[str, str, list]:
    """``for_run`` for the trainer: (mode, reason, evaluation background RGB) for a new run
    (``ckpt`` None) or a resumed one, refusing (TrainError) a mode the dataset or run cannot train."""

    train = dataset.split("train")
    recorded = (ckpt.get("config") or {}).get("background_used") if ckpt is not None else None
    mode, reason = for_run(requested, recorded, dataset)
    if mode == "random" and not train.has_alpha:
        raise TrainError(
            f"{train.frames[0].image}: --background {mode} needs images with an alpha channel (RGBA); "
            "this dataset's images are RGB (--background environment learns their background)"
        )
    if ckpt is not None and mode == "environment" and "environment" not in ckpt["options"]:
        raise TrainError("--resume: the run was trained without a learned environment; "
                         "it cannot continue with --background environment")
    return mode, reason, [0.0, 0.0, 0.0] if mode == "black" else [1.0, 1.0, 1.0]

"""Alpha as supervision (``train --alpha-weight W``, issue 56): on a capture with a transparent film
every pixel's alpha says how opaque the scene is along its ray, and a loss can ask the rendered
opacity to match it, beside the colours.

Off by default (W = 0), so that scores compare with colours-only tools, and because the random
background (``data.backgrounds``) already makes the colour loss see the alpha: a ray left partly
transparent shows a random colour that no pixel has. docs/BENCHMARKS.md, "Alpha as supervision
(issue 56)", measures the two against each other.

Training with it is refused, naming the flag and the dataset, on a dataset that is no transparent
film (``check_alpha``): an opaque capture's alpha is 1 everywhere, and the loss would fill the box.
"""
from __future__ import annotations

from typing import Optional

import torch

from nerf_core.data.backgrounds import images_are_opaque
from nerf_core.data.split import Dataset
from nerf_core.errors import DatasetError
from nerf_core.image.losses import alpha_loss

# ``train --alpha-weight``'s default: off (the colours alone, as every peer trains).
DEFAULT_ALPHA_WEIGHT = 0.0


def check_alpha(dataset: Dataset) -> None:
    """Refuse alpha supervision on ``dataset`` unless it is a transparent film with alpha in its train
    images.

    Raises:
        DatasetError: one line naming ``--alpha-weight`` and the dataset: it declares an opaque film
            (``film_transparent: false``), its images have no alpha channel, or their alpha is opaque
            everywhere (``data.backgrounds.images_are_opaque``).
    """
    train = dataset.split("train")
    if dataset.film_transparent is False:
        why = "declares film_transparent: false (an opaque capture: its alpha is 1 everywhere)"
    elif not train.has_alpha:
        why = "has images without an alpha channel (RGB)"
    elif images_are_opaque(train.images):
        why = "has train images whose alpha is opaque everywhere"
    else:
        return
    raise DatasetError(f"--alpha-weight: {dataset.root}: {why}; alpha supervision needs a capture on a "
                       "transparent film (alpha in its images): train without --alpha-weight")


def with_alpha_term(loss: torch.Tensor, out: dict, alpha: Optional[torch.Tensor],
                    ray_weight: Optional[torch.Tensor], weight: float) -> torch.Tensor:
    """A step's ``loss`` () with what ``train --alpha-weight`` adds: ``weight`` times ``alpha_loss`` of
    the rendered opacity ``out["acc"]`` (n,) against the pixels' ``alpha`` (n,) (``RayBatch.alpha``),
    each ray weighted by ``ray_weight`` (n,) as in the colour loss (``RayBatch.weight``; None =
    uniform). ``loss`` itself when the weight is 0 or the batch carries no alpha (colours only)."""
    if alpha is None or not weight:
        return loss
    return loss + weight * alpha_loss(out["acc"], alpha, ray_weight)

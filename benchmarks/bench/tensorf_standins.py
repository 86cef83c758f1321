"""Stand-ins for the modules TensoRF's training imports but a plain torch install may lack.

TensoRF's ``train.py`` (apchenstu/TensoRF, read at commit 6a1e23b) imports, through ``opt``,
``renderer``, ``utils``, ``dataLoader`` and ``models``, these third-party modules at module level:

====================  =========================================  ====================================
module                what the training + PSNR path uses          without it
====================  =========================================  ====================================
torch, numpy, PIL     everything; the loader opens the PNGs       **required**: the launcher stops
configargparse        ``opt.config_parser`` (we pass no           argparse (same flags: we never use
                      ``--config``: every value is on argv)       ``--config``)
kornia                ``create_meshgrid`` for the ray grid        the same formula (checked against
                                                                  kornia in benchmarks/tests)
torchvision           ``transforms.ToTensor`` of the RGBA PNGs    the same conversion (uint8 / 255,
                                                                  HWC -> CHW); 8-bit images only
tqdm                  progress bars                               a silent pass-through
torch.utils           ``SummaryWriter`` (TensorBoard logs)        a no-op writer
.tensorboard
imageio               test renders as PNG, videos as mp4          PNG through PIL, no videos
cv2                   depth colour map of the test renders        a grey map
scipy.signal          SSIM (we ask for PSNR only)                 an empty module
skimage.measure,      mesh export (not used)                      empty modules
plyfile
lpips                 LPIPS, imported inside a function that      never imported (extra metrics off)
                      runs only with extra metrics
====================  =========================================  ====================================

``install()`` puts a stand-in into ``sys.modules`` only for a module that does not import, and
returns the names it stood in for, so a result says which ones a run used. The launcher also always
routes ``renderer.imageio`` through ``PngOnlyImageio``: TensoRF writes mp4 videos of its test renders,
which need imageio's ffmpeg plugin (rarely installed) and are no part of a score.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.machinery
import sys
import types

REQUIRED = ("torch", "numpy", "PIL")


class MissingRequired(RuntimeError):
    """A module the training itself needs is not installed."""


def check_required() -> None:
    """Import the modules TensoRF cannot train without; raise ``MissingRequired`` naming the missing ones."""
    missing = []
    for name in REQUIRED:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise MissingRequired(f"TensoRF needs {', '.join(missing)}, which this Python ({sys.executable}) "
                              "does not have; install it (or carry its wheel, docs/benchmarks/gpu_tensorf.md)")


# --------------------------------------------------------------------------------------------
# The stand-ins
# --------------------------------------------------------------------------------------------


def create_meshgrid(height, width, normalized_coordinates=True, device=None, dtype=None):
    """kornia.utils.create_meshgrid: (1, H, W, 2) pixel grid whose [0, y, x] is (x, y) (or in [-1, 1])."""
    import torch

    xs = torch.linspace(0, width - 1, width, device=device, dtype=dtype)
    ys = torch.linspace(0, height - 1, height, device=device, dtype=dtype)
    if normalized_coordinates:
        xs = (xs / (width - 1) - 0.5) * 2
        ys = (ys / (height - 1) - 0.5) * 2
    grid = torch.stack(torch.meshgrid([xs, ys], indexing="ij"), dim=-1)  # (W, H, 2)
    return grid.permute(1, 0, 2).unsqueeze(0)


class ToTensor:
    """torchvision.transforms.ToTensor for 8-bit PIL images: (C, H, W) float in [0, 1]."""

    def __call__(self, pic):
        import numpy as np
        import torch

        arr = np.array(pic, dtype=np.uint8, copy=True)
        if arr.ndim == 2:
            arr = arr[:, :, None]
        if pic.mode not in ("L", "LA", "RGB", "RGBA", "P"):
            raise ValueError(f"the ToTensor stand-in reads 8-bit images only, not mode {pic.mode!r}")
        return torch.from_numpy(arr).permute(2, 0, 1).contiguous().float().div(255)


class Tqdm:
    """tqdm stand-in: iterates, ignores the bar's options and descriptions."""

    _instances: set = set()

    def __init__(self, iterable=None, *args, **kwargs):
        self.iterable = iterable if iterable is not None else []

    def __iter__(self):
        return iter(self.iterable)

    def set_description(self, *args, **kwargs):
        pass

    def update(self, *args, **kwargs):
        pass

    def close(self):
        pass


class SummaryWriter:
    """torch.utils.tensorboard.SummaryWriter stand-in: accepts and drops every call."""

    def __init__(self, *args, **kwargs):
        pass

    def __getattr__(self, name):
        return lambda *args, **kwargs: None


class ConfigArgParser(argparse.ArgumentParser):
    """configargparse.ArgumentParser without config files (``is_config_file`` is accepted and ignored)."""

    def add_argument(self, *args, **kwargs):
        kwargs.pop("is_config_file", None)
        return super().add_argument(*args, **kwargs)


def _png_write(path, image) -> None:
    import numpy as np
    from PIL import Image

    Image.fromarray(np.asarray(image)).save(path)


class PngOnlyImageio:
    """What TensoRF's ``renderer`` needs of imageio: PNG writes (through PIL); videos are skipped."""

    @staticmethod
    def imwrite(path, image, *args, **kwargs):
        _png_write(path, image)

    @staticmethod
    def mimwrite(*args, **kwargs):
        pass


def _grey_colormap(image, cmap=None):
    import numpy as np

    return np.repeat(np.asarray(image)[..., None], 3, axis=-1)


def _module(name: str, **attrs) -> types.ModuleType:
    mod = types.ModuleType(name)
    # a spec, since torch._dynamo looks up the specs of modules it knows of (tqdm among them)
    mod.__spec__ = importlib.machinery.ModuleSpec(name, None)
    mod.__dict__.update(attrs)
    mod.__dict__["__nerf_bench_standin__"] = True
    return mod


def _standins() -> dict[str, dict[str, types.ModuleType]]:
    """For each importable name TensoRF uses: the stand-in modules to register when it is missing."""
    transforms = _module("torchvision.transforms", ToTensor=ToTensor)
    tqdm_auto = _module("tqdm.auto", tqdm=Tqdm)
    scipy_signal = _module("scipy.signal")
    skimage_measure = _module("skimage.measure")
    return {
        "configargparse": {"configargparse": _module("configargparse", ArgumentParser=ConfigArgParser)},
        "kornia": {"kornia": _module("kornia", create_meshgrid=create_meshgrid)},
        "torchvision.transforms": {"torchvision": _module("torchvision", transforms=transforms),
                                   "torchvision.transforms": transforms},
        "tqdm.auto": {"tqdm": _module("tqdm", tqdm=Tqdm, auto=tqdm_auto), "tqdm.auto": tqdm_auto},
        "torch.utils.tensorboard": {"torch.utils.tensorboard": _module("torch.utils.tensorboard",
                                                                       SummaryWriter=SummaryWriter)},
        "imageio": {"imageio": _module("imageio", imwrite=PngOnlyImageio.imwrite, mimwrite=PngOnlyImageio.mimwrite)},
        "cv2": {"cv2": _module("cv2", COLORMAP_JET=2, applyColorMap=_grey_colormap)},
        "scipy.signal": {"scipy": _module("scipy", signal=scipy_signal), "scipy.signal": scipy_signal},
        "skimage.measure": {"skimage": _module("skimage", measure=skimage_measure), "skimage.measure": skimage_measure},
        "plyfile": {"plyfile": _module("plyfile")},
    }


def install() -> list[str]:
    """Register a stand-in for each optional module that does not import; return their names.

    Raises ``MissingRequired`` first when torch, numpy or PIL is missing.
    """
    check_required()
    used = []
    for name, modules in _standins().items():
        try:
            importlib.import_module(name)
            continue
        except Exception:  # noqa: BLE001 (a broken install, e.g. tensorboard without its deps, is missing too)
            pass
        for mod_name, mod in modules.items():
            if mod_name in sys.modules and not getattr(sys.modules[mod_name], "__nerf_bench_standin__", False):
                # the parent package imported but its submodule did not (torchvision without
                # transforms, scipy without signal): attach the stand-in to the real parent
                continue
            sys.modules[mod_name] = mod
        parent, _, child = name.rpartition(".")
        if parent and parent in sys.modules:
            setattr(sys.modules[parent], child, modules[name])
        used.append(name)
    return used

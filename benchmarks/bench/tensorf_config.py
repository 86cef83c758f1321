"""TensoRF's command line for a benchmark run: its own ``configs/lego.txt``, the schedule scaled, our paths.

TensoRF's lego config (VM-192: ``n_lamb_sigma`` 16x3, ``n_lamb_sh`` 48x3, 128^3 -> 300^3 voxels) trains
30 000 iterations, upsampling at ``[2000, 3000, 4000, 5500, 7000]`` and updating its alpha mask at
``[2000, 4000]``. The issue's comparison runs it for 5 000 iterations with that schedule halved
(``[1000, 1500, 2000, 2750, 3500]`` and ``[1000, 2000]``): ``schedule_scale`` = iterations / 10 000,
so a shorter quick run keeps the same shape. Everything else is the config's; the learning rate decays
to 0.1x over ``n_iters`` as TensoRF does when ``lr_decay_iters`` is -1.

Standard library (+ PIL for ``check_dataset``) only.
"""
from __future__ import annotations

import ast
import json
import os

CONFIG = os.path.join("configs", "lego.txt")
LIST_KEYS = ("upsamp_list", "update_AlphaMask_list")
BLENDER_WIDTH = 800  # TensoRF's blender loader: img_wh = int(800 / downsample)


class ConfigError(ValueError):
    """A config file, dataset or flag TensoRF cannot run with; the message names it."""


def read_config(path: str) -> dict:
    """``key = value`` lines of a configargparse file (``#`` comments); lists as lists, numbers as numbers."""
    values = {}
    try:
        with open(path, encoding="utf-8") as fh:
            lines = fh.readlines()
    except OSError as exc:
        raise ConfigError(f"cannot read TensoRF's config {path}: {exc.strerror}") from None
    for n, line in enumerate(lines, 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        if "=" not in line:
            raise ConfigError(f"{path}:{n}: expected 'key = value', got {line!r}")
        key, value = (s.strip() for s in line.split("=", 1))
        try:
            values[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            values[key] = value  # a bare word (blender, TensorVMSplit, softplus)
    return values


def scaled_schedule(config: dict, n_iters: int) -> dict:
    """``upsamp_list`` and ``update_AlphaMask_list`` scaled by ``n_iters / 10000`` (5000 -> halved)."""
    scale = n_iters / 10000.0
    out = {}
    for key in LIST_KEYS:
        its = [max(1, int(round(i * scale))) for i in config[key]]
        if len(set(its)) != len(its):
            raise ConfigError(f"{n_iters} TensoRF iterations are too few: {key} {config[key]} scaled to {its} "
                              "repeats an iteration")
        out[key] = its
    return out


def build_argv(config: dict, datadir: str, basedir: str, expname: str, n_iters: int, downsample: float,
               eval_every: int, quick: bool = False) -> list[str]:
    """TensoRF's ``train.py`` arguments: the config's values with ours over them, lists as repeated flags.

    ``eval_every`` > 0 evaluates every test view each ``eval_every`` iterations (TensoRF's own
    ``vis_every`` with ``N_vis`` -1); ``render_test`` 1 evaluates them after the last one. ``quick``
    (plumbing tests on a CPU) shrinks the grid to 16^3 -> 32^3 voxels and the batch to 256 rays, and
    keeps every voxel in the alpha mask.
    """
    values = dict(config)
    values.update(scaled_schedule(config, n_iters))
    values.update({"datadir": datadir, "basedir": basedir, "expname": expname, "n_iters": n_iters,
                   "downsample_train": downsample, "dataset_name": "blender", "render_test": 1,
                   "vis_every": eval_every if eval_every > 0 else n_iters + 1,
                   "N_vis": -1 if eval_every > 0 else 0, "progress_refresh_rate": 100})
    if quick:
        # alpha_mask_thre 0: a few dozen iterations learn no density, and an empty alpha mask stops
        # TensoRF (updateAlphaMask: amin of no voxels); 0 keeps every voxel, so the path still runs
        values.update({"N_voxel_init": 16 ** 3, "N_voxel_final": 32 ** 3, "batch_size": 256, "alpha_mask_thre": 0.0})
    argv = []
    for key, value in values.items():
        if key == "config":
            continue
        if isinstance(value, (list, tuple)):
            for item in value:
                argv += [f"--{key}", str(item)]
        else:
            argv += [f"--{key}", str(value)]
    return argv


def check_dataset(datadir: str) -> tuple[int, float]:
    """A dataset TensoRF's blender loader reads right: ``(width, downsample)``, or ``ConfigError``.

    The loader assumes square images ``800 / downsample`` wide (it never resizes once it has set
    ``downsample`` back to 1), RGBA PNGs at ``file_path + '.png'`` and the principal point at the
    centre; it reads ``camera_angle_x`` for the focal length.
    """
    from PIL import Image

    sizes = set()
    for split in ("train", "test"):
        path = os.path.join(datadir, f"transforms_{split}.json")
        try:
            with open(path, encoding="utf-8") as fh:
                meta = json.load(fh)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{path}: cannot read it ({exc})") from None
        if "camera_angle_x" not in meta or not meta.get("frames"):
            raise ConfigError(f"{path}: TensoRF needs camera_angle_x and frames")
        for field, half in (("cx", "w"), ("cy", "h")):
            if field in meta and half in meta and abs(float(meta[field]) - float(meta[half]) / 2) > 1e-3:
                raise ConfigError(f"{path}: {field} = {meta[field]} is off-centre; TensoRF's loader puts the "
                                  "principal point at the image centre")
        frame = meta["frames"][0]
        image = os.path.join(datadir, f"{frame['file_path']}.png")
        try:
            with Image.open(image) as im:
                mode, size = im.mode, im.size
        except OSError as exc:
            raise ConfigError(f"{image} (frame 0 of {path} + '.png', as TensoRF opens it): {exc}") from None
        if mode != "RGBA":
            raise ConfigError(f"{image}: mode {mode}; TensoRF's blender loader needs RGBA (a capture on a "
                              "transparent film, not --opaque)")
        sizes.add(size)
    if len(sizes) != 1:
        raise ConfigError(f"{datadir}: train and test images differ in size ({sorted(sizes)})")
    w, h = sizes.pop()
    downsample = BLENDER_WIDTH / w
    if w != h or int(BLENDER_WIDTH / downsample) != w:
        raise ConfigError(f"{datadir}: {w}x{h} px images; TensoRF's blender loader needs square images whose "
                          f"width W gives int(800 / (800 / W)) == W (200, 100, 400, 800, ...)")
    return w, downsample

"""A COLMAP folder as a dataset, and our cameras as COLMAP cameras (standard library + numpy).

A COLMAP folder holds ``images/`` and a sparse model in ``sparse/0/`` or ``sparse/`` (``.bin`` or
``.txt``, ``contract.colmap_model``). ``colmap_frames(root)`` reads it into the same ``FrameInfo``
records a transforms file gives, so ``load_dataset`` trains on it unchanged:

- cameras: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE, and FULL_OPENCV
  without its rational terms, become ``fl_x fl_y cx cy w h`` and a ``contract.lens.Lens``; any other
  model is refused by name (undistort the images with COLMAP's ``image_undistorter`` first);
- poses: ``colmap_model.pose_from_colmap`` (OpenCV world-to-camera -> our OpenGL camera-to-world);
- splits: the split lists of our own export's manifest (``MANIFEST``) when it is there; else
  nerfstudio's and 3D Gaussian Splatting's rule for COLMAP scenes (``llffhold``): the images sorted by
  name, every ``HOLDOUT_EVERY``-th from the first is test (and val), the rest train;
- scene box: our manifest's ``aabb`` (and ``near``/``far``) when it records one, else the sparse points' 1st-99th
  percentiles padded by ``BOX_PAD`` of their extent on each side (none without points: the loader then
  places it from the cameras); near/far from the points' depths in the images that see them;
- no normalisation: poses and points stay in the reconstruction's own units and frame.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .colmap_model import Camera, ColmapError, Model, find_sparse, pose_from_colmap, read_model
from .errors import PoseError
from .lens import Lens
from .paths import why_not_a_file
from .poses import check_pose
from .transforms import LAYOUT_READERS, SPLITS, FrameInfo, parse_intrinsics

MANIFEST = "nerf_bridge_colmap.json"  # written by our export beside images/ and sparse/
MANIFEST_FORMAT = "nerf_bridge_colmap"
HOLDOUT_EVERY = 8  # 3DGS's llffhold and nerfstudio's eval_interval
BOX_PERCENTILES = (1.0, 99.0)
BOX_PAD = 0.1
READ_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE", "FULL_OPENCV")


# -- cameras ----------------------------------------------------------------------------------------
def camera_intrinsics(cam: Camera, where: str) -> Tuple[Dict[str, float], Optional[Lens]]:
    """({fl_x, fl_y, cx, cy, w, h}, lens or None) of a COLMAP camera; ColmapError for a model not read."""
    p = [float(v) for v in cam.params]
    if cam.model not in READ_MODELS:
        raise ColmapError(f"{where}: camera {cam.id} has model {cam.model}, which is not read (the models read are "
                          f"{', '.join(READ_MODELS)}); undistort the images first (COLMAP's image_undistorter)")
    k = [0.0] * 6  # k1 k2 k3 k4 p1 p2
    if cam.model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        k[:len(p) - 3] = p[3:]
    else:
        fx, fy, cx, cy = p[:4]
        if cam.model == "OPENCV":
            k[0], k[1], k[4], k[5] = p[4:8]
        elif cam.model == "OPENCV_FISHEYE":
            k[:4] = p[4:8]
        elif cam.model == "FULL_OPENCV":
            if any(v != 0.0 for v in p[9:12]):
                raise ColmapError(f"{where}: camera {cam.id} is FULL_OPENCV with rational terms k4-k6 "
                                  f"({p[9]:g}, {p[10]:g}, {p[11]:g}), which are not read; undistort the images first")
            k[0], k[1], k[4], k[5], k[2] = p[4], p[5], p[6], p[7], p[8]
    intr = parse_intrinsics({"fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": cam.width, "h": cam.height},
                            f"{where}: camera {cam.id}")
    if not all(math.isfinite(v) for v in k):
        raise ColmapError(f"{where}: camera {cam.id}: a distortion parameter is not a finite number")
    if cam.model == "OPENCV_FISHEYE":
        return intr, Lens("OPENCV_FISHEYE", tuple(k))
    return intr, (Lens("OPENCV", tuple(k)) if any(k) else None)


def colmap_camera(fx: float, fy: float, cx: float, cy: float, w: int, h: int,
                  lens: Optional[Lens]) -> Tuple[str, Tuple[float, ...]]:
    """(model, params) of our pinhole intrinsics and lens: PINHOLE, OPENCV (k1 k2 p1 p2), FULL_OPENCV
    (with k3), OPENCV_FISHEYE; ValueError for an OPENCV lens with k4, which COLMAP has no model for."""
    if lens is None:
        return "PINHOLE", (fx, fy, cx, cy)
    k1, k2, k3, k4, p1, p2 = lens.coeffs
    if lens.fisheye:
        return "OPENCV_FISHEYE", (fx, fy, cx, cy, k1, k2, k3, k4)
    if k4:
        raise ValueError(f"an OPENCV lens with k4 = {k4:g} has no COLMAP model (FULL_OPENCV's k4 is rational)")
    if k3:
        return "FULL_OPENCV", (fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0)
    return "OPENCV", (fx, fy, cx, cy, k1, k2, p1, p2)


# -- the folder as a dataset ------------------------------------------------------------------------
def read_manifest(root: Path) -> Optional[dict]:
    """Our export's manifest in ``root``, or None (absent, unreadable, or another tool's file)."""
    try:
        meta = json.loads((Path(root) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) and meta.get("format") == MANIFEST_FORMAT else None


def _splits(names: List[str], manifest: Optional[dict]) -> Tuple[Dict[str, str], str]:
    """({image name: split}, a sentence saying which rule gave them)."""
    listed = (manifest or {}).get("images")
    if isinstance(listed, dict) and all(isinstance(v, list) for v in listed.values()):
        where = {str(n): s for s, ns in listed.items() if s in SPLITS for n in ns}
        if any(where.get(n) == "train" for n in names):
            return {n: where.get(n, "train") for n in names}, f"splits as the export recorded them ({MANIFEST})"
    order = sorted(names)
    out = {n: ("test" if k % HOLDOUT_EVERY == 0 else "train") for k, n in enumerate(order)}
    if len(order) < 2:
        out = {n: "train" for n in order}
    return out, (f"COLMAP splits by 3DGS's and nerfstudio's rule: images sorted by name, every {HOLDOUT_EVERY}th "
                 f"from the first ({sum(v == 'test' for v in out.values())} of {len(order)}) held out as test and val")


def _scene(model: Model, poses: Dict[int, np.ndarray], manifest: Optional[dict], images_file: Path,
           recorded: Path) -> dict:
    """The scene fields (``aabb``, ``near``, ``far`` with ``KEY_file``) of a model, as ``frame_infos`` gives them."""
    scene: dict = {"film_transparent": False, "film_transparent_file": images_file}
    if manifest and isinstance(manifest.get("aabb"), list):
        scene["aabb"], scene["aabb_file"] = manifest["aabb"], recorded
    if manifest and all(isinstance(manifest.get(k), (int, float)) for k in ("near", "far")):
        for k in ("near", "far"):
            scene[k], scene[k + "_file"] = manifest[k], recorded
    pts = model.points
    if not len(pts):
        return scene
    if "aabb" not in scene:
        lo, hi = np.percentile(pts.xyz, BOX_PERCENTILES, axis=0)
        pad = BOX_PAD * np.maximum(hi - lo, 1e-6 * max(1.0, float(np.abs(hi).max())))
        points_file = images_file.with_name(images_file.name.replace("images", "points3D"))
        scene["aabb"], scene["aabb_file"] = [(lo - pad).tolist(), (hi + pad).tolist()], points_file
    # (point index, image id) of every observation; without tracks every point counts in every image
    owner = np.concatenate([np.full(len(t), k) for k, t in enumerate(pts.tracks)] + [np.zeros(0, int)]).astype(int)
    seen_by = np.concatenate([t[:, 0] for t in pts.tracks] + [np.zeros(0, np.int64)])
    depths = []
    for iid, c2w in poses.items():
        x = pts.xyz[owner[seen_by == iid]] if len(owner) else pts.xyz
        z = (x - c2w[:3, 3]) @ -c2w[:3, 2]
        depths.append(z[z > 0])
    z = np.concatenate(depths) if depths else np.zeros(0)
    if len(z) and "near" not in scene:
        lo, hi = np.percentile(z, BOX_PERCENTILES)
        scene["near"], scene["near_file"] = float(0.5 * lo), images_file
        scene["far"], scene["far_file"] = float(1.5 * hi), images_file
    return scene


def colmap_frames(root: Path | str, splits: Sequence[str] = SPLITS) -> Tuple[Path, Dict[str, List[FrameInfo]], dict]:
    """(root, {split: [FrameInfo]}, scene) of a COLMAP folder, as ``contract.frame_infos`` gives a transforms
    dataset (rules in the module doc). ``scene["notes"]`` says how the splits were made.

    Raises ColmapError naming the file and the camera or image: a missing, truncated or damaged model
    file, a camera model not read, an image whose camera is missing, whose file is missing, or whose
    pose is not finite, two images of one name.
    """
    root = Path(root)
    sparse = find_sparse(root)
    if sparse is None:
        raise ColmapError(f"{root}: no sparse model (sparse/0/cameras.bin or .txt)")
    model = read_model(sparse)
    images_file = next(sparse.glob("images.*"), sparse / "images.bin")
    manifest = read_manifest(root)
    names = [im.name for im in model.images.values()]
    seen: Dict[str, int] = {}
    for im in model.images.values():
        if im.name in seen:
            raise ColmapError(f"{images_file}: images {seen[im.name]} and {im.id} have the same name {im.name!r}")
        seen[im.name] = im.id
    if not names:
        raise ColmapError(f"{images_file}: the model has no registered images")
    split_of, split_note = _splits(names, manifest)
    cameras_file = str(sparse / images_file.name.replace("images", "cameras"))
    cams: dict = {}  # only the cameras images use are read: an unused camera of another model is no obstacle
    masks = root / "masks"
    our_masks = bool(manifest and manifest.get("masks"))
    # our export's masks are the film's alpha and its images the film on white: together, the RGBA film
    restore = our_masks and manifest.get("background") == [1.0, 1.0, 1.0]
    out: Dict[str, List[FrameInfo]] = {s: [] for s in SPLITS}
    poses = {}
    for im in model.images.values():
        where = f"{images_file}: image {im.id} ({im.name})"
        if not (np.isfinite(im.qvec).all() and np.isfinite(im.tvec).all()) or not np.linalg.norm(im.qvec) > 0:
            raise ColmapError(f"{where}: its pose (qvec {im.qvec.tolist()}, tvec {im.tvec.tolist()}) is not finite")
        try:
            c2w = check_pose(pose_from_colmap(im.qvec, im.tvec), f"{where}: pose")
        except PoseError as exc:
            raise ColmapError(str(exc)) from None
        poses[im.id] = c2w
        image = root / "images" / im.name
        if not image.is_file():
            raise ColmapError(f"{where}: its file {image} {why_not_a_file(image, im.name)}")
        if im.camera_id not in cams:
            cams[im.camera_id] = camera_intrinsics(model.cameras[im.camera_id], cameras_file)
        intr, lens = cams[im.camera_id]
        mask = masks / Path(im.name).with_suffix(".png")
        info = FrameInfo(im.id, images_file, im.name, image, c2w, dict(intr), lens=lens,
                         mask=mask if mask.is_file() and not our_masks else None,
                         alpha=mask if restore and mask.is_file() else None)
        out[split_of[im.name]].append(info)
    # the export's order (the capture's) when its manifest lists the images, else by name as 3DGS sorts them
    listed = (manifest or {}).get("images") if isinstance((manifest or {}).get("images"), dict) else {}
    rank = {n: k for names in listed.values() if isinstance(names, list) for k, n in enumerate(map(str, names))}
    for s in SPLITS:
        out[s].sort(key=lambda f: (rank.get(f.file_path, len(rank)), f.file_path))
    if manifest is None:
        out["val"] = list(out["test"])  # as nerfstudio: the held-out images serve as val and test
    scene = _scene(model, poses, manifest, images_file, root / MANIFEST)
    scene["notes"] = [split_note]
    if restore:
        scene["film_transparent"], scene["film_transparent_file"] = True, root / MANIFEST
        scene["notes"].append(f"{masks}: the film's alpha, as the export wrote it: the images are read as the "
                              "RGBA film (composited onto white by the export), not masked")
    elif our_masks:
        scene["notes"].append(f"{masks}: not read as training masks: the export made them from the film's transparency "
                              "(the images are composited, so every pixel trains)")
    return root, {s: out[s] for s in SPLITS if s in splits or s == "train"}, scene


LAYOUT_READERS["colmap"] = colmap_frames

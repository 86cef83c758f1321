"""nerfstudio's ``colmap`` dataparser reads our COLMAP export, and its cameras look at the scene (issue 57).

    python benchmarks/peer_readers/nerfstudio_colmap.py --dataset DATASET --out DIR --python PY [--setup]

1. ``python -m nerf_core export colmap DATASET --out DIR/colmap`` with this interpreter (the project's,
   the checkout on PYTHONPATH);
2. ``PY _nerfstudio_child.py DIR/colmap DIR/nerfstudio.json``: nerfstudio 1.1.5's
   ``ColmapDataParserConfig(data=DIR/colmap, colmap_path="sparse/0", images_path="images",
   masks_path="masks" (when the export wrote masks), load_3D_points=True, eval_mode="all",
   downscale_factor=1).setup().get_dataparser_outputs(split="train")``, its defaults otherwise
   (orientation "up", centre "poses", auto_scale_poses), written as JSON: image names, fx fy cx cy
   width height, camera_to_worlds (3x4), dataparser_transform and dataparser_scale, number of points;
3. here, against the capture's own ``transforms_train.json`` (``nerf_core.contract.frame_infos``):
   the same image names, intrinsics exact (nerfstudio holds them as float32: ours rounded to float32 must be
   equal), poses equal after undoing the dataparser transform and scale, every camera's optical axis
   through the capture's ``aabb``, every mask file there, and the export's points all loaded.

nerfstudio's rule, from ``colmap_dataparser.py`` (1.1.5): ``c2w = inv([R(qvec) | tvec])`` with columns 1
and 2 negated (COLMAP's OpenCV camera axes to nerfstudio's OpenGL ones, which are ours), then, with
``assume_colmap_world_coordinate_convention``, the world rows permuted (x, z, y) and the new z negated
(``A``); then ``auto_orient_and_center_poses`` (``T``), and the translations times ``s = 1 / max |t|``.
It returns ``dataparser_transform = T @ A`` (3x4, ``applied_transform`` folded in) and
``dataparser_scale = s``, so ``c2w_ns = [D_R C_R | s (D_R C_t + D_t)]`` for our OpenGL camera-to-world
``C`` and ``C = [D_R^T c2w_ns_R | D_R^T (c2w_ns_t / s - D_t)]`` (``contract.nerfstudio_frame.to_dataset_pose``):
no axis flip is left over, because our camera convention is nerfstudio's.

Writes DIR/colmap/ (the export), DIR/nerfstudio.json (the child's output) and DIR/summary.json; the last
stdout line is the summary as JSON. Exit 0 when every check passes, 1 with one ``FAILED:`` line per check
that fails, 2 for bad arguments or a step that did not run.

The environment (``--setup`` builds it at ``--python``'s venv, e.g. ``/work/nsenv/bin/python``):
``python3 -m venv ENV``; ``ENV/bin/pip install --no-deps`` of exactly: nerfstudio==1.1.5 jaxtyping==0.3.11
opencv-python-headless==5.1.0.95 viser==1.1.1 msgspec==0.23.0 websockets==17.4 tensorboard==2.21.0
protobuf==7.36.2 absl-py==2.5.1 appdirs==1.4.4 newrawpy==0.20.0; and a ``.pth`` file in ENV's
site-packages naming the project venv's site-packages (``/work/main/.venv/lib/python3.11/site-packages``:
torch 2.13.0+cpu, numpy 1.26.4, pillow, rich, scipy, scikit-image, matplotlib, ...), which Python puts on
sys.path after ENV's own. That is the import chain of ``nerfstudio.data.dataparsers.colmap_dataparser``
and nothing more (nerfstudio's full requirements, gsplat, nerfacc, tiny-cuda-nn, are not needed to read).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from typing import Dict, List, Optional, Sequence

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [p for p in (REPO, os.path.join(REPO, "scripts")) if p not in sys.path]
import _bootstrap  # noqa: E402,F401  (puts the checkout on sys.path, honours interrupts)
from nerf_core.contract.camera_files import image_size  # noqa: E402
from nerf_core.utils.atomic import write_text_atomic  # noqa: E402
from nerf_core.contract.intrinsics import resolve_intrinsics  # noqa: E402
from nerf_core.contract.nerfstudio_frame import to_dataset_pose  # noqa: E402
from nerf_core.contract.transforms import frame_infos  # noqa: E402

PROG = "nerfstudio_colmap.py"
CHILD = os.path.join(HERE, "_nerfstudio_child.py")
ROTATION_TOLERANCE = 1e-5  # max |entry| of the rotation difference: nerfstudio keeps poses in float32
TRANSLATION_TOLERANCE = 1e-5  # times max(1, largest |camera position|), in scene units
# The packages --setup installs with --no-deps (the import chain of nerfstudio's colmap dataparser),
# on top of the project venv's site-packages (torch, numpy, pillow, rich, ...) reached through a .pth file.
NERFSTUDIO_PACKAGES = ("nerfstudio==1.1.5", "jaxtyping==0.3.11", "opencv-python-headless==5.1.0.95", "viser==1.1.1",
                       "msgspec==0.23.0", "websockets==17.4", "tensorboard==2.21.0", "protobuf==7.36.2",
                       "absl-py==2.5.1", "appdirs==1.4.4", "newrawpy==0.20.0")


def expected_frames(dataset: str) -> tuple[List[dict], np.ndarray]:
    """The capture's train frames as {name, c2w, fx, fy, cx, cy, w, h} (named as ``export colmap`` names
    its images for one split: the frame's stem + ``.png``) and its ``aabb`` (2, 3)."""
    _, _, frames, scene = frame_infos(dataset, splits=("train",))
    if scene.get("aabb") is None:
        raise ValueError(f"{dataset}: the capture has no 'aabb' (the optical-axis check needs the scene box)")
    out = []
    for fr in frames["train"]:
        fx, fy, cx, cy, w, h = resolve_intrinsics(fr.intrinsics, None, image_size(fr.image), fr.where)
        out.append({"name": f"{fr.stem}.png", "c2w": np.asarray(fr.c2w, np.float64),
                    "fx": fx, "fy": fy, "cx": cx, "cy": cy, "w": w, "h": h})
    return out, np.asarray(scene["aabb"], np.float64).reshape(2, 3)


def axis_hits_box(origin: np.ndarray, direction: np.ndarray, aabb: np.ndarray) -> bool:
    """Whether the ray ``origin + t direction``, t > 0, meets the box (slab test; a camera inside counts)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / direction
        t0, t1 = (aabb[0] - origin) * inv, (aabb[1] - origin) * inv
    t0 = np.where(np.isnan(t0), -np.inf, t0)
    t1 = np.where(np.isnan(t1), np.inf, t1)
    near, far = np.minimum(t0, t1).max(), np.maximum(t0, t1).min()
    return bool(far >= max(near, 0.0))


def compare(ns: dict, expected: Sequence[dict], aabb: np.ndarray,
            points: Optional[int] = None) -> tuple[dict, List[str]]:
    """(summary, failures) of nerfstudio's outputs ``ns`` (the child's JSON) against our frames.

    ``expected``: as ``expected_frames``; ``points``: how many points the export wrote (None: not checked).
    """
    failures: List[str] = []
    names = list(ns["image_filenames"])
    by_name: Dict[str, dict] = {e["name"]: e for e in expected}
    missing, extra = sorted(set(by_name) - set(names)), sorted(set(names) - set(by_name))
    if missing or extra or len(names) != len(set(names)):
        failures.append(f"images: nerfstudio read {len(names)} images, the capture has {len(by_name)} train frames; "
                        f"missing {missing[:5]}, extra {extra[:5]}")
    d = np.asarray(ns["dataparser_transform"], np.float64)[:3]
    s = float(ns["dataparser_scale"])
    rot_err = pos_err = 0.0
    worst = None
    bad_intrinsics: List[str] = []
    blind: List[str] = []
    compared = 0
    scale = max(1.0, max((float(np.abs(e["c2w"][:3, 3]).max()) for e in expected), default=1.0))
    for k, name in enumerate(names):
        e = by_name.get(name)
        if e is None:
            continue
        compared += 1
        got = {"fx": ns["fx"][k], "fy": ns["fy"][k], "cx": ns["cx"][k], "cy": ns["cy"][k],
               "w": ns["width"][k], "h": ns["height"][k]}
        for key, value in got.items():
            want = np.float32(e[key]) if key in ("fx", "fy", "cx", "cy") else int(round(e[key]))
            if value != want:
                bad_intrinsics.append(f"{name} {key} {value!r} != {float(want)!r}")
        c2w = np.eye(4)
        c2w[:3] = np.asarray(ns["camera_to_worlds"][k], np.float64)[:3]
        ours = to_dataset_pose(c2w, d, s)
        r = float(np.abs(ours[:3, :3] - e["c2w"][:3, :3]).max())
        p = float(np.abs(ours[:3, 3] - e["c2w"][:3, 3]).max())
        if worst is None or max(r, p / scale) > max(rot_err, pos_err / scale):
            worst = name
        rot_err, pos_err = max(rot_err, r), max(pos_err, p)
        # OpenGL: the camera looks down its -z axis; nerfstudio's pose brought back to the scene's frame
        if not axis_hits_box(ours[:3, 3], -ours[:3, 2], aabb):
            blind.append(name)
    if bad_intrinsics:
        failures.append(f"intrinsics: {len(bad_intrinsics)} values differ, e.g. {bad_intrinsics[:3]}")
    if rot_err > ROTATION_TOLERANCE or pos_err > TRANSLATION_TOLERANCE * scale:
        failures.append(f"poses: after undoing nerfstudio's transform and scale the worst camera ({worst}) is off by "
                        f"{rot_err:.3g} (rotation entries, tolerance {ROTATION_TOLERANCE:g}) and {pos_err:.3g} scene "
                        f"units (tolerance {TRANSLATION_TOLERANCE * scale:.3g})")
    if blind:
        failures.append(f"optical axes: {len(blind)} cameras look past the scene box {aabb.tolist()}: {blind[:5]}")
    got_points = ns.get("num_points3D")
    if points is not None and got_points != points:
        failures.append(f"points: nerfstudio loaded {got_points} points, the export wrote {points}")
    masks = ns.get("mask_filenames")
    if masks is not None:
        absent = [m for m in masks if not os.path.isfile(m)]
        if absent or len(masks) != len(names):
            failures.append(f"masks: {len(masks)} mask paths for {len(names)} images, {len(absent)} absent: "
                            f"{absent[:3]}")
    first = next((e for e in expected if e["name"] in names), None)
    summary = {
        "images": len(names), "expected_images": len(by_name),
        "intrinsics": None if first is None else {k: first[k] for k in ("fx", "fy", "cx", "cy", "w", "h")},
        "intrinsics_exact": not bad_intrinsics,
        "max_rotation_error": rot_err, "max_position_error": pos_err, "worst_camera": worst,
        "cameras_compared": compared, "cameras_looking_at_box": compared - len(blind),
        "points3D": got_points, "masks": None if masks is None else len(masks),
        "dataparser_transform": d.tolist(), "dataparser_scale": s,
        "ok": not failures,
    }
    return summary, failures


def setup_env(python: str) -> None:
    """The venv ``python`` lives in (``ENV/bin/python``), with the packages of ``NERFSTUDIO_PACKAGES``."""
    env = os.path.dirname(os.path.dirname(os.path.abspath(python)))
    if not os.path.exists(python):
        # this interpreter's Python version, so the .pth below names site-packages it can import
        subprocess.run([sys.executable, "-m", "venv", env], check=True)
    site = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    ours = subprocess.run([sys.executable, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    write_text_atomic(os.path.join(site, "zz_project_venv.pth"), ours + "\n")  # after ENV's own site-packages
    # pip talks on stderr: stdout ends with the summary line
    subprocess.run([python, "-m", "pip", "install", "--no-deps", *NERFSTUDIO_PACKAGES], check=True, stdout=sys.stderr)


def parse_args(argv):
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", required=True, help="a capture folder (transforms_train.json with an aabb); read only")
    p.add_argument("--out", required=True, help="new output folder (colmap/, nerfstudio.json, summary.json)")
    p.add_argument("--python", required=True, help="an interpreter that imports nerfstudio (1.1.5)")
    p.add_argument("--setup", action="store_true", help="first create --python's venv with the packages listed above")
    return p.parse_args(argv)


def main(argv=None) -> int:
    a = parse_args(sys.argv[1:] if argv is None else argv)
    out = os.path.abspath(a.out)
    if os.path.exists(out) and (not os.path.isdir(out) or os.listdir(out)):
        _bootstrap.fail(PROG, f"--out {out}: exists and is not an empty folder; name a new one")
    try:
        expected, aabb = expected_frames(a.dataset)
    except Exception as exc:  # noqa: BLE001  (DatasetError and friends: one line)
        _bootstrap.fail(PROG, f"--dataset {a.dataset}: {exc}")
    if a.setup:
        setup_env(a.python)
    os.makedirs(out, exist_ok=True)
    colmap = os.path.join(out, "colmap")
    env = dict(os.environ, PYTHONPATH=REPO + os.pathsep + os.environ.get("PYTHONPATH", ""))
    export_cmd = [sys.executable, "-m", "nerf_core", "export", "colmap", a.dataset, "--out", colmap]
    run = subprocess.run(export_cmd, env=env, capture_output=True, text=True)
    if run.returncode != 0:
        _bootstrap.fail(PROG, f"export colmap failed (exit {run.returncode}): {run.stderr.strip()[-800:]}")
    exported = json.loads(run.stdout.strip().splitlines()[-1])
    ns_json = os.path.join(out, "nerfstudio.json")
    child_cmd = [a.python, CHILD, colmap, ns_json]
    run = subprocess.run(child_cmd, capture_output=True, text=True)
    if run.returncode != 0:
        _bootstrap.fail(PROG, f"nerfstudio's colmap dataparser failed (exit {run.returncode}): "
                              f"{run.stderr.strip()[-1500:]}")
    with open(ns_json) as f:
        ns = json.load(f)
    summary, failures = compare(ns, expected, aabb, points=exported.get("points"))
    summary.update(dataset=os.path.abspath(a.dataset), out=out, nerfstudio=ns.get("nerfstudio_version"),
                   torch=ns.get("torch_version"), options=ns.get("options"), failures=failures,
                   commands=[" ".join(export_cmd), " ".join(child_cmd)])
    write_text_atomic(os.path.join(out, "summary.json"), json.dumps(summary, indent=1))
    for line in failures:
        print(f"FAILED: {line}")
    print(json.dumps(summary))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

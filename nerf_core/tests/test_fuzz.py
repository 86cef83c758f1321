"""Property-based tests (hypothesis): every generated input to a reader ends in its clear error or a
correct result, never another exception, a hang or a crash.

Readers: transforms files and datasets, checkpoints (weights, optimiser state, scalar entries), the
render server's requests and input lines, the CLI's flags, nerfstudio's camera_path.json.

CI runs a small fixed budget (the "ci" profile, derandomised so a run is reproducible); for a longer
hunt: ``HYPOTHESIS_PROFILE=long bash scripts/test.sh nerf_core/tests/test_fuzz.py``.
"""
from __future__ import annotations

import copy
import io
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nerf_core.cameras.camera_path import CameraPathError, cameras_from_camera_path
from nerf_core.cli.main import build_parser
from nerf_core.cli.train import _options
from nerf_core.contract.errors import DatasetError, PoseError
from nerf_core.contract.transforms import SPLITS, frame_infos
from nerf_core.data.loading import load_dataset
from nerf_core.engine.config import TrainConfig
from nerf_core.engine.optim import make_optimizer
from nerf_core.errors import ImageReadError, RunError, TrainError
from nerf_core.render.server import RenderServer, RequestError, parse_request
from nerf_core.runs.checkpoint_checks import check_entries
from nerf_core.runs.checkpoints import model_from_checkpoint, read_checkpoint

settings.register_profile("ci", max_examples=60, deadline=None, derandomize=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
settings.register_profile("long", max_examples=3000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

# JSON values, and numbers that are legal JSON but odd: huge, tiny, negative zero, long integers
ODD_NUMBERS = st.one_of(st.integers(-10 ** 30, 10 ** 30), st.floats(allow_nan=False, allow_infinity=False),
                        st.sampled_from([0, -0.0, 1e308, -1e308, 5e-324, 2 ** 63, 1, -1]))
SCALARS = st.one_of(st.none(), st.booleans(), ODD_NUMBERS, st.text(max_size=12))
JSON = st.recursive(SCALARS, lambda kids: st.one_of(st.lists(kids, max_size=5),
                                                     st.dictionaries(st.text(max_size=8), kids, max_size=5)),
                    max_leaves=20)
MATRIX = st.one_of(JSON, st.lists(st.lists(ODD_NUMBERS, min_size=4, max_size=4), min_size=3, max_size=5),
                   st.lists(ODD_NUMBERS, min_size=16, max_size=16))


def _valid_frame(k):
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, -3.0 - k * 0.1, 0.5]
    return {"file_path": f"./train/r_{k}", "transform_matrix": c2w.tolist()}


# -- transforms files and datasets -----------------------------------------------------------------

FRAME_FIELDS = st.sampled_from(["file_path", "transform_matrix", "fl_x", "fl_y", "cx", "cy", "w", "h",
                                "camera_angle_x", "depth_file_path", "mask_path", "k1", "camera_model"])
TOP_FIELDS = st.sampled_from(["camera_angle_x", "fl_x", "w", "h", "aabb", "near", "far", "frames",
                              "film_transparent", "pixel_filter", "camera_model", "k1", "train_filenames"])


@st.composite
def transforms_doc(draw):
    """A transforms file near a valid one: a valid base with fields replaced, removed or added."""
    doc = {"camera_angle_x": 0.9, "w": 24, "h": 20, "frames": [_valid_frame(k) for k in range(3)]}
    for _ in range(draw(st.integers(0, 4))):
        where = draw(st.sampled_from(["top", "frame", "del", "matrix"]))
        if where == "top":
            doc[draw(TOP_FIELDS)] = draw(JSON)
        elif where == "del" and doc:
            doc.pop(draw(st.sampled_from(sorted(doc))))
        elif isinstance(doc.get("frames"), list) and doc["frames"] and isinstance(doc["frames"][0], dict):
            fr = doc["frames"][draw(st.integers(0, len(doc["frames"]) - 1))]
            if isinstance(fr, dict):
                if where == "matrix":
                    fr["transform_matrix"] = draw(MATRIX)
                else:
                    fr[draw(FRAME_FIELDS)] = draw(JSON)
    return doc


@pytest.fixture(scope="module")
def image_dataset(tmp_path_factory):
    from nerf_core.tests.conftest import make_dataset

    return make_dataset(tmp_path_factory.mktemp("fuzz") / "ds", n_train=3, n_val=1, n_test=1, layouts=("synthetic",))


@given(doc=transforms_doc(), raw=st.one_of(st.none(), st.binary(max_size=40)))
def test_transforms_reader_ends_in_a_dataset_error_or_a_dataset(image_dataset, tmp_path_factory, doc, raw):
    ds = tmp_path_factory.mktemp("case")
    for split in ("train", "val", "test"):
        (ds / split).symlink_to(image_dataset / split)
    for split in ("val", "test"):
        (ds / f"transforms_{split}.json").write_text((image_dataset / f"transforms_{split}.json").read_text())
    text = json.dumps(doc).encode() if raw is None else raw
    (ds / "transforms_train.json").write_bytes(text)
    try:
        frame_infos(ds, SPLITS)
        dataset = load_dataset(ds)
    except (DatasetError, ImageReadError) as exc:
        assert str(exc) and "Traceback" not in str(exc)
        return
    assert len(dataset.split("train")) >= 2 and torch.isfinite(dataset.aabb).all()


# -- checkpoints -------------------------------------------------------------------------------------

TENSORS = st.one_of(
    st.builds(lambda shape, fill: torch.full(shape, fill), st.lists(st.integers(0, 6), max_size=4).map(tuple),
              st.sampled_from([0.0, 1.0, float("nan"), float("inf"), -1e30])),
    st.builds(lambda n: torch.zeros(n, dtype=torch.float64), st.integers(0, 5)),
    st.builds(lambda n: torch.zeros(n, dtype=torch.uint8), st.integers(0, 5)))
VALUES = st.one_of(
    SCALARS, TENSORS, st.lists(SCALARS, max_size=3), st.dictionaries(st.text(max_size=5), SCALARS, max_size=3)
)


@st.composite
def damaged_checkpoint(draw, base):
    ckpt = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        target = draw(st.sampled_from(["entry", "weight", "moment", "rng"]))
        if target == "entry":
            ckpt[draw(st.sampled_from(sorted(ckpt, key=str)))] = draw(VALUES)
        elif target == "weight" and isinstance(ckpt.get("model"), dict) and ckpt["model"]:
            ckpt["model"][draw(st.sampled_from(sorted(ckpt["model"], key=str)))] = draw(TENSORS)
        elif (target == "moment" and isinstance(ckpt.get("optimizer"), dict)
              and isinstance(ckpt["optimizer"].get("state"), dict) and ckpt["optimizer"]["state"]):
            state = ckpt["optimizer"]["state"]
            moments = state[draw(st.sampled_from(sorted(state, key=str)))]
            if isinstance(moments, dict):
                moments[draw(st.sampled_from(["exp_avg", "exp_avg_sq", "step"]))] = draw(TENSORS)
        elif target == "rng" and isinstance(ckpt.get("rng"), dict) and ckpt["rng"]:
            ckpt["rng"][draw(st.sampled_from(sorted(ckpt["rng"], key=str)))] = draw(VALUES)
    return ckpt


@pytest.fixture(scope="module")
def base_checkpoint(trained_run):
    return read_checkpoint(trained_run["run"] / "checkpoints" / "latest.pt")


def test_checkpoints_end_in_a_run_error_or_load_and_step(base_checkpoint):
    @given(ckpt=damaged_checkpoint(base_checkpoint))
    def run(ckpt):
        try:
            check_entries(ckpt, "ck", for_resume=True)
            model = model_from_checkpoint(ckpt, torch.device("cpu"), "ck").train()
            opt = make_optimizer(model, 1e-3)
            opt.check_state(ckpt["optimizer"], "ck")
        except RunError as exc:
            assert str(exc).startswith("ck")
            return
        # Everything checked: the (fused) optimiser may now load and step without writing out of bounds.
        try:
            opt.load_state_dict(ckpt["optimizer"])
        except (ValueError, KeyError):
            return  # the trainer starts Adam afresh here
        for p in model.parameters():
            p.grad = torch.ones_like(p)
        opt.step()
        assert all(torch.isfinite(p).all() for p in model.parameters())

    run()


# -- the render server ---------------------------------------------------------------------------------

REQUEST_FIELDS = st.sampled_from(["id", "c2w", "fx", "fy", "cx", "cy", "w", "h", "out", "depth", "near", "far",
                                  "group", "pixel_filter", "cmd"])


@st.composite
def request_line(draw, out_dir):
    req = {"id": draw(st.integers(0, 9)), "c2w": np.eye(4).tolist(), "fx": 20.0, "fy": 20.0, "w": 8, "h": 6,
           "out": str(out_dir / f"v{draw(st.integers(0, 10 ** 9))}.npy")}
    req["c2w"][2][3] = 3.0
    for _ in range(draw(st.integers(0, 3))):
        key = draw(REQUEST_FIELDS)
        req[key] = draw(MATRIX if key == "c2w" else JSON)
    kind = draw(st.sampled_from(["json", "text", "bytes"]))
    if kind == "json":
        return json.dumps(req, allow_nan=True)
    if kind == "text":
        return draw(st.text(max_size=60))
    return draw(st.binary(max_size=60)).decode("utf-8", errors="surrogateescape")


def test_serve_answers_every_line_with_an_event(trained_run, tmp_path):
    out = io.StringIO()
    server = RenderServer(str(trained_run["run"]), device="cpu", out=out)

    @given(line=request_line(tmp_path))
    def run(line):
        out.seek(0)
        out.truncate()
        try:
            parse_request(json.loads(line))
        except (RequestError, PoseError, ValueError, RecursionError, TypeError, AttributeError):
            pass  # parse_request itself is exercised through handle below; json.loads may fail
        keep_going = server.handle(line.replace("\n", " ") + "\n")
        events = [json.loads(x) for x in out.getvalue().splitlines()]
        if not keep_going:
            return  # {"cmd": "quit"}
        assert events or not line.strip(), line
        assert all(e["event"] in ("result", "error", "skipped", "progress") for e in events), events

    run()


# -- the command line ------------------------------------------------------------------------------

FLAGS = st.sampled_from(["--max-steps", "--max-seconds", "--seed", "--batch-rays", "--downscale", "--lr",
                         "--eval-views", "--eval-at", "--set", "--device", "--background", "--size", "--method",
                         "--log-every", "--checkpoint-every", "--preview-every", "--unbounded", "--resume",
                         "--overwrite", "--progress"])
FLAG_VALUES = st.one_of(st.text(max_size=10), ODD_NUMBERS.map(str),
                        st.sampled_from(["nan", "inf", "-1", "0", "1e400", "unbounded=false", "n=[1,2", "=", "cuda:9",
                                         "meta", "auto", ""]))


def test_train_flags_end_in_a_usage_error_a_train_error_or_a_config(tmp_path):
    parser = build_parser()

    @given(flags=st.lists(st.tuples(FLAGS, FLAG_VALUES), max_size=4))
    def run(flags):
        argv = ["train", "ds", "--out", str(tmp_path / "run")]
        for flag, value in flags:
            argv += [flag] if flag in ("--unbounded", "--resume", "--overwrite") else [flag, value]
        try:
            a = parser.parse_args(argv)
        except SystemExit as exc:
            assert exc.code == 2  # argparse's one usage line
            return
        try:
            cfg = TrainConfig(dataset=a.dataset, out=a.out, method=a.method, max_steps=a.max_steps,
                              max_seconds=a.max_seconds, seed=a.seed, resume=a.resume, overwrite=a.overwrite,
                              size=a.size, options=_options(a), progress=a.progress, device=a.device, lr=a.lr,
                              batch_rays=a.batch_rays, background=a.background, downscale=a.downscale,
                              eval_views=a.eval_views, eval_at=a.eval_at)
            cfg.check()
        except (TrainError, ValueError) as exc:
            assert str(exc)
            return
        assert cfg.max_steps is None or cfg.max_steps > 0
        assert cfg.max_seconds is None or (math.isfinite(cfg.max_seconds) and cfg.max_seconds > 0)

    run()


# -- nerfstudio's camera_path.json ---------------------------------------------------------------------

@st.composite
def camera_path_doc(draw):
    c2w = np.eye(4)
    c2w[2, 3] = 3.0
    cam = {"camera_to_world": c2w.reshape(-1).tolist(), "fov": 50.0, "aspect": 1.5}
    doc = {"render_height": 20, "render_width": 30, "camera_path": [dict(cam), dict(cam)], "seconds": 1}
    for _ in range(draw(st.integers(0, 3))):
        if draw(st.booleans()):
            doc[draw(st.sampled_from(["render_height", "render_width", "camera_path", "fps"]))] = draw(JSON)
        elif (
            isinstance(doc.get("camera_path"), list) and doc["camera_path"] and isinstance(doc["camera_path"][0], dict)
        ):
            key = draw(st.sampled_from(["camera_to_world", "fov", "aspect"]))
            doc["camera_path"][0][key] = draw(MATRIX if key == "camera_to_world" else JSON)
    return doc


@given(doc=camera_path_doc())
def test_camera_paths_end_in_a_camera_path_error_or_cameras(doc):
    try:
        cams, stems = cameras_from_camera_path(doc, Path("camera_path.json"))
    except CameraPathError as exc:
        assert str(exc).startswith("camera_path.json")
        return
    assert len(stems) == cams.c2w.shape[0] >= 1 and torch.isfinite(cams.c2w).all()
    assert bool((cams.fx > 0).all()) and bool((cams.width >= 1).all())

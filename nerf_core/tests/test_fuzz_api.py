"""Property-based tests (hypothesis) of the public API: every function in ``nerf_core.__all__`` gets
valid arguments with one of them replaced by a generated bad value. Each call must end in
ValueError/TypeError naming the function or the argument, in the library's own errors (DatasetError,
RunError, TrainError, ImageReadError, which name the file or field), or in a correct result; never
another exception, a hang, or a non-finite number presented as a result.

The error classes themselves, ``available_methods`` (no arguments), ``TrainConfig`` (a dataclass:
``train`` checks it, and is fuzzed here) and the ``volume`` submodule (its ``stratified_samples`` is
fuzzed; the others are nerfacc-style internals) are the names of ``__all__`` not called directly.
"""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import nerf_core
from nerf_core.contract.errors import DatasetError
from nerf_core.errors import ImageReadError, RunError, TrainError
from nerf_core.volume import stratified_samples

LIBRARY_ERRORS = (DatasetError, RunError, TrainError, ImageReadError)
FUZZ = settings(max_examples=12, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
POSE = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1.0]]

BAD = st.one_of(
    st.none(), st.booleans(), st.integers(-(2 ** 70), 2 ** 70), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=4), st.sampled_from(["\ud800", "", "purple", "../..", "/dev/null"]),
    st.lists(st.floats(allow_nan=True), max_size=4), st.just({}), st.just(object()),
    st.sampled_from([np.zeros((2, 2)), np.full(3, np.nan), torch.zeros(0), torch.full((4, 4, 3), float("inf")),
                     torch.zeros(4, 4, 3, dtype=torch.uint8), torch.ones(2, 3) * -1]),
)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    from nerf_core.tests.conftest import make_dataset

    root = tmp_path_factory.mktemp("fuzz_api")
    ds = make_dataset(root / "ds", n_train=3, n_test=1, w=12, h=12)
    cams = nerf_core.Cameras.create(np.array(POSE)[None], 6.0, 6.0, 3.0, 3.0, 6, 6)
    model = nerf_core.build_model("test-grid", BOX).eval()
    dataset = nerf_core.load_dataset(ds)
    return dict(root=root, ds=ds, cams=cams, model=model, split=dataset.split("train"))


def _calls(w):
    """name -> (function, valid keyword arguments)."""
    a = torch.rand(4, 4, 3)
    return {
        "psnr": (nerf_core.psnr, dict(pred=a, gt=a.clone(), mask=None)),
        "ssim": (nerf_core.ssim, dict(pred=torch.rand(12, 12, 3), gt=torch.rand(12, 12, 3))),
        "depth_mae": (
            nerf_core.depth_mae,
            dict(pred_z=torch.rand(4, 4), gt_z=torch.rand(4, 4) + 0.1, gt_alpha=None, mask=None),
        ),
        "Cameras.create": (
            nerf_core.Cameras.create,
            dict(c2w=np.array(POSE), fx=6.0, fy=6.0, cx=3.0, cy=3.0, width=6, height=6),
        ),
        "build_model": (nerf_core.build_model, dict(name="test-grid", aabb=BOX)),
        "render_view": (
            nerf_core.render_view,
            dict(
                model=w["model"], cameras=w["cams"], view=0, near=None, far=None, background=(1.0, 1.0, 1.0), chunk=64
            ),
        ),
        "rays_for_view": (nerf_core.rays_for_view, dict(cameras=w["cams"], view=0)),
        "stratified_samples": (
            stratified_samples,
            dict(near=torch.zeros(3), far=torch.ones(3), n_samples=4, jitter=False),
        ),
        "RayBatcher": (
            nerf_core.RayBatcher,
            dict(split=w["split"], background="white", gen=torch.Generator(), device=torch.device("cpu")),
        ),
        "evaluate_split": (nerf_core.evaluate_split, dict(model=w["model"], split=w["split"], views=[0], chunk=512)),
        "evaluate_run": (
            nerf_core.evaluate_run,
            dict(run=w["root"] / "no_run", split="test", max_views=None, downscale=None, chunk=64, show_progress=False),
        ),
        "render_run": (
            nerf_core.render_run,
            dict(
                run=w["root"] / "no_run",
                cameras_path=None,
                out=w["root"] / "out",
                split="test",
                chunk=64,
                show_progress=False,
            ),
        ),
        "load_dataset": (nerf_core.load_dataset, dict(path=w["ds"], downscale=1)),
        "load_cameras": (nerf_core.load_cameras, dict(path=w["ds"], split="test")),
        "check_dataset": (nerf_core.check_dataset, dict(path=w["ds"], background="auto", for_training=False)),
        "load_run": (nerf_core.load_run, dict(run=w["root"] / "no_run", device=torch.device("cpu"), checkpoint=None)),
        "open_run": (nerf_core.open_run, dict(path=w["root"] / "no_run", device="cpu", checkpoint=None)),
        "register": (nerf_core.register, dict(name="fuzz-method", replace=False)),
        "train": (
            lambda **kw: nerf_core.train(nerf_core.TrainConfig(**kw)),
            # no dataset there: the fields are checked first, then loading it stops the run (fast)
            dict(
                dataset=str(w["root"] / "no_dataset"),
                out=str(w["root"] / "never"),
                method="test-grid",
                max_steps=1,
                log_every=1,
                chunk=64,
                preview_size=8,
                eval_views=0,
                show_bar=False,
                stdout_events=False,
                options={},
                dataset_moved=True,
                overwrite=False,
            ),
        ),
    }


CASES = [(name, arg) for name, (_, kw) in _calls({"root": Path("."), "ds": None, "cams": None, "model": None,
                                                   "split": None}).items() for arg in kw]


def _finite_result(value) -> bool:
    """No NaN presented as a result (psnr's inf for identical images is documented, and correct)."""
    if isinstance(value, float):
        return not math.isnan(value)
    if isinstance(value, torch.Tensor) and value.is_floating_point():
        return bool(torch.isfinite(value).all())
    if isinstance(value, (tuple, list)):
        return all(_finite_result(v) for v in value)
    if isinstance(value, dict):
        return all(_finite_result(v) for k, v in value.items() if k not in ("psnr",))
    return True


def test_every_public_function_is_fuzzed():
    called = {name.split(".")[0] for name, _ in CASES} | {"TrainConfig", "available_methods", "volume", "__version__"}
    errors = {n for n in nerf_core.__all__ if n.endswith("Error") or n == "CheckpointRefused"}
    assert set(nerf_core.__all__) - errors - called == {"Dataset", "Split", "RadianceModel", "Run"}  # classes


@pytest.mark.parametrize("name, arg", CASES)
def test_bad_arguments_end_in_a_named_error_or_a_correct_result(world, name, arg):
    func, valid = _calls(world)[name]

    never = world["root"] / "never"  # train's run folder: made only by a run that starts

    @FUZZ
    @given(bad=BAD)
    def check(bad):
        kw = dict(valid, **{arg: bad})
        shutil.rmtree(never, ignore_errors=True)  # a bad value that is a valid one trains; the next starts anew
        try:
            result = func(**kw)
        except TrainError as exc:
            if str(exc).startswith("TrainConfig."):  # a field refused: before the run folder is made
                assert not never.exists(), str(exc)
            return
        except (ValueError, TypeError) as exc:
            text = str(exc)
            assert arg.split("_")[0] in text or name.split(".")[0] in text or "must" in text, (name, arg, bad, text)
            return
        except LIBRARY_ERRORS:
            return
        if name == "register":
            assert callable(result)
            return
        assert _finite_result(result), (name, arg, bad, result)

    check()

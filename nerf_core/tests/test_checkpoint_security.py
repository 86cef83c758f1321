"""Checkpoints never run code: a crafted ``latest.pt`` is refused with one clear line, while the
checkpoints the trainer writes (and those of older runs, with numpy RNG state) still load."""
import json
import os
import pickle
import subprocess
import sys
import types

import numpy as np
import pytest
import torch

from nerf_core.engine.config import TrainConfig
from nerf_core.engine.trainer import train
from nerf_core.errors import RunError
from nerf_core.runs.checkpoints import read_checkpoint
from nerf_core.utils.seeding import rng_state, set_rng_state

# torch 2.6 added the helper these tests inspect checkpoints with (the library supports torch 2.5, where
# everything else in this file runs; CI's torch 2.13 runs all of it).
needs_torch_2_6 = pytest.mark.skipif(not hasattr(torch.serialization, "get_unsafe_globals_in_checkpoint"),
                                     reason="torch < 2.6: no torch.serialization.get_unsafe_globals_in_checkpoint")

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class Payload:
    """Unpickling this calls ``func(*args)``: what a malicious checkpoint does."""

    def __init__(self, func, *args):
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args


class Note:
    """An ordinary class: harmless here, but a checkpoint must not build arbitrary classes either."""

    def __init__(self):
        self.text = "hello"


def _writes_marker(marker):
    return Payload(exec, f"open({str(marker)!r}, 'w').write('pwned')")


PAYLOADS = {
    "os.system": lambda m: Payload(os.system, f"touch '{m}'"),
    "builtins.exec": _writes_marker,
    "subprocess": lambda m: Payload(subprocess.call, ["touch", str(m)]),
    "class": lambda m: Note(),
}


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest")
    return subprocess.run([sys.executable, "-m", "nerf_core", *args], capture_output=True, text=True, cwd=REPO_ROOT,
                          env=env, timeout=180)


# ----------------------------------------------------------------------------------------------
# refused


@pytest.mark.parametrize("kind", sorted(PAYLOADS))
def test_a_checkpoint_with_code_is_refused_without_running_it(run_copy, tmp_path, kind):
    marker = tmp_path / "MARKER"
    ck = run_copy / "checkpoints" / "latest.pt"
    real = read_checkpoint(ck)
    torch.save({**real, "step": PAYLOADS[kind](marker)}, ck)  # a real checkpoint with one poisoned entry
    with pytest.raises(RunError) as err:
        read_checkpoint(ck)
    msg = str(err.value)
    assert msg.startswith(f"{ck}: refused") and "not plain tensors" in msg and "will not be loaded" in msg
    assert "weights_only=False" not in msg  # torch's advice to load it unsafely must not be passed on
    assert not marker.exists()


def test_a_plain_pickle_with_code_is_refused_too(tmp_path):
    marker, ck = tmp_path / "MARKER", tmp_path / "latest.pt"
    with open(ck, "wb") as f:  # not torch.save's zip: torch.load unpickles it directly
        pickle.dump({"model": _writes_marker(marker)}, f, protocol=2)
    with pytest.raises(RunError, match="refused.*not plain tensors"):
        read_checkpoint(ck)
    assert not marker.exists()


def test_a_damaged_checkpoint_is_a_clear_error(tmp_path):
    ck = tmp_path / "latest.pt"
    ck.write_bytes(b"\x80\x02}q\x00(X\x05")  # a truncated pickle
    with pytest.raises(RunError, match="cannot read checkpoint") as err:
        read_checkpoint(ck)
    assert str(err.value).startswith(str(ck)) and "weights_only=False" not in str(err.value)


@pytest.mark.parametrize("command", ["eval", "render", "resume"])
def test_cli_refuses_a_malicious_checkpoint_in_one_line(run_copy, trained_run, tmp_path, command):
    marker = tmp_path / "MARKER"
    ck = run_copy / "checkpoints" / "latest.pt"
    torch.save({**read_checkpoint(ck), "model": Payload(os.system, f"touch '{marker}'")}, ck)
    events_before = (run_copy / "progress.jsonl").read_text()
    args = {
        "eval": ["eval", str(run_copy), "--no-bar"],
        "render": ["render", str(run_copy), "--cameras", str(trained_run["dataset"] / "transforms_test.json"),
                   "--out", str(tmp_path / "renders"), "--no-bar"],
        "resume": ["train", str(trained_run["dataset"]), "--out", str(run_copy), "--resume", "--max-steps", "40",
                   "--no-bar"],
    }[command]
    proc = _cli(*args)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr + proc.stdout
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith(f"nerf_core {args[0]}: error: {ck}: refused") and "not plain tensors" in last
    assert not marker.exists()
    if command == "resume":
        event = json.loads(proc.stdout.strip().splitlines()[-1])
        assert event["event"] == "error" and str(ck) in event["message"]
        assert (run_copy / "progress.jsonl").read_text() == events_before  # the refused resume wrote nothing
        assert not (run_copy / ".lock").exists()


# ----------------------------------------------------------------------------------------------
# still loaded


@needs_torch_2_6
def test_the_trainers_checkpoints_need_no_allowlist(trained_run):
    ck = trained_run["run"] / "checkpoints" / "latest.pt"
    assert torch.serialization.get_unsafe_globals_in_checkpoint(ck) == []
    state = torch.load(ck, weights_only=True)  # torch's own allowlist, nothing added
    assert state["step"] == 30 and isinstance(state["rng"]["numpy"]["key"], torch.Tensor)
    assert type(state["versions"]["torch"]) is str


def test_numpy_rng_state_round_trips_through_a_checkpoint(run_copy):
    ck = read_checkpoint(run_copy / "checkpoints" / "latest.pt")
    np.random.seed(7)
    np.random.standard_normal()  # leaves a cached gaussian in the state
    expected = np.random.get_state()
    saved = rng_state(torch.Generator())
    after = np.random.standard_normal(4)
    torch.save({**ck, "rng": saved}, run_copy / "checkpoints" / "latest.pt")
    np.random.seed(99)
    set_rng_state(read_checkpoint(run_copy / "checkpoints" / "latest.pt")["rng"], torch.Generator())
    got = np.random.get_state()
    assert got[0] == expected[0] and np.array_equal(got[1], expected[1]) and got[2:] == expected[2:]
    np.testing.assert_array_equal(np.random.standard_normal(4), after)


def _old_format(ck: dict, numpy_state) -> dict:
    """``ck`` as trainers before weights-only checkpoints wrote it: numpy RNG state and TorchVersion."""
    from torch.torch_version import TorchVersion

    old = {**ck, "rng": {**ck["rng"], "numpy": numpy_state}}
    old["versions"] = {**ck["versions"], "torch": TorchVersion(torch.__version__)}
    old["config"] = {**ck["config"], "versions": dict(old["versions"])}
    return old


@needs_torch_2_6
def test_an_old_checkpoint_with_numpy_rng_state_still_loads_and_resumes(run_copy, trained_run):
    path = run_copy / "checkpoints" / "latest.pt"
    numpy_state = np.random.RandomState(123).get_state()
    torch.save(_old_format(read_checkpoint(path), numpy_state), path)
    needs = set(torch.serialization.get_unsafe_globals_in_checkpoint(path))
    assert {"numpy.ndarray", "torch.torch_version.TorchVersion"} <= needs  # it really is the old format
    ck = read_checkpoint(path)
    set_rng_state(ck["rng"], torch.Generator())
    assert np.array_equal(np.random.get_state()[1], numpy_state[1])
    out = train(TrainConfig(dataset=str(trained_run["dataset"]), out=str(run_copy), method="test-grid", max_steps=33,
                            batch_rays=256, resume=True, stdout_events=False, show_bar=False, eval_views=0))
    assert out["step"] == 33
    assert torch.serialization.get_unsafe_globals_in_checkpoint(path) == []  # rewritten in the new format


class _Numpy2Pickler(pickle._Pickler):
    """Names numpy's array constructor as numpy 2 does (``numpy._core``), whatever numpy is installed."""

    def save_global(self, obj, name=None):
        if getattr(obj, "__name__", None) == "_reconstruct" and "multiarray" in getattr(obj, "__module__", ""):
            self.write(pickle.GLOBAL + b"numpy._core.multiarray\n_reconstruct\n")
            self.memoize(obj)
            return
        super().save_global(obj, name)


@needs_torch_2_6
def test_an_old_checkpoint_written_under_numpy_2_also_loads(run_copy):
    path = run_copy / "checkpoints" / "latest.pt"
    numpy_state = np.random.RandomState(5).get_state()
    torch.save(_old_format(read_checkpoint(path), numpy_state), path,
               pickle_module=types.SimpleNamespace(__name__="numpy2_pickle", Pickler=_Numpy2Pickler))
    assert "numpy._core.multiarray._reconstruct" in torch.serialization.get_unsafe_globals_in_checkpoint(path)
    assert np.array_equal(read_checkpoint(path)["rng"]["numpy"][1], numpy_state[1])

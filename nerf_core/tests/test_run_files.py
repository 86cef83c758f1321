"""A run's own files against foreign or damaged ones (docs/RELIABILITY.md, "run files"): checkpoints
that are not ours, another run's checkpoint, a damaged metrics.json and a dataset that changed
after training. Each is named in one line; none is a traceback, and no score is filed under the
wrong run."""
import json
import os
import subprocess
import sys

import pytest
import torch

from nerf_core.engine.config import TrainConfig
from nerf_core.engine.trainer import train
from nerf_core.errors import RunError
from nerf_core.evaluation.evaluate import evaluate_run
from nerf_core.runs.checkpoints import load_run, read_checkpoint

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest")
    return subprocess.run([sys.executable, "-m", "nerf_core", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO_ROOT, env=env, timeout=180)


def _edited_checkpoint(run, tmp_path, **entries):
    ckpt = read_checkpoint(run / "checkpoints" / "latest.pt")
    ckpt.update(entries)
    path = tmp_path / "edited.pt"
    torch.save(ckpt, path)
    return path


# ---------------------------------------------------------------------------------------------- checkpoints


@pytest.mark.parametrize("entries, words", [
    ({"options": [1, 2]}, "entry 'options' must be a dict"),
    ({"aabb": "x"}, "entry 'aabb' must be the scene box"),
    ({"aabb": [[0, 0], [1, 1]]}, "entry 'aabb' must be the scene box"),
    ({"aabb": [[0, 0, 0], [1, 1, float("nan")]]}, "entry 'aabb' must be the scene box"),
    ({"model": [1, 2]}, "entry 'model' must be the model's weights"),
    ({"model": {"w": "x"}}, "entry 'model' must be the model's weights"),
    ({"method": 3}, "entry 'method' must be a method name"),
    ({"options": {"no_such_option": 1}}, "unknown options"),
])
def test_a_checkpoint_with_entries_of_the_wrong_kind_is_named(run_copy, tmp_path, entries, words):
    ck = _edited_checkpoint(run_copy, tmp_path, **entries)
    with pytest.raises(RunError, match=words) as err:
        load_run(run_copy, torch.device("cpu"), ck)
    assert str(err.value).startswith(str(ck))


@pytest.mark.parametrize("content, words", [
    (b"", "the file is empty"),
    (b"hello, this is a note\n", "it holds text"),
    (b"\x89PNG\r\n\x1a\n....", "not a file written by torch.save"),
])
def test_a_file_that_is_no_checkpoint_says_what_it_is(tmp_path, content, words):
    path = tmp_path / "latest.pt"
    path.write_bytes(content)
    with pytest.raises(RunError, match=words):
        read_checkpoint(path)


def test_a_folder_given_as_checkpoint_is_called_a_folder(run_copy):
    with pytest.raises(RunError, match="is a folder; give a checkpoint file"):
        read_checkpoint(run_copy / "checkpoints")


def test_a_truncated_checkpoint_message_leaves_out_torchs_advice(run_copy):
    ck = run_copy / "checkpoints" / "latest.pt"
    ck.write_bytes(ck.read_bytes()[: ck.stat().st_size // 2])
    with pytest.raises(RunError) as err:
        read_checkpoint(ck)
    assert "cannot read checkpoint" in str(err.value) and "miniz" not in str(err.value)


def test_another_runs_checkpoint_is_refused_and_files_no_metrics(run_copy, dataset_factory, tmp_path):
    other = tmp_path / "other"
    train(
        TrainConfig(
            dataset=str(dataset_factory(tmp_path / "ds", n_train=5)),
            out=str(other),
            method="vmgrid",
            max_steps=2,
            batch_rays=64,
            seed=0,
            stdout_events=False,
            show_bar=False,
            eval_views=0,
        )
    )
    before = (run_copy / "metrics.json").read_bytes()
    proc = _cli("eval", run_copy, "--checkpoint", other / "checkpoints" / "latest.pt", "--no-bar")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "belongs to another run" in last and "method 'vmgrid'" in last and "another dataset" in last
    assert (run_copy / "metrics.json").read_bytes() == before
    proc = _cli("render", run_copy, "--checkpoint", other / "checkpoints" / "latest.pt", "--out", tmp_path / "r",
                "--no-bar")
    assert proc.returncode == 2 and "belongs to another run" in proc.stderr and not (tmp_path / "r").exists()


def test_an_older_checkpoint_of_the_same_run_still_evaluates(run_copy):
    step_file = sorted((run_copy / "checkpoints").glob("step_*.pt"))[0]
    summary = evaluate_run(run_copy, checkpoint=step_file, print_fn=lambda *_: None, show_progress=False)
    assert summary["step"] == read_checkpoint(step_file)["step"]


# ---------------------------------------------------------------------------------------------- metrics.json


@pytest.mark.parametrize("content, words", [("[]", "got a list"), ('{"psnr": 3', "not readable as JSON")])
def test_a_damaged_metrics_file_is_refused_before_evaluating(run_copy, content, words):
    (run_copy / "metrics.json").write_text(content)
    shown = []
    with pytest.raises(RunError, match=words) as err:
        evaluate_run(run_copy, print_fn=shown.append, show_progress=False)
    assert str(err.value).startswith(str(run_copy / "metrics.json"))
    assert shown == []  # refused first: no minutes of evaluation thrown away
    assert (run_copy / "metrics.json").read_text() == content  # and the file is left as it was


def test_a_progress_log_that_is_a_folder_is_refused_before_evaluating(run_copy):
    (run_copy / "progress.jsonl").unlink()
    (run_copy / "progress.jsonl").mkdir()
    before = (run_copy / "metrics.json").read_bytes()
    with pytest.raises(RunError, match="progress.jsonl: is a folder"):
        evaluate_run(run_copy, print_fn=lambda *_: None, show_progress=False)
    assert (run_copy / "metrics.json").read_bytes() == before


def test_a_resumed_training_keeps_a_damaged_metrics_file_aside(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    cfg = dict(dataset=str(sphere_dataset), out=str(run), method="test-grid", batch_rays=64, seed=0,
               stdout_events=False, show_bar=False, eval_views=1)
    train(TrainConfig(max_steps=3, **cfg))
    (run / "metrics.json").write_text("[1, 2]")
    train(TrainConfig(max_steps=5, resume=True, **cfg))
    assert (run / "metrics.json.damaged").read_text() == "[1, 2]"
    assert json.loads((run / "metrics.json").read_text())["step"] == 5


# ---------------------------------------------------------------------------------------------- the dataset


def test_eval_and_render_note_a_dataset_that_changed_since_training(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(TrainConfig(dataset=str(sphere_dataset), out=str(run), method="test-grid", max_steps=3, batch_rays=64,
                      seed=0, stdout_events=False, show_bar=False, eval_views=0))
    proc = _cli("eval", run, "--no-bar")
    assert proc.returncode == 0 and "changed since the run trained" not in proc.stderr
    test_file = sphere_dataset / "transforms_test.json"
    data = json.loads(test_file.read_text())
    data["frames"][0]["transform_matrix"][0][3] += 0.5  # a new capture written over the old one
    test_file.write_text(json.dumps(data))
    # `render --cameras` of the dataset's own file, as the add-on's Compare runs it, was silent
    for args in (["eval", run], ["render", run, "--out", tmp_path / "renders"],
                 ["render", run, "--cameras", test_file, "--out", tmp_path / "compare"]):
        proc = _cli(*args, "--no-bar")
        assert proc.returncode == 0, proc.stderr
        assert "changed since the run trained on it" in proc.stderr and str(sphere_dataset.resolve()) in proc.stderr
    # ...and renders.json carries it, for the add-on to show beside the imported scores
    assert (
        "changed since the run trained on it"
        in json.loads((tmp_path / "compare" / "renders.json").read_text())["notes"][0]
    )
    other = tmp_path / "cams.json"  # cameras of the user's own: no dataset of the run's involved
    other.write_text(json.dumps({"camera_angle_x": 0.7, "w": 8, "h": 8, "frames": [data["frames"][0]]}))
    proc = _cli("render", run, "--cameras", other, "--out", tmp_path / "own", "--no-bar")
    assert proc.returncode == 0 and "changed since" not in proc.stderr, proc.stderr

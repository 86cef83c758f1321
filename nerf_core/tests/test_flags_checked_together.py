"""Flags are checked for what they name and against each other before anything is written, and the
render server survives bytes that are not UTF-8 (docs/RELIABILITY.md, cases 193-198)."""
import json
import os
import subprocess
import sys

import numpy as np

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _cli(*args, stdin=None):
    env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "nerf_core", *args], capture_output=True, cwd=REPO_ROOT, env=env,
                          timeout=180, input=stdin, text=stdin is None or isinstance(stdin, str))


def _refused(proc, *words):
    err = proc.stderr if isinstance(proc.stderr, str) else proc.stderr.decode()
    assert proc.returncode == 2 and "Traceback" not in err, err
    for w in words:
        assert w in err, err


def _train(ds, run, *flags):
    return _cli("train", str(ds), "--out", str(run), "--method", "test-grid", "--batch-rays", "64", "--no-bar", *flags)


def test_devices_nothing_runs_on_are_refused_before_a_run_folder_exists(sphere_dataset, tmp_path):
    for name in ("meta", "xla", "hpu"):
        run = tmp_path / f"run_{name}"
        _refused(_train(sphere_dataset, run, "--max-steps", "2", "--device", name),
                 f"--device {name}: nerf_core trains and renders on cpu, cuda, mps devices")
        assert not run.exists()
    _refused(_cli("eval", str(tmp_path / "nothing"), "--device", "meta"))


def test_unbounded_flag_and_set_unbounded_false_disagree(sphere_dataset, tmp_path):
    _refused(_train(sphere_dataset, tmp_path / "run", "--max-steps", "2", "--unbounded", "--set", "unbounded=false"),
             "--unbounded and --set unbounded=False disagree")
    # The option's old spellings (``--contract``, ``--set contract=...``) still mean the same.
    _refused(_train(sphere_dataset, tmp_path / "run", "--max-steps", "2", "--contract", "--set", "contract=false"),
             "--unbounded and --set unbounded=False disagree")
    _refused(_train(sphere_dataset, tmp_path / "run", "--set", "contract=true", "--set", "unbounded=false"),
             "'contract' is the old name of 'unbounded'")
    assert not (tmp_path / "run").exists()


def test_eval_at_beyond_the_time_budget_is_refused(sphere_dataset, tmp_path):
    _refused(_train(sphere_dataset, tmp_path / "run", "--max-seconds", "30", "--eval-at", "10,1000"),
             "--eval-at 1000 lies beyond --max-seconds 30")
    assert not (tmp_path / "run").exists()


def test_eval_at_after_the_step_budget_is_said(sphere_dataset, tmp_path):
    proc = _train(sphere_dataset, tmp_path / "run", "--max-steps", "3", "--eval-at", "1000", "--eval-views", "0")
    assert proc.returncode == 0, proc.stderr
    assert "--eval-at 1000: training ended after" in proc.stderr and "nothing was evaluated there" in proc.stderr
    notes = [json.loads(x) for x in proc.stdout.splitlines() if '"note"' in x]
    assert any("--eval-at 1000" in n["message"] for n in notes)


def test_progress_inside_the_new_run_folder_is_refused_on_every_try(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    for _ in range(2):  # before, the first try made RUN/progress.jsonl and every retry found RUN not empty
        _refused(_train(sphere_dataset, run, "--max-steps", "2", "--progress", str(run / "progress.jsonl")),
                 "lies inside --out", "writes")
        assert not run.exists()


def test_serve_answers_after_a_line_that_is_not_utf8(trained_run, tmp_path):
    c2w = np.eye(4)
    c2w[2, 3] = 3.0
    req = {"id": 2, "c2w": c2w.tolist(), "fx": 22.0, "fy": 20.0, "w": 24, "h": 18, "out": str(tmp_path / "v.npy")}
    stdin = b'{"id": 1, "c2w": "\xff\xfe"}\n' + json.dumps(req).encode() + b"\n"  # then EOF
    proc = _cli("serve", str(trained_run["run"]), stdin=stdin)
    assert proc.returncode == 0, proc.stderr
    events = [json.loads(x) for x in proc.stdout.decode().splitlines()]
    errors = [e for e in events if e["event"] == "error"]
    assert errors and "input line is not UTF-8" in errors[0]["message"]
    assert any(e["event"] == "result" and e["id"] == 2 for e in events), events
    assert (tmp_path / "v.npy").is_file()


def test_images_too_small_to_score_are_refused_before_training(sphere_dataset, tmp_path):
    # 24x20 px at --downscale 4: 6x5, below SSIM's 11x11 window. Before, training ran to its end and
    # then failed with "ssim needs 11x11", naming no flag and writing no metrics.
    run = tmp_path / "run"
    _refused(_train(sphere_dataset, run, "--max-steps", "2", "--downscale", "4"),
             "the test images are 6x5 px at --downscale 4", "--eval-views 0")
    assert not run.exists()
    proc = _train(sphere_dataset, run, "--max-steps", "2", "--downscale", "4", "--eval-views", "0")
    assert proc.returncode == 0, proc.stderr  # training without evaluation is fine


def test_train_frames_that_repeat_one_view_get_a_note(dataset_factory, tmp_path):
    ds = dataset_factory(tmp_path / "ds", layouts=("synthetic",))
    meta = json.loads((ds / "transforms_train.json").read_text())
    meta["frames"] = meta["frames"] + [meta["frames"][0]] * 300
    (ds / "transforms_train.json").write_text(json.dumps(meta))
    from nerf_core.data.loading import load_dataset

    notes = load_dataset(ds).notes
    assert any("the 308 train frames show 8 distinct views (300 repeat another frame's image and pose)" in n
               for n in notes), notes
    meta["frames"] = [meta["frames"][0]] * 3000  # one view, many times: still one view
    (ds / "transforms_train.json").write_text(json.dumps(meta))
    _refused(_train(ds, tmp_path / "run", "--max-steps", "2"), "the train split has 1 view")


def test_hdr_train_images_get_a_note(dataset_factory, tmp_path):
    from nerf_core.data.loading import load_dataset
    from nerf_core.image.io import read_exr_rgba, write_exr

    ds = dataset_factory(tmp_path / "ds", layouts=("synthetic",), exr_images=True)
    img = ds / "train" / "r_0.exr"
    rgba = read_exr_rgba(img)
    rgba[..., :3] *= 4.0  # a bright HDR render: values up to 4
    write_exr(img, {c: rgba[..., j] for j, c in enumerate("RGBA")})
    notes = load_dataset(ds).notes
    assert any("r_0.exr" in n and "exceed 1.0 (HDR" in n for n in notes), notes
    assert not any("HDR" in n for n in load_dataset(dataset_factory(tmp_path / "png")).notes)


def test_a_run_config_with_far_before_near_is_refused(run_copy, tmp_path):
    cfg = json.loads((run_copy / "config.json").read_text())
    cfg["near"], cfg["far"] = 5.0, 1.0
    (run_copy / "config.json").write_text(json.dumps(cfg))
    _refused(_cli("eval", str(run_copy), "--no-bar"), "field 'far' (1.0) must be greater than field 'near' (5.0)")


def test_an_unknown_pixel_filter_in_a_run_is_said(run_copy, tmp_path):
    cfg = json.loads((run_copy / "config.json").read_text())
    cfg["pixel_filter"] = {"type": "MITCHELL", "width": 1.5}
    (run_copy / "config.json").write_text(json.dumps(cfg))
    proc = _cli("render", str(run_copy), "--out", str(tmp_path / "views"), "--no-bar")
    assert proc.returncode == 0, proc.stderr
    assert "pixel_filter" in proc.stderr and "rendering through Blender's default filter" in proc.stderr


def test_a_progress_log_cut_mid_line_gets_the_next_event_on_its_own_line(tmp_path):
    from nerf_core.runs.events import EventLog, read_events

    log = tmp_path / "progress.jsonl"
    log.write_text('{"event": "start", "time": 1.0}\n{"event": "step", "ti')  # a trainer killed mid-write
    EventLog([log], stdout=False).emit("start", resumed_from=8)
    lines = log.read_text().splitlines()
    assert lines[-2] == '{"event": "step", "ti' and json.loads(lines[-1])["resumed_from"] == 8
    assert [e["event"] for e in read_events(log)][-1] == "start"


def test_a_run_whose_latest_is_gone_renders_from_its_newest_step_file(run_copy, tmp_path):
    (run_copy / "checkpoints" / "latest.pt").unlink()
    proc = _cli("eval", str(run_copy), "--no-bar")
    assert proc.returncode == 0, proc.stderr
    assert "latest.pt is missing; using the newest complete checkpoint, step_" in proc.stderr

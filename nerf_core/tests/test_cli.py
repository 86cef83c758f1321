"""The command line: help, import without bpy, and one-line errors with non-zero exits."""
import json
import os
import subprocess
import sys

import pytest

from nerf_core.cli.main import build_parser, main

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _run(*args, **env):
    e = dict(os.environ, PYTHONPATH=REPO_ROOT, **env)
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=REPO_ROOT, env=e, timeout=120)


def test_help_and_no_bpy_import():
    proc = _run("-c", "import sys, runpy; sys.argv = ['nerf_core', '--help']\n"
                      "try:\n    runpy.run_module('nerf_core', run_name='__main__')\n"
                      "except SystemExit as e:\n    assert e.code == 0\n"
                      "import nerf_core.engine.trainer, nerf_core.render.views, nerf_core.check.dataset\n"
                      "assert 'bpy' not in sys.modules, 'nerf_core imported bpy'")
    assert proc.returncode == 0, proc.stderr
    for word in ("train", "render", "eval", "check", "examples"):
        assert word in proc.stdout


def test_stable_flags_parse():
    p = build_parser()
    a = p.parse_args(
        [
            "train",
            "ds",
            "--out",
            "r",
            "--method",
            "m",
            "--max-seconds",
            "5",
            "--max-steps",
            "9",
            "--seed",
            "3",
            "--resume",
            "--size",
            "auto",
            "--progress",
            "f.jsonl",
            "--set",
            "x=1",
        ]
    )
    assert (
        a.dataset,
        a.out,
        a.method,
        a.max_seconds,
        a.max_steps,
        a.seed,
        a.resume,
        a.size,
        a.progress,
        a.options,
    ) == ("ds", "r", "m", 5.0, 9, 3, True, "auto", "f.jsonl", ["x=1"])
    r = p.parse_args(["render", "run", "--cameras", "t.json", "--out", "d", "--split", "val"])
    assert (r.run, r.cameras, r.out, r.split) == ("run", "t.json", "d", "val")
    e = p.parse_args(["eval", "run", "--split", "test"])
    assert e.split == "test"
    with pytest.raises(SystemExit):
        p.parse_args(["train", "ds", "--out", "r", "--max-steps", "-1"])


def test_train_errors_are_one_line_with_an_error_event(tmp_path):
    proc = _run(
        "-m", "nerf_core", "train", str(tmp_path / "missing"), "--out", str(tmp_path / "run"), "--max-steps", "2"
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("nerf_core train: error:") and "missing" in proc.stderr
    event = json.loads(proc.stdout.strip().splitlines()[-1])
    assert event["event"] == "error" and "missing" in event["message"]
    assert not (tmp_path / "run").exists()  # nothing created for a run that never started


def test_train_via_cli_in_process(sphere_dataset, tmp_path, capsys):
    run = tmp_path / "run"
    rc = main(
        [
            "train",
            str(sphere_dataset),
            "--out",
            str(run),
            "--method",
            "test-grid",
            "--max-steps",
            "4",
            "--batch-rays",
            "64",
            "--no-bar",
            "--eval-views",
            "1",
            "--preview-every",
            "2",
            "--checkpoint-every",
            "2",
        ]
    )
    assert rc == 0
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    assert events[0]["event"] == "start" and events[-1]["event"] == "done"
    assert [e["step"] for e in events if e["event"] == "preview"] == [2, 4]
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == [
        "latest.pt",
        "step_0000002.pt",
        "step_0000004.pt",
    ]
    assert main(["train", str(sphere_dataset), "--out", str(run), "--method", "test-grid", "--max-steps", "4"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert main(["train", str(sphere_dataset), "--out", str(tmp_path / "r2"), "--method", "no-such-method"]) == 2
    assert "no-such-method" in capsys.readouterr().err


def test_check_and_methods_commands(sphere_dataset, capsys):
    assert main(["check", str(sphere_dataset)]) == 0 and "valid" in capsys.readouterr().out
    assert main(["methods"]) == 0 and "(default)" in capsys.readouterr().out
    (sphere_dataset / "transforms_test.json").unlink()
    bad = _run("-m", "nerf_core", "check", str(sphere_dataset))
    assert bad.returncode == 1 and "transforms_test.json" in bad.stdout and "Traceback" not in bad.stderr

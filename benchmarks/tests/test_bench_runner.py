"""Running the CLIs a study measures: events, subprocesses, parallel jobs (``bench.runner``)."""
from __future__ import annotations

import os
import sys

from bench import runner


def test_parse_events_skips_warnings_and_partial_lines():
    lines = ['{"event": "start", "n_params": 10}', "UserWarning: something", '{"event": "step", "step": 1',
             "", '{"event": "done", "step": 5, "elapsed": 2.0}', "[1, 2]"]
    events = runner.parse_events(lines)
    assert [e["event"] for e in events] == ["start", "done"]


def test_run_cli_streams_events_and_reports_errors(tmp_path):
    script = tmp_path / "child.py"
    script.write_text(
        "import json, sys\n"
        "print('noise')\n"
        "print(json.dumps({'event': 'step', 'step': 1}))\n"
        "print(json.dumps({'event': 'error', 'message': 'dataset X: frame 3 missing'}))\n"
        "sys.stderr.write('traceback text\\n')\n"
        "sys.exit(3)\n"
    )
    seen = []
    res = runner.run_cli([sys.executable, str(script)], on_event=seen.append, log_path=str(tmp_path / "log.txt"))
    assert res.returncode == 3 and not res.ok
    assert [e["event"] for e in seen] == ["step", "error"]
    assert res.error_message() == "dataset X: frame 3 missing"
    assert res.stdout_tail == ["noise"]
    assert "traceback text" in (tmp_path / "log.txt").read_text()


def test_run_cli_passes_env_extra_to_the_child(tmp_path):
    script = tmp_path / "child.py"
    script.write_text("import json, os\nprint(json.dumps({'event': 'env', 'omp': "
                      "os.environ.get('OMP_NUM_THREADS')}))\n")
    res = runner.run_cli([sys.executable, str(script)], env_extra={"OMP_NUM_THREADS": "1"})
    assert res.ok and res.events == [{"event": "env", "omp": "1"}]


def test_thread_env_splits_the_cores_between_jobs(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    assert runner.thread_env(1) == {}
    assert runner.thread_env(2)["OMP_NUM_THREADS"] == "4"
    assert runner.thread_env(16)["OMP_NUM_THREADS"] == "1"  # never zero threads


def test_run_parallel_overlaps_tasks_and_keeps_their_order():
    import threading

    barrier = threading.Barrier(2, timeout=10)  # both tasks must be running at once to pass it

    def task(x):
        barrier.wait()
        return x * 10

    assert runner.run_parallel([lambda: task(1), lambda: task(2)], jobs=2) == [10, 20]
    assert runner.run_parallel([lambda: 1, lambda: 2, lambda: 3], jobs=1) == [1, 2, 3]


def test_shared_progress_adds_live_runs_to_finished_work():
    from nerf_core.utils.progressbar import ProgressBar

    bar = ProgressBar(total=100, enabled=False)
    p = runner.SharedProgress(bar)
    p.advance("a", 10)
    p.advance("b", 5)
    assert bar.done == 15
    p.finish("a", 40)  # a run books its planned cost, whatever its last step event said
    assert bar.done == 45
    p.advance("b", 20)
    assert bar.done == 60


def test_final_test_metrics_takes_the_trainers_final_eval_not_an_eval_at_one(tmp_path):
    events = [{"event": "eval", "split": "test", "psnr": 20.0, "eval_wall": 1.5},  # --eval-at, mid-run
              {"event": "eval", "split": "val", "psnr": 21.0},
              {"event": "eval", "split": "test", "psnr": 24.0, "ssim": 0.9},
              {"event": "done", "step": 10}]
    train = runner.CliResult(args=["train"], returncode=0, events=events)
    metrics, why = runner.final_test_metrics(train, str(tmp_path / "never_read"))
    assert why is None and metrics["psnr"] == 24.0 and metrics["ssim"] == 0.9


def test_final_test_metrics_falls_back_to_eval_and_says_why_it_failed(tmp_path):
    # Only a mid-run evaluation: the run's own eval is asked for, and on a folder with no run it fails.
    train = runner.CliResult(args=["train"], returncode=0,
                             events=[{"event": "eval", "split": "test", "psnr": 20.0, "eval_wall": 1.5}])
    missing = tmp_path / "no_run"
    metrics, why = runner.final_test_metrics(train, str(missing), log_path=str(tmp_path / "log.txt"))
    assert metrics is None
    assert str(missing) in why and "Traceback" not in why  # one line naming the folder
    assert "eval" in (tmp_path / "log.txt").read_text()  # the eval command was run and logged


def test_contended_allows_the_benchmarks_own_load_but_not_other_jobs(monkeypatch):
    monkeypatch.setattr(runner.os, "cpu_count", lambda: 2)
    # Quiet start, and at the end the 2 threads of the benchmark itself: not contended.
    assert not runner.contended(0.0, 2.01, own_threads=2)
    assert not runner.contended(None, None, own_threads=2)
    # Another job before the start, or more load at the end than the benchmark's own threads.
    assert runner.contended(1.2, 2.0, own_threads=2)
    assert runner.contended(0.0, 2.6, own_threads=2)
    assert runner.contended(0.0, 1.6, own_threads=1)
    assert not runner.contended(0.0, 1.4, own_threads=1)

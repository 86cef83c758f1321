"""The render-farm files in farm/: the Flamenco job type compiles into the tasks the README promises,
and the SLURM array script turns array task ids into the right --shard K/N.

Neither Flamenco nor SLURM runs here: the job type is executed by Node.js with a stand-in for the
few Flamenco calls it makes (author.Task / author.Command / path.join / job.addTask), and the SLURM
script with its dry-run switch and the environment SLURM would give it.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
JOB_TYPE = os.path.join(REPO, "farm", "flamenco", "nerf-capture.js")
SLURM = os.path.join(REPO, "farm", "slurm", "capture_array.sh")

HARNESS = r"""
const fs = require("fs");
const nodePath = require("path");
const src = fs.readFileSync(process.argv[2], "utf8");
const tasks = [];
const author = {
  Task: (name, type) => {
    const t = {name, type, commands: [], deps: []};
    t.addCommand = (c) => t.commands.push(c);
    t.addDependency = (d) => t.deps.push(d.name);
    return t;
  },
  Command: (type, params) => Object.assign({type}, params),
};
const path = {join: (...p) => nodePath.posix.join(...p)};
const job = {settings: JSON.parse(process.argv[3]), addTask: (t) => tasks.push(t)};
try {
  new Function("author", "path", "print", "job", src + "\nreturn [JOB_TYPE, compileJob(job)];")(
    author, path, () => {}, job);
  console.log(JSON.stringify(tasks.map((t) => ({name: t.name, type: t.type, commands: t.commands, deps: t.deps}))));
} catch (e) {
  console.log(JSON.stringify({error: String(e)}));
}
"""


def _compile(tmp_path, **settings):
    harness = tmp_path / "harness.js"
    harness.write_text(HARNESS)
    base = {"blendfile": "/farm/scene.blend", "nerf_bridge_dir": "/farm/nerf-blender", "dataset_dir": "/farm/ds",
            "shards": 3, "capture_args": "--count 100 --samples 64 --depth"}
    base.update(settings)
    proc = subprocess.run(["node", str(harness), JOB_TYPE, json.dumps(base)], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


@pytest.mark.skipif(shutil.which("node") is None, reason="Node.js is not installed")
def test_flamenco_job_type_makes_one_task_per_shard_then_a_merge(tmp_path):
    tasks = _compile(tmp_path)
    assert [t["name"] for t in tasks] == ["capture-shard-1-of-3", "capture-shard-2-of-3", "capture-shard-3-of-3",
                                          "merge-shards"]
    for k, t in enumerate(tasks[:3], start=1):
        (cmd,) = t["commands"]
        assert t["type"] == "blender" and cmd["type"] == "blender-render" and cmd["blendfile"] == "/farm/scene.blend"
        assert cmd["exe"] == "{blender}" and cmd["args"] == [
            "--python", "/farm/nerf-blender/scripts/capture.py", "--", "--out", "/farm/ds", "--quiet",
            "--count", "100", "--samples", "64", "--depth", "--shard", f"{k}/3"]
    merge = tasks[3]
    assert merge["deps"] == ["capture-shard-1-of-3", "capture-shard-2-of-3", "capture-shard-3-of-3"]
    assert merge["commands"][0]["args"] == ["--python", "/farm/nerf-blender/scripts/capture.py", "--",
                                            "--out", "/farm/ds", "--merge"]


@pytest.mark.skipif(shutil.which("node") is None, reason="Node.js is not installed")
@pytest.mark.parametrize("settings, words", [
    ({"shards": 0}, "shards: must be a whole number of at least 1"),
    ({"capture_args": "--count 5 --shard 1/2"}, "--shard is set by the job type"),
    ({"capture_args": "--out=/elsewhere"}, "--out is set by the job type"),
])
def test_flamenco_job_type_refuses_bad_settings(tmp_path, settings, words):
    result = _compile(tmp_path, **settings)
    assert words in result["error"]


@pytest.mark.parametrize("task_id, first, last, shard", [("1", "1", "4", "1/4"), ("4", "1", "4", "4/4"),
                                                         ("0", "0", "7", "1/8"), ("7", "0", "7", "8/8")])
def test_slurm_array_task_becomes_its_shard(task_id, first, last, shard):
    env = dict(os.environ, SLURM_ARRAY_TASK_ID=task_id, SLURM_ARRAY_TASK_MIN=first, SLURM_ARRAY_TASK_MAX=last,
               SLURM_ARRAY_TASK_COUNT=str(int(last) - int(first) + 1), NERF_DRY_RUN="1", BLENDER="blender",
               NERF_BRIDGE_DIR="/repo")
    proc = subprocess.run(["bash", SLURM, "scene.blend", "/shared/ds", "--count", "100"], capture_output=True,
                          text=True, env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["blender", "-b", "scene.blend", "--python", "/repo/scripts/capture.py", "--",
                                   "--out", "/shared/ds", "--quiet", "--count", "100", "--shard", shard]


def test_slurm_merge_and_bad_arrays():
    env = dict(os.environ, NERF_DRY_RUN="1", BLENDER="blender", NERF_BRIDGE_DIR="/repo")
    proc = subprocess.run(["bash", SLURM, "--merge", "/shared/ds"], capture_output=True, text=True, env=env)
    assert proc.returncode == 0 and proc.stdout.split() == [
        "blender", "-b", "--factory-startup", "--python", "/repo/scripts/capture.py", "--", "--out", "/shared/ds",
        "--merge"]
    gaps = dict(env, SLURM_ARRAY_TASK_ID="3", SLURM_ARRAY_TASK_MIN="1", SLURM_ARRAY_TASK_MAX="5",
                SLURM_ARRAY_TASK_COUNT="3")  # --array=1,3,5: shard numbers would not be 1..N
    proc = subprocess.run(["bash", SLURM, "scene.blend", "/shared/ds"], capture_output=True, text=True, env=gaps)
    assert proc.returncode == 2 and "contiguous range" in proc.stderr

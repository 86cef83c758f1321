"""Issue 57 part 3 (the exports as one table) and issue 58 rules 5 and 6 (part) as the exports meet them:

- a format is one declaration (``contract.exports``) plus a writer (``export.formats``): the toy format
  below is both, in this file, and goes through the CLI like the built-in ones;
- export events go through the event log, which refuses a name ``contract.EVENTS`` lacks;
- every loader of a run's dataset notices a changed one (``runs.dataset_identity.dataset_changed_note``);
- the output is tried before the work, a failed write names it, ``pixel_filter`` means one thing, and
  an unusable ``torch.device`` is refused at ``open_run``.
"""
from __future__ import annotations

import ast
import errno
import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import nerf_core
from nerf_core import contract
from nerf_core.cli.main import main
from nerf_core.contract import exports
from nerf_core.export import formats, volume
from nerf_core.image import pixel_filter as pf
from nerf_core.render.run import DatasetChanged
from nerf_core.runs.events import EventLog
from nerf_core.tests.conftest import use_model
from nerf_core.tests.test_export_mesh import SphereModel

REPO = Path(__file__).resolve().parents[2]


def _lines(capsys):
    captured = capsys.readouterr()
    return [json.loads(line) for line in captured.out.strip().splitlines()], captured.err.strip().splitlines()


# ----------------------------------------------------------------------------------------------
# The table: a toy format in one declaration plus a writer


@pytest.fixture
def toy_format():
    """``export centre``: the density at the box's centre and its corners, as a text file."""
    fmt = exports.declare(exports.ExportFormat(
        "centre", ".txt", "the density at the centre (a test's toy format)", "nine densities",
        options=(exports.Option("--scale", "positive_float", "multiply the densities", default=1.0),)))

    def extract(job):
        pts = torch.tensor(np.vstack([job.box.mean(axis=0), *[[job.box[i, 0], job.box[j, 1], job.box[k, 2]]
                                                              for i in (0, 1) for j in (0, 1) for k in (0, 1)]]),
                           dtype=torch.float32)
        job.say("centre", 1.0)
        return job.model.density_at(pts).numpy() * job.options["scale"]

    def write(path, values):
        from nerf_core.utils.atomic import write_text_atomic
        write_text_atomic(path, "\n".join(f"{v:.6g}" for v in values) + "\n")

    formats.writer("centre", 1, extract, write, lambda values: {"centre": float(values[0])})
    yield fmt
    formats.WRITERS.pop("centre")
    exports.EXPORTS.pop("centre")


def test_a_toy_format_declared_in_one_file_exports_through_the_cli(toy_format, monkeypatch, tmp_path, capsys):
    use_model(monkeypatch, SphereModel())
    out = tmp_path / "c.txt"
    assert main(["export", "centre", "run", "--out", str(out), "--scale", "2", "--resolution", "8"]) == 0
    events, err = _lines(capsys)
    assert events[-1]["kind"] == "centre" and events[-1]["centre"] == pytest.approx(2e4, rel=1e-3)
    assert events[-1]["resolution"] == 8 and events[-1]["out"] == str(out.resolve())
    assert [e["event"] for e in events[:-1]] == ["progress"]  # its one stage
    values = [float(v) for v in out.read_text().split()]
    assert len(values) == 9 and values[1] == pytest.approx(0.0, abs=1e-3)
    # the suffix rule comes from the declaration too
    assert main(["export", "centre", "run", "--out", str(tmp_path / "c.ply")]) == 2
    assert "--out" in capsys.readouterr().err and not (tmp_path / "c.ply").exists()


def test_the_table_is_what_the_cli_the_addon_and_the_script_read():
    from nerf_core.cli.main import build_parser
    kinds = next(a for a in build_parser()._subparsers._group_actions[0].choices["export"]._actions
                 if a.dest == "kind").choices
    assert set(exports.EXPORTS) == set(formats.WRITERS) and set(exports.EXPORTS) | {"colmap"} == set(kinds)
    assert exports.export_suffix("mesh") == ".ply" and exports.export_file_name("volume", 3) == "volume_003.npz"
    with pytest.raises(ValueError, match=r"export: unknown export 'cloud'; one of mesh, volume"):
        exports.export_format("cloud")
    # the add-on and scripts/import_geometry.py hold no suffix of their own
    for rel in ("addon/compare/geometry_job.py", "scripts/import_geometry.py"):
        text = (REPO / rel).read_text(encoding="utf-8")
        assert '".ply"' not in text and '".npz"' not in text and "contract" in text, rel


def test_the_event_log_refuses_a_name_that_contract_events_lacks(capsys):
    log = EventLog(stdout=True)
    with pytest.raises(ValueError, match=r"event 'exported' is not one of contract.EVENTS"):
        log.emit("exported", out="x")
    log.emit("progress", stage="density", fraction=0.5)
    assert contract.parse_event_line(capsys.readouterr().out)["event"] == "progress"


# ----------------------------------------------------------------------------------------------
# Rule 5: every loader path notices a changed dataset


def test_export_culls_with_a_replaced_datasets_cameras_and_says_so(monkeypatch, tmp_path, capsys, dataset_factory):
    ds = dataset_factory(tmp_path / "ds", n_train=4, n_test=1, w=12, h=10)
    use_model(monkeypatch, SphereModel(), config={"dataset": str(ds), "dataset_hash": "0" * 64})
    out = tmp_path / "m.ply"
    assert main(["export", "mesh", "run", "--out", str(out), "--resolution", "24", "--level", "5000"]) == 0
    events, _ = _lines(capsys)
    notes = [e["message"] for e in events if e.get("event") == "note"]
    assert len(notes) == 1 and "changed since the run trained on it" in notes[0], notes
    assert "the culling uses the cameras there now" in notes[0] and events[-1]["notes"] == notes


def test_open_run_dataset_notes_a_changed_dataset_as_eval_does(run_copy, trained_run, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(trained_run["dataset"], ds)
    cfg = run_copy / "config.json"
    config = json.loads(cfg.read_text())
    config["dataset"] = str(ds)
    cfg.write_text(json.dumps(config))
    meta = json.loads((ds / "transforms_train.json").read_text())
    meta["frames"] = meta["frames"][:-1]  # one training view fewer: another dataset at the same path
    (ds / "transforms_train.json").write_text(json.dumps(meta))
    run = nerf_core.open_run(run_copy, device="cpu")
    with pytest.warns(DatasetChanged, match="changed since the run trained on it"):
        run.dataset
    assert len(run.notes) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run.cameras("test")  # said once


LOADS = {"load_dataset", "load_cameras", "camera_views"}
OPENS = {"load_trained", "load_run", "open_run"}


def test_every_module_that_opens_a_run_and_loads_data_checks_the_dataset_identity():
    """The mechanism: a module that opens a run and reads a dataset calls ``dataset_changed_note`` (the one
    check), or reads the dataset through ``Run`` (``run.dataset``, ``run.cameras``), which does."""
    missing = []
    for path in sorted((REPO / "nerf_core").rglob("*.py")):
        rel = path.relative_to(REPO)
        if "tests" in rel.parts:
            continue
        names = {n.func.id if isinstance(n.func, ast.Name) else n.func.attr
                 for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                 if isinstance(n, ast.Call) and isinstance(n.func, (ast.Name, ast.Attribute))}
        if names & OPENS and names & LOADS and "dataset_changed_note" not in names:
            missing.append(str(rel))
    assert not missing, "modules that open a run and load its data without dataset_changed_note: " + str(missing)


# ----------------------------------------------------------------------------------------------
# Rule 6 (part): messages name what the user typed


def test_an_out_where_no_file_can_be_made_is_refused_before_the_work(monkeypatch, capsys):
    monkeypatch.setattr("nerf_core.export.run_export.open_run", lambda *a, **k: pytest.fail("the run was opened"))
    assert main(["export", "mesh", "run", "--out", "/proc/x.ply"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nerf_core export: error: --out /proc/x.ply: cannot create a file in "
                                               "/proc ("), err


@pytest.mark.parametrize("kind,name", [("volume", "v.npz"), ("mesh", "m.ply")])
def test_ulimit_f_during_an_export_names_the_output_and_leaves_nothing(kind, name, tmp_path):
    """A file-size limit: SIGXFSZ ignored (else it kills the export), the write's EFBIG named by --out,
    the temporary removed. Before, the process died of SIGXFSZ or ended in a zipfile traceback."""
    out = tmp_path / name
    script = f"""
import resource, sys
from nerf_core.tests.conftest import use_model
from nerf_core.tests.test_export_mesh import SphereModel
from nerf_core.cli.main import main
use_model(None, SphereModel())
resource.setrlimit(resource.RLIMIT_FSIZE, (20000, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
sys.exit(main(["export", {kind!r}, "run", "--out", {str(out)!r}, "--resolution", "40"]))
"""
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert len(err) == 1 and f"--out {out}: cannot write: file too large (a file-size limit, ulimit -f" in err[0], err
    assert os.listdir(tmp_path) == []


def test_a_full_disk_during_the_volume_write_names_the_output(monkeypatch, tmp_path, capsys):
    use_model(monkeypatch, SphereModel())

    def full(fh, array, **kw):
        fh.write(b"\x93NUMPY")
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(volume.np.lib.format, "write_array", full)
    out = tmp_path / "v.npz"
    assert main(["export", "volume", "run", "--out", str(out), "--resolution", "12"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(f"--out {out}: cannot write: no space left on device; nothing was "
                                             "written; free space or raise the limit, then export again"), err
    assert os.listdir(tmp_path) == []


def test_pixel_filter_none_means_one_ray_a_pixel_everywhere_and_unknown_names_are_refused(run_copy):
    assert pf.of_run({}, None) is pf.POINT and pf.of_run({}, "none") is pf.POINT
    assert pf.of_run({}, "auto") is not pf.POINT
    run = nerf_core.open_run(run_copy, device="cpu")
    cams = run.dataset.split("test").cameras
    a = run.render(cams, 0, pixel_filter=None)
    b = run.render(cams, 0, pixel_filter="none")
    assert torch.equal(a["rgb"], b["rgb"]) and a["n_rays"] == b["n_rays"] == int(cams.width[0] * cams.height[0])
    with pytest.raises(ValueError, match=r"Run.render: pixel_filter: must be 'none', 'auto', None or a PixelFilter, "
                                         r"got 'box'"):
        run.render(cams, 0, pixel_filter="box")


@pytest.mark.parametrize("device", [torch.device("meta"), torch.device("cuda", 7)])
def test_open_run_refuses_an_unusable_torch_device_at_the_boundary(run_copy, device):
    with pytest.raises(ValueError, match=r"^open_run: device (meta|cuda:7): "):
        nerf_core.open_run(run_copy, device=device)

"""Compare's Import as Mesh / Import as Volume: ``nerf_core export`` runs in a child process whose
progress events reach the panel, Cancel stops it, and the result is imported into its collection."""
from __future__ import annotations

import os
import sys
import time

import bpy
import numpy as np
import pytest

import addon
from addon.common import jobs
from addon.compare import compare_ui, geometry_import, geometry_job
from addon.train import train_ui


@pytest.fixture
def registered():
    addon.register()
    yield
    jobs.forget((train_ui.RENDER,))
    addon.unregister()


def _fake_python(tmp_path, body: str) -> str:
    """An executable standing in for the interpreter with torch: it takes ``-m nerf_core export KIND
    RUN --out OUT`` and runs ``body`` with ``out`` and ``emit`` defined."""
    script = tmp_path / "fake_python"
    script.write_text(f"#!{sys.executable}\n"
                      "import json, sys, time\n"
                      "sys.path.insert(0, " + repr(os.getcwd()) + ")\n"
                      "out = sys.argv[sys.argv.index('--out') + 1]\n"
                      "def emit(**ev):\n"
                      "    print(json.dumps({'time': time.time(), **ev}), flush=True)\n" + body)
    script.chmod(0o755)
    return str(script)


MESH_BODY = (
    "import numpy as np\n"
    "from nerf_core.export.ply import write_mesh_ply\n"
    "emit(event='progress', stage='density', fraction=0.5)\n"
    "time.sleep(0.5)\n"
    "write_mesh_ply(out, np.array([[0, 0, 0], [1, 0, 0], [0, 1, 1.0]]), np.array([[0, 1, 2]]),\n"
    "               np.full((3, 3), 200, np.uint8))\n"
    "print(json.dumps({'out': out, 'kind': 'mesh'}))\n")


def _drive(job, timeout=60):
    seen = []
    deadline = time.monotonic() + timeout
    while job.update() == "running":
        seen.append(job.stage())
        assert time.monotonic() < deadline, job.process.log_tail()
        time.sleep(0.05)
    return seen


def test_export_job_shows_progress_and_imports_the_mesh_into_its_collection(registered, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    out = geometry_job.fresh_file(str(run), "mesh")
    assert out == str(run / "geometry" / "mesh_001.ply")
    job = geometry_job.GeometryJob(bpy.context.scene.name, _fake_python(tmp_path, MESH_BODY), str(run), "mesh", out)
    job.on_update = compare_ui.sync_geometry_settings
    jobs.add(train_ui.RENDER, job)
    seen = _drive(job)
    assert "density 50 %" in seen
    assert job.state == "done", job.message
    obj = bpy.data.objects[job.object_name]
    assert obj.users_collection[0].name == geometry_import.MESH_COLLECTION
    assert np.allclose([tuple(v.co) for v in obj.data.vertices], [[0, 0, 0], [1, 0, 0], [0, 1, 1]])
    assert geometry_job.fresh_file(str(run), "mesh").endswith("mesh_002.ply")  # the first is never overwritten


def test_cancel_stops_the_export_and_imports_nothing(registered, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    body = "emit(event='progress', stage='density', fraction=0.1)\nwhile True: time.sleep(0.1)\n"
    job = geometry_job.GeometryJob(bpy.context.scene.name, _fake_python(tmp_path, body), str(run), "volume",
                                   geometry_job.fresh_file(str(run), "volume"))
    jobs.add(train_ui.RENDER, job)
    deadline = time.monotonic() + 30
    while job.stage() == "":
        job.update()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert bpy.ops.nerf.train_cancel(target="RENDER") == {"FINISHED"}
    _drive(job)
    assert job.state == "cancelled" and job.message.startswith("Export cancelled")
    assert geometry_import.VOLUME_COLLECTION not in bpy.data.collections


def test_a_failed_export_reports_the_child_error(registered, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    body = ("print('nerf_core export: error: no surface at density level 12.5 per scene unit', file=sys.stderr)\n"
            "sys.exit(2)\n")
    job = geometry_job.GeometryJob(bpy.context.scene.name, _fake_python(tmp_path, body), str(run), "mesh",
                                   geometry_job.fresh_file(str(run), "mesh"))
    _drive(job)
    assert job.state == "failed" and "no surface at density level" in job.message


def test_the_panel_offers_every_import(registered):
    assert hasattr(bpy.types, "NERF_OT_import_geometry")
    props = bpy.ops.nerf.import_geometry.get_rna_type().properties["geometry"]
    assert set(props.enum_items.keys()) == {"MESH", "VOLUME", "WORLD"}
    assert {k.lower() for k in props.enum_items.keys()} == set(geometry_import.IMPORTERS)

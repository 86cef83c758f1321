"""Issue 58, rule 2: what cannot fit is refused before the work, naming the flag.

- One ``available_memory`` (``nerf_core/utils/memory.py``): the smallest of the free memory, the
  address-space limit and a cgroup's limit; nothing else reads them (a mechanism test).
- The export's budgets hold the real peaks, measured with tracemalloc on foggy fields (white noise:
  faces in every cell; a smooth fog; a colour at every node), so a change that allocates more fails here.
- An allocation that fails anyway is one line naming the flag.
"""
from __future__ import annotations

import ast
import json
import os
import resource
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import torch

from nerf_core.cli.main import main
from nerf_core.export import grid, mesh, volume
from nerf_core.methods.base import RadianceModel
from nerf_core.tests.conftest import use_model
from nerf_core.utils import memory

REPO = Path(__file__).resolve().parents[2]
BOX = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
FOG_LEVEL = 50.0


class Fog(RadianceModel):
    """A field that is fog everywhere: white noise (``freq`` None: a surface in nearly every grid cell)
    or a smooth 3-D sine, density around ``FOG_LEVEL``, so that every node is coloured."""

    method_name = "fog"

    def __init__(self, freq=None):
        super().__init__(torch.tensor(BOX, dtype=torch.float32))
        self.freq = freq

    def density_at(self, p):
        if self.freq is None:
            h = torch.sin(p[:, 0] * 127.1 + p[:, 1] * 311.7 + p[:, 2] * 74.7) * 43758.5453
            return 2.0 * FOG_LEVEL * (h - torch.floor(h))
        f = self.freq
        return FOG_LEVEL * (1.0 + 0.9 * torch.sin(f * p[:, 0] + 0.3) * torch.sin(1.1 * f * p[:, 1] + 0.7)
                            * torch.sin(0.9 * f * p[:, 2]))

    def colour_at(self, p, d):
        return torch.sigmoid(p)


@pytest.fixture
def fog_run(monkeypatch):
    return lambda model: use_model(monkeypatch, model)


def _peak(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


# ----------------------------------------------------------------------------------------------
# One available_memory, the smallest of three limits


def _fake_proc(tmp_path, avail_kb=8 << 20, vm_kb=1 << 20, cgroup_line="0::/job\n"):
    proc = tmp_path / "proc"
    (proc / "self").mkdir(parents=True)
    (proc / "meminfo").write_text(f"MemTotal: {avail_kb * 2} kB\nMemAvailable: {avail_kb} kB\n")
    (proc / "self" / "status").write_text(f"Name: python\nVmSize: {vm_kb} kB\n")
    (proc / "self" / "cgroup").write_text(cgroup_line)
    return proc


def test_available_memory_is_the_smallest_of_free_memory_and_the_cgroups_limit(tmp_path):
    proc, cg = _fake_proc(tmp_path), tmp_path / "cgroup"
    (cg / "job").mkdir(parents=True)
    (cg / "job" / "memory.max").write_text(f"{2 << 30}\n")
    (cg / "job" / "memory.current").write_text(f"{512 << 20}\n")
    assert memory.available_memory(proc, cg) == (2 << 30) - (512 << 20)  # below the 8 GB free
    (cg / "job" / "memory.max").write_text("max\n")  # no limit: the free memory
    assert memory.available_memory(proc, cg) == 8 << 30
    # cgroup v1 (this machine's kind): memory.limit_in_bytes minus memory.usage_in_bytes
    proc1 = _fake_proc(tmp_path / "v1", cgroup_line="4:memory:/box\n0::/\n")
    (cg / "memory" / "box").mkdir(parents=True)
    (cg / "memory" / "box" / "memory.limit_in_bytes").write_text(f"{1 << 30}\n")
    (cg / "memory" / "box" / "memory.usage_in_bytes").write_text(f"{256 << 20}\n")
    assert memory.available_memory(proc1, cg) == (1 << 30) - (256 << 20)
    (cg / "memory" / "box" / "memory.limit_in_bytes").write_text(f"{(1 << 63) - 4096}\n")  # v1's "no limit"
    assert memory.available_memory(proc1, cg) == 8 << 30


def test_available_memory_takes_the_address_space_limit_minus_what_is_mapped(tmp_path, monkeypatch):
    proc = _fake_proc(tmp_path, vm_kb=3 << 20)  # 3 GB mapped
    monkeypatch.setattr(memory.resource, "getrlimit", lambda which: (4 << 30, resource.RLIM_INFINITY))
    assert memory.available_memory(proc, tmp_path / "none") == 1 << 30
    monkeypatch.setattr(memory.resource, "getrlimit", lambda which: (resource.RLIM_INFINITY,) * 2)
    assert memory.available_memory(proc, tmp_path / "none") == 8 << 30


def test_export_under_ulimit_v_is_refused_before_the_work_naming_the_resolution(tmp_path):
    """The machine has the memory, the address-space limit has not: refused before sampling, one line.
    Before, MemAvailable alone approved it and the grids ended in a MemoryError traceback."""
    out = tmp_path / "v.npz"
    script = f"""
import resource, sys
sys.path.insert(0, {str(Path(__file__).parent)!r})
from test_export_memory import Fog
from nerf_core.tests.conftest import use_model
from nerf_core.cli.main import main
use_model(None, Fog(freq=20.0))
vm = next(int(ln.split()[1]) * 1024 for ln in open("/proc/self/status") if ln.startswith("VmSize:"))
resource.setrlimit(resource.RLIMIT_AS, (vm + (600 << 20), resource.getrlimit(resource.RLIMIT_AS)[1]))
sys.exit(main(["export", "volume", "run", "--out", {str(out)!r}, "--resolution", "512"]))
"""
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert len(err) == 1 and "--resolution 512: a 512^3 grid needs 1.0 GB of memory" in err[0], err
    assert "MB is available" in err[0] and not out.exists()


def test_no_module_but_utils_memory_reads_the_memory_limits():
    """The mechanism: a second reader of free memory or limits would disagree with the first (as the
    export's and render's did); every size check goes through ``utils.memory.available_memory``."""
    signs = ("MemAvailable", "SC_AVPHYS_PAGES", "SC_PHYS_PAGES", "RLIMIT_AS", "memory.max", "limit_in_bytes")
    found = []
    for root in ("nerf_core", "scripts", "addon", "tools"):
        for path in sorted((REPO / root).rglob("*.py")):
            rel = path.relative_to(REPO)
            if "tests" in rel.parts or rel == Path("nerf_core/utils/memory.py"):
                continue
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                text = node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else (
                    node.attr if isinstance(node, ast.Attribute) else None)
                if text is not None and any(s in text for s in signs):
                    found.append(f"{rel}:{node.lineno}: {text[:60]}")
                if isinstance(node, ast.FunctionDef) and node.name == "available_memory":
                    found.append(f"{rel}:{node.lineno}: def available_memory")
    assert not found, "memory limits read outside nerf_core/utils/memory.py:\n" + "\n".join(found)


# ----------------------------------------------------------------------------------------------
# The budgets hold the measured peaks


@pytest.mark.parametrize("freq", [None, 40.0], ids=["white-noise", "smooth"])
def test_the_volume_budget_holds_the_peak_of_a_fog(freq):
    res = 96
    peak = _peak(lambda: volume.volume_grids(Fog(freq), BOX, res))
    budget = res ** 3 * volume.BYTES_PER_SAMPLE + grid.CHUNK_BYTES
    assert peak <= budget, f"{peak / res ** 3:.1f} B a sample against {budget / res ** 3:.1f} budgeted"
    # and it is a budget, not a guess of ten times too much
    assert peak > 0.4 * budget


@pytest.mark.parametrize("freq", [None, 0.8 * 64], ids=["white-noise", "smooth"])
def test_the_mesh_budget_holds_the_peak_of_a_fog(freq, monkeypatch):
    res = 64
    model = Fog(freq)
    cells = []
    monkeypatch.setattr(mesh, "check_surface_fits", lambda n, r, level, flag="--resolution": cells.append(n))
    peak = _peak(lambda: mesh.extract_mesh(model, BOX, res, level=FOG_LEVEL))
    budget = res ** 3 * mesh.BYTES_PER_SAMPLE + grid.CHUNK_BYTES + cells[0] * mesh.BYTES_PER_CROSSED_CELL
    assert peak <= budget, f"{peak / 1e6:.1f} MB at peak against {budget / 1e6:.1f} MB budgeted ({cells[0]} cells)"
    if freq is None:  # the worst case (faces in every cell) uses the budget: it is not a guess of ten times too much
        assert peak > 0.5 * budget


def test_a_fog_too_large_for_its_faces_is_refused_before_marching_cubes(monkeypatch):
    model = Fog(None)
    monkeypatch.setattr(mesh, "available_memory", lambda: 64 << 20)
    monkeypatch.setattr(mesh, "marching_cubes", lambda *a: pytest.fail("marching cubes ran"))
    with pytest.raises(ValueError) as exc:
        mesh.extract_mesh(model, BOX, 64, level=FOG_LEVEL)
    msg = str(exc.value)
    assert msg.startswith("--resolution 64: the surface at density level 50 crosses ") and "--level" in msg
    assert "64.0 MB is available" in msg


def test_a_grid_that_fits_the_machine_but_not_its_budget_is_refused_naming_the_flag(monkeypatch, fog_run,
                                                                                    tmp_path, capsys):
    fog_run(Fog(20.0))
    monkeypatch.setattr(grid, "available_memory", lambda: 100 << 20)  # 256^3 * 36 B + a chunk's 50 MB > 100 MB
    assert main(["export", "mesh", "run", "--out", str(tmp_path / "m.ply"), "--resolution", "256"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    want = "--resolution 256: a 256^3 grid needs 626.0 MB of memory and 100.0 MB is available"
    assert len(err) == 1 and want in err[0], err


# ----------------------------------------------------------------------------------------------
# What fails anyway is one line naming the flag


@pytest.mark.parametrize("kind,where", [("volume", "volume_grids"), ("mesh", "extract_mesh")])
@pytest.mark.parametrize("error", [MemoryError(), RuntimeError("DefaultCPUAllocator: can't allocate memory: "
                                                                "you tried to allocate 123 bytes")])
def test_an_allocation_that_fails_inside_the_export_is_one_line_naming_the_resolution(kind, where, error, fog_run,
                                                                                      monkeypatch, tmp_path, capsys):
    fog_run(Fog(20.0))
    target = volume if kind == "volume" else mesh

    def fail(*a, **k):
        raise error
    monkeypatch.setattr(target, where, fail)
    out = tmp_path / ("v.npz" if kind == "volume" else "m.ply")
    assert main(["export", kind, "run", "--out", str(out), "--resolution", "24"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nerf_core export: error: --resolution 24: not enough memory ("), err
    assert "lower the resolution" in err[0] and not out.exists()


def test_other_runtime_errors_pass_unchanged():
    with pytest.raises(RuntimeError, match="shape mismatch"):
        with memory.named_out_of_memory("--chunk 1", "lower --chunk"):
            raise RuntimeError("shape mismatch")


def test_an_allocation_that_fails_inside_render_names_the_chunk(run_copy, trained_run, monkeypatch, tmp_path,
                                                                capsys):
    from nerf_core.render import views

    def fail(*a, **k):
        raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB")
    monkeypatch.setattr(views, "render_view", fail)
    ds = trained_run["dataset"]
    assert main(["render", str(run_copy), "--cameras", str(ds / "transforms_test.json"), "--out",
                 str(tmp_path / "r"), "--no-bar"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--chunk 8192: not enough memory (CUDA out of memory." in err[0], err
    assert "lower --chunk" in err[0]


def test_summary_of_a_fog_volume_is_whole(fog_run, tmp_path, capsys):
    fog_run(Fog(None))
    out = tmp_path / "v.npz"
    assert main(["export", "volume", "run", "--out", str(out), "--resolution", "40"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    arrays = volume.read_volume(out)
    assert summary["resolution"] == 40 and np.count_nonzero(arrays["color"].any(axis=-1)) > 0.9 * 40 ** 3


def test_an_allocation_that_fails_inside_eval_names_the_chunk(run_copy, monkeypatch, capsys):
    from nerf_core.evaluation import evaluate

    def fail(*a, **k):
        raise MemoryError()
    monkeypatch.setattr(evaluate, "evaluate_split", fail)
    metrics = (run_copy / "metrics.json").read_bytes()
    assert main(["eval", str(run_copy), "--chunk", "4096", "--no-bar"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--chunk 4096: not enough memory (MemoryError" in err[0], err
    assert (run_copy / "metrics.json").read_bytes() == metrics

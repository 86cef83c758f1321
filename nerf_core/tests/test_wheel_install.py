"""The library as a user installs it: a wheel of ``nerf-bridge``, built from the checkout, installed
into a fresh virtual environment without bpy and without network, and used from a folder outside the
checkout: ``python -m nerf_core --help``, both console scripts, ``train`` and ``eval`` on a dataset,
and the example of docs/API.md.

The environment gets its dependencies only from the wheel folder that scripts/setup_env.sh fills
(``.venv/wheelhouse``: torch, numpy, pillow and openexr at the pinned versions), with ``--no-index``,
so pip resolves the wheel's own metadata exactly as it would on a user's machine.
"""
from __future__ import annotations

import email.parser
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
WHEELHOUSE = Path(os.environ.get("NERF_WHEELHOUSE", REPO_ROOT / ".venv" / "wheelhouse"))


def _clean_env(**extra: str) -> dict:
    """The environment of a user's shell: no PYTHONPATH into the checkout, no pip settings of ours or
    of this machine (its extra indexes and find-links), so only what the test passes to pip counts."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("PIP_", "PYTHON", "VIRTUAL_ENV", "CONDA"))}
    env.update(PIP_CONFIG_FILE=os.devnull, PIP_DISABLE_PIP_VERSION_CHECK="1", OMP_NUM_THREADS="1", **extra)
    return env


def _run(cmd, cwd, timeout=600) -> str:
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, env=_clean_env(), capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, f"$ {' '.join(map(str, cmd))}\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout + proc.stderr


def _build_wheel(tmp_path: Path) -> Path:
    """Build the wheel from a copy of the files it is made of, so the build writes nothing (build/,
    *.egg-info) into the checkout."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO_ROOT / name, src / name)
    shutil.copytree(REPO_ROOT / "nerf_core", src / "nerf_core",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "tests"))
    dist = tmp_path / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", dist, src],
         cwd=tmp_path)
    wheels = sorted(dist.glob("*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def _metadata(wheel: Path) -> email.message.Message:
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        meta = next(n for n in names if n.endswith(".dist-info/METADATA"))
        text = zf.read(meta).decode("utf-8")
    assert not [n for n in names if "/tests/" in n or n.startswith(("addon/", "scripts/", "bpy"))], \
        "the wheel carries only the library"
    return email.parser.Parser().parsestr(text)


def test_wheel_metadata_is_loose_and_names_the_product(tmp_path):
    """Any Python from 3.10, any torch from 2.5, no bpy: the pins belong to constraints.txt."""
    meta = _metadata(_build_wheel(tmp_path))
    assert meta["Name"] == "nerf-bridge"
    assert meta["Requires-Python"] == ">=3.10"
    requires = meta.get_all("Requires-Dist")
    core = [r for r in requires if "extra ==" not in r]
    assert any(r.replace(" ", "").startswith("torch>=") for r in core), core
    user_facing = [r for r in requires if 'extra == "dev"' not in r]  # dev: our own tools, pinned by constraints.txt
    assert not [r for r in user_facing if "==" in r.split(";")[0] or r.startswith("bpy")], requires
    extras = set(meta.get_all("Provides-Extra"))
    assert {"exr", "charts", "mesh"} <= extras
    extra_only = ("openexr", "matplotlib", "scikit-image", "fast-simplification")
    assert not [r for r in core if r.lower().startswith(extra_only)], "EXR, charts and mesh are extras"


@pytest.mark.slow
def test_wheel_installs_offline_and_trains_outside_the_checkout(tmp_path, dataset_factory, api_example_code):
    if not (WHEELHOUSE.is_dir() and list(WHEELHOUSE.glob("torch-*.whl"))):
        pytest.fail(f"{WHEELHOUSE}: no wheel folder with torch; run `bash scripts/setup_env.sh` (it fills it)")
    wheel = _build_wheel(tmp_path)

    venv = tmp_path / "user-venv"
    base_python = getattr(sys, "_base_executable", sys.executable)
    _run([base_python, "-m", "venv", venv], cwd=tmp_path)
    py, bindir = venv / "bin" / "python", venv / "bin"
    _run([py, "-m", "pip", "install", "-q", "--no-index", "--find-links", WHEELHOUSE, f"{wheel}[exr]"],
         cwd=tmp_path)

    work = tmp_path / "work"  # the user's folder: neither the checkout nor the venv
    work.mkdir()
    where = _run([py, "-c", "import importlib.util, nerf_core; print(nerf_core.__file__); "
                  "print(importlib.util.find_spec('bpy'))"], cwd=work).split()
    assert where[0].startswith(str(venv)) and "site-packages" in where[0], where
    assert where[1] == "None", "the library's environment has no bpy"
    # The native kernel's C source ships in the wheel, and builds where there is a compiler.
    backend = _run([py, "-c", "from nerf_core.fields import vm_products; print(vm_products.backend())"], cwd=work)
    if shutil.which("cc") or shutil.which("gcc"):
        assert "('native', '')" in backend, backend

    for cmd in ([py, "-m", "nerf_core", "--help"], [bindir / "nerf-bridge", "--help"],
                [bindir / "nerf-core", "--help"]):
        assert "train" in _run(cmd, cwd=work)

    dataset = dataset_factory(work / "scene", n_train=6, n_val=1, n_test=1, w=24, h=20, layouts=("synthetic",))
    _run([py, "-m", "nerf_core", "train", "scene", "--out", "run", "--max-steps", "10", "--no-bar"], cwd=work)
    scores = _run([py, "-m", "nerf_core", "eval", "run"], cwd=work)
    assert "psnr" in scores.lower(), scores

    script = work / "example.py"
    script.write_text(api_example_code(dataset, work / "runs" / "scene"), encoding="utf-8")
    out = _run([py, script], cwd=work)
    assert "PSNR" in out, out

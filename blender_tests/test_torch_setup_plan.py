"""Set up PyTorch's decisions without running pip: the commands, the refusals, pip's output read as
progress, what a failure tells the user, and which interpreters are offered (addon/bridge/torch_setup)."""
from __future__ import annotations

import os

import pytest

from addon.bridge import torch_setup
from addon.bridge.child_process import SetupError

PY = "/opt/blender/4.2/python/bin/python3.11"


def wheels(tmp_path):
    folder = tmp_path / "wheels"
    folder.mkdir()
    (folder / "torch-2.13.0-cp311-cp311-linux_x86_64.whl").write_bytes(b"")
    return str(folder)


def test_default_device_follows_the_nvidia_driver():
    assert torch_setup.default_device(which=lambda n: "/usr/bin/nvidia-smi", exists=lambda p: False) == "CUDA"
    assert torch_setup.default_device(which=lambda n: None, exists=lambda p: p == "/proc/driver/nvidia") == "CUDA"
    assert torch_setup.default_device(which=lambda n: None, exists=lambda p: False) == "CPU"
    assert torch_setup.default_device(which=lambda n: "/x", exists=lambda p: True, platform="darwin") == "CPU"


def test_online_plan_uses_the_builds_index_and_says_how_big(tmp_path):
    plan = torch_setup.plan_setup(str(tmp_path / "env"), PY, "CPU", environ={"PIP_INDEX_URL": "https://mirror"})
    assert [s.name for s in plan.steps] == ["venv", "pip", "install", "verify"]
    venv, _, install, verify = plan.steps
    assert venv.cmd == [PY, "-m", "venv", "--clear", str(tmp_path / "env")]
    assert install.cmd[:3] == [plan.python, "-m", "pip"] and "https://download.pytorch.org/whl/cpu" in install.cmd
    # the user's pip configuration is kept
    assert "--no-index" not in install.cmd and install.env["PIP_INDEX_URL"] == "https://mirror"
    assert "torch>=2.5" in install.cmd and "openexr>=3.2,<4" in install.cmd
    assert verify.cmd[0] == plan.python and "import torch, nerf_core" in verify.cmd[-1]
    assert "about 200 MB" in plan.describe() and str(tmp_path / "env") in plan.describe()
    cuda = torch_setup.plan_setup(str(tmp_path / "env"), PY, "CUDA", openexr=False)
    assert "https://download.pytorch.org/whl/cu128" in cuda.steps[2].cmd and "about 2.5 GB" in cuda.describe()
    assert not any("openexr" in a for a in cuda.steps[2].cmd)
    bounds = [(s.start, s.end) for s in plan.steps]
    assert bounds[0][0] == 0.0 and bounds[-1][1] == 1.0 and all(a[1] == b[0] for a, b in zip(bounds, bounds[1:]))


def test_wheel_folder_is_the_only_source(tmp_path):
    folder = wheels(tmp_path)
    env = {"PIP_FIND_LINKS": "/elsewhere", "PIP_EXTRA_INDEX_URL": "https://x", "PYTHONPATH": "/blender", "HOME": "/h"}
    plan = torch_setup.plan_setup(str(tmp_path / "env"), PY, "CPU", wheel_dir=folder, online=False, environ=env)
    assert [s.name for s in plan.steps] == ["venv", "install", "verify"]  # no pip update: nothing to fetch it from
    install = plan.steps[1]
    assert install.cmd[install.cmd.index("--find-links") + 1] == folder and "--no-index" in install.cmd
    assert install.env["PIP_CONFIG_FILE"] == os.devnull and install.env["HOME"] == "/h"
    assert not {"PIP_FIND_LINKS", "PIP_EXTRA_INDEX_URL", "PYTHONPATH"} & set(install.env)
    assert "no download" in plan.describe()


@pytest.mark.parametrize("case, match", [
    ("offline", "online access is off .*choose a folder of wheels"),
    ("missing", "Wheel folder .*nowhere does not exist"),
    ("empty", "holds no .whl files"),
    ("mac-cuda", "no CUDA builds for macOS"),
    ("device", "Unknown PyTorch build 'ROCM'"),
])
def test_refusals_name_what_to_change(tmp_path, case, match):
    (tmp_path / "empty").mkdir()
    kwargs = {"offline": dict(online=False), "missing": dict(wheel_dir=str(tmp_path / "nowhere")),
              "empty": dict(wheel_dir=str(tmp_path / "empty")), "mac-cuda": dict(device="CUDA", platform="darwin"),
              "device": dict(device="ROCM")}[case]
    with pytest.raises(SetupError, match=match):
        torch_setup.plan_setup(str(tmp_path / "env"), PY, **{"device": "CPU", **kwargs})


def test_blenders_python_is_found(tmp_path):
    python = tmp_path / "python3.11"
    python.write_text("")
    assert torch_setup.base_python(str(python)) == str(python)
    # Blender before 2.91: sys.executable is Blender itself, bpy.app.binary_path_python the Python
    assert torch_setup.base_python("/opt/blender/blender", str(python)) == str(python)
    with pytest.raises(SetupError, match="Blender's Python interpreter was not found .*Python with torch"):
        torch_setup.base_python("/opt/blender/blender")


PIP_ONLINE = """Looking in indexes: https://download.pytorch.org/whl/cpu, https://pypi.org/simple
Collecting torch>=2.1
  Downloading https://download.pytorch.org/whl/cpu/torch-2.13.0%2Bcpu-cp311-cp311-manylinux_2_28_x86_64.whl (190.0 MB)
Progress 0 of 199229440
Progress 99614720 of 199229440
"""


def test_pip_output_becomes_coarse_progress():
    p = torch_setup.PipProgress()
    assert p.status() == "Starting pip" and p.share() == 0.0
    p.feed(PIP_ONLINE)
    assert p.collected == 1 and p.file_fraction == pytest.approx(0.5)
    assert p.status() == "Downloading torch-2.13.0%2Bcpu-cp311-cp311-manylinux_2_28_x86_64.whl (190.0 MB) 50%"
    share = p.share()
    assert 0.0 < share < 0.8
    p.feed("Collecting numpy\r\nProcessing ./numpy-2.4.6-cp311.whl\nInstalling collected packages: numpy, torch\n")
    assert p.phase == "install" and p.installing == 2 and p.share() == 0.8 > share
    p.feed("Successfully installed numpy-2.4.6 torch-2.13.0+cpu\n")
    assert p.phase == "installed" and p.share() == 1.0
    p.feed("ERROR: Could not find a version that satisfies the requirement torch>=2.1 (from versions: none)\n")
    assert p.pip_errors == ["ERROR: Could not find a version that satisfies the requirement torch>=2.1 "
                            "(from versions: none)"]


def test_failures_are_explained(tmp_path):
    folder = wheels(tmp_path)
    offline = torch_setup.plan_setup(str(tmp_path / "env"), PY, wheel_dir=folder)
    lines = ["Looking in links: x", "ERROR: Could not find a version that satisfies the requirement pillow>=10",
             "ERROR: No matching distribution found for pillow>=10"]
    message = torch_setup.explain_failure(offline.steps[1], lines, offline)
    assert message.startswith(f"The wheel folder {folder} lacks a wheel") and "pip download" in message
    online = torch_setup.plan_setup(str(tmp_path / "env"), PY)
    message = torch_setup.explain_failure(online.steps[2], ["WARNING: Retrying ... NewConnectionError(...)",
                                                            "ERROR: No matching distribution found for torch"], online)
    assert message.startswith("Could not reach the package index")
    message = torch_setup.explain_failure(online.steps[0], ["Error: Command '...ensurepip...' returned 1"], online)
    assert "could not create a virtual environment" in message


def test_candidate_interpreters_in_order_each_once(tmp_path):
    def venv(name):
        path = tmp_path / name / "bin"
        path.mkdir(parents=True)
        (path / "python").write_text("")
        return str(tmp_path / name)

    addon_dir = os.path.join(os.path.dirname(venv(".venv")), "addon")
    private, conda = venv("private"), venv("conda")
    found = torch_setup.candidate_interpreters(addon_dir, {"VIRTUAL_ENV": os.path.join(tmp_path, ".venv"),
                                                           "CONDA_PREFIX": conda}, private_env=private)
    assert [c.label.split(" (")[0] for c in found] == ["Private environment", "This checkout's .venv",
                                                       "Active conda environment"]
    assert found[0].python == torch_setup.env_python(private)
    assert torch_setup.candidate_interpreters(str(tmp_path / "x" / "addon"), {}, private_env="") == []


def test_requirements_are_the_librarys_own():
    """The private environment gets exactly what pyproject.toml declares for nerf_core (and its `exr`
    extra): one list of needs, so the add-on never installs a torch the library refuses."""
    import tomllib

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(root, "pyproject.toml"), "rb") as fh:
        project = tomllib.load(fh)["project"]
    assert list(torch_setup.REQUIREMENTS) == project["dependencies"]
    assert [torch_setup.EXR_REQUIREMENT] == project["optional-dependencies"]["exr"]

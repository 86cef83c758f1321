"""nerf_core.contract: stdlib + numpy only, and its rules."""
import subprocess
import sys
import os

from nerf_core import contract


def test_imports_with_torch_blocked():
    # The add-on imports the contract inside Blender, where torch must never load.
    code = ("import sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'torch' or name.startswith('torch.'):\n"
            "            raise ImportError('torch blocked')\n"
            "sys.meta_path.insert(0, Block())\n"
            "import nerf_core.contract as c\n"
            "assert 'torch' not in sys.modules\n"
            "print(c.latest_checkpoint('R'))\n")
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == os.path.join("R", "checkpoints", "latest.pt")


def test_run_paths():
    assert contract.step_checkpoint("R", 12) == os.path.join("R", "checkpoints", "step_0000012.pt")
    assert contract.preview_path("R", 3) == os.path.join("R", "previews", "step_0000003.png")
    assert contract.config_path("R") == os.path.join("R", "config.json")


def test_budget_fraction():
    assert contract.budget_fraction(50, 10.0, 100, 40.0) == 0.5  # steps run out first
    assert contract.budget_fraction(10, 30.0, 100, 40.0) == 0.75  # seconds run out first
    assert contract.budget_fraction(500, None, 100, None) == 1.0  # clamped
    assert contract.budget_fraction(5, 1.0, None, None) is None
    assert contract.budget_fraction(None, None, 100, 10) is None


def test_parse_event_line():
    assert contract.parse_event_line('{"event": "step", "step": 3}\n') == {"event": "step", "step": 3}
    for bad in ("", "warning: x", '{"event": 3}', '{"step": 1}', '{"event": "st', "[1]"):
        assert contract.parse_event_line(bad) is None

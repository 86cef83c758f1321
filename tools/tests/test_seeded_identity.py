"""tools/seeded_identity.py: two runs of the same commit print the same fingerprints."""
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _fingerprints(out):
    proc = subprocess.run([sys.executable, str(REPO / "tools" / "seeded_identity.py"), str(out),
                           "--vmgrid-steps", "4", "--nerf-steps", "2"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return [json.loads(line) for line in proc.stdout.splitlines()]


def test_seeded_runs_repeat_bit_for_bit(tmp_path):
    first, second = _fingerprints(tmp_path / "a"), _fingerprints(tmp_path / "b")
    assert [f["method"] for f in first] == ["vmgrid", "nerf"]
    assert first == second and all(len(f["weights_sha256"]) == 64 for f in first)


def test_an_existing_folder_is_refused(tmp_path):
    proc = subprocess.run([sys.executable, str(REPO / "tools" / "seeded_identity.py"), str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "exists; name a new folder" in proc.stderr

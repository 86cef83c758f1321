#!/usr/bin/env bash
# Create (or reuse) the project's virtual environment at .venv and install the project into it.
# Sourced by scripts/demo.sh and scripts/test.sh so both README commands set up the same way.
# Usage: bash scripts/setup_env.sh            (prints the venv's python path on its last line)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"

die() { echo "setup: ERROR: $*" >&2; exit 1; }

# bpy==5.0.1 ships wheels for CPython 3.11 only, so pick a 3.11 interpreter explicitly.
pick_python() {
    for cand in "${NERF_PYTHON:-}" python3.11 python3 python; do
        [ -n "$cand" ] || continue
        command -v "$cand" >/dev/null 2>&1 || continue
        if "$cand" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' 2>/dev/null; then
            echo "$cand"; return 0
        fi
    done
    return 1
}

if [ ! -x "$venv/bin/python" ]; then
    py="$(pick_python)" || die "Python 3.11 is required (bpy==5.0.1 has wheels for 3.11 only).
  Found: $(python3 --version 2>&1 || echo 'no python3').
  Install Python 3.11 (e.g. 'pyenv install 3.11' or your distribution's python3.11 package),
  or point NERF_PYTHON at a 3.11 interpreter, then run this command again."
    echo "setup: creating virtual environment $venv with $py" >&2
    "$py" -m venv "$venv" || die "could not create $venv; on Debian/Ubuntu install python3.11-venv."
fi
"$venv/bin/python" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' \
    || die "$venv is not a Python 3.11 environment; delete it ('rm -rf .venv') and run again."

# Reinstall only when the dependency spec (pyproject.toml or the exact pins in constraints.txt)
# changed since the last successful install.
stamp="$venv/.nerf_installed"
want="$(cat "$root/pyproject.toml" "$root/constraints.txt" | sha256sum | cut -d' ' -f1)"
# Wheels of the library's runtime dependencies, at the pinned versions, for the tests that build a
# fresh environment with no network: the wheel install test and the add-on's "Set up PyTorch".
wheelhouse="$venv/wheelhouse"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    echo "setup: installing dependencies into $venv (bpy is ~800 MB on first install)" >&2
    "$venv/bin/python" -m pip install --disable-pip-version-check -q --upgrade pip >&2 || true
    if ! "$venv/bin/python" -m pip install --disable-pip-version-check -q -e "$root[dev]" -c "$root/constraints.txt" >&2; then
        die "pip install failed (see above). Check your network access to PyPI and that
  'pip install torch==2.13.0' and 'pip install bpy==5.0.1' work for $("$venv/bin/python" --version)."
    fi
    rm -rf "$wheelhouse"
    if ! "$venv/bin/python" -m pip download --disable-pip-version-check -q -d "$wheelhouse" \
            -c "$root/constraints.txt" torch numpy pillow openexr >&2; then
        die "could not fetch the dependency wheels into $wheelhouse (see above)."
    fi
    echo "$want" > "$stamp"
else
    echo "setup: reusing $venv (dependencies unchanged)" >&2
fi
"$venv/bin/python" - <<'PY' >&2 || die "the environment is incomplete; delete .venv and run again."
import importlib
for mod in ("torch", "numpy", "OpenEXR", "bpy", "pytest", "xdist", "matplotlib", "skimage", "fast_simplification", "nerf_core"):
    importlib.import_module(mod)
PY
echo "$venv/bin/python"

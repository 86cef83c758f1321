#!/usr/bin/env bash
# README command 2: set up .venv and run every test (pyproject.toml's testpaths).
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -k capture`.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
py="$(bash "$root/scripts/setup_env.sh" | tail -n 1)"
cd "$root"
set +e
"$py" -m pytest "$@"
rc=$?
set -e
# pytest exits 5 when it collected nothing: a test command that ran no test is a failure.
if [ "$rc" -eq 5 ]; then
    echo "test: ERROR: pytest collected no tests" >&2
    exit 1
fi
exit "$rc"

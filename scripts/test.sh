#!/usr/bin/env bash
# README command 2: set up .venv and run every test (pyproject.toml's testpaths).
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -k capture`.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
py="$(bash "$root/scripts/setup_env.sh" | tail -n 1)"
cd "$root"
# Tests run in parallel, one pytest-xdist worker per core (NERF_TEST_WORKERS=0 runs them in this process;
# a number picks that many). Each worker's torch, and every process a test starts, uses one thread, so
# two workers on two cores do not fight over them. worksteal: the long tests (a killed training loop, a
# wheel installed offline) do not leave one worker idle while the other finishes a queue.
workers="${NERF_TEST_WORKERS:-auto}"
par=()
if [ "$workers" != "0" ]; then
    par=(-n "$workers" --dist worksteal)
    export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
fi
set +e
"$py" -m pytest "${par[@]}" "$@"
rc=$?
set -e
# pytest exits 5 when it collected nothing: a test command that ran no test is a failure.
if [ "$rc" -eq 5 ]; then
    echo "test: ERROR: pytest collected no tests" >&2
    exit 1
fi
exit "$rc"

#!/usr/bin/env bash
# README command 1: set up .venv and run the main job end to end (scripts/demo.py; flags pass through).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
py="$(bash "$root/scripts/setup_env.sh" | tail -n 1)"
exec "$py" "$root/scripts/demo.py" "$@"

#!/usr/bin/env bash
# Create .venv on Python 3.12 and install FlatLab-LeRobot (editable) with its test extras.
# Python 3.12 is looked up as: $PYTHON, python3.12 on PATH, then pyenv's installed 3.12.x.
set -euo pipefail
cd "$(dirname "$0")/.."
is312() { "$1" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' >/dev/null 2>&1; }
py=""
candidates=("${PYTHON:-}" "$(command -v python3.12 || true)")
if command -v pyenv >/dev/null 2>&1; then
  for v in $(pyenv versions --bare 2>/dev/null | grep -E '^3\.12(\.|$)' || true); do
    candidates+=("$(pyenv root)/versions/$v/bin/python")
  done
fi
for c in "$HOME"/.pyenv/versions/3.12*/bin/python; do candidates+=("$c"); done
for c in "${candidates[@]}"; do
  if [ -n "$c" ] && is312 "$c"; then py="$c"; break; fi
done
[ -n "$py" ] || { echo "setup: Python 3.12 not found (set PYTHON=/path/to/python3.12)" >&2; exit 1; }
[ -x .venv/bin/python ] || "$py" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
echo "setup: ready ($(.venv/bin/python --version), $(.venv/bin/python -c 'import mujoco, lerobot; print("mujoco", mujoco.__version__, "lerobot", lerobot.__version__)'))"

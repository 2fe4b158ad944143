#!/usr/bin/env bash
# Create .venv on Python 3.12 and install FlatLab-LeRobot (editable) with its test extras.
# Python 3.12 is looked up as: $PYTHON, python3.12 on PATH, then pyenv (`pyenv prefix 3.12*`).
set -euo pipefail
cd "$(dirname "$0")/.."
py="${PYTHON:-}"
if [ -z "$py" ] && command -v python3.12 >/dev/null 2>&1; then py=$(command -v python3.12); fi
if [ -z "$py" ] && command -v pyenv >/dev/null 2>&1; then
  v=$(pyenv versions --bare | grep -E '^3\.12(\.|$)' | tail -n 1 || true)
  [ -n "$v" ] && py="$(pyenv root)/versions/$v/bin/python"
fi
if [ -z "$py" ]; then
  for c in "$HOME"/.pyenv/versions/3.12*/bin/python; do [ -x "$c" ] && py="$c"; done
fi
[ -n "$py" ] || { echo "setup: Python 3.12 not found (set PYTHON=/path/to/python3.12)" >&2; exit 1; }
[ -x .venv/bin/python ] || "$py" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
echo "setup: ready ($(.venv/bin/python --version), $(.venv/bin/python -c 'import mujoco, lerobot; print("mujoco", mujoco.__version__, "lerobot", lerobot.__version__)'))"

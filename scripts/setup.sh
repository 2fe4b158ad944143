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
# A CI run once ended in "No space left on device" half-way through torch's CUDA wheels: say so up front.
avail_kb=$(df -Pk . | awk 'NR==2 {print $4}')
[ "${avail_kb:-0}" -ge 8000000 ] || echo "setup: warning: only $((avail_kb / 1024)) MB free here; the install needs about 7 GB" >&2
# torch pulls several GB of CUDA wheels from PyPI; a dropped connection mid-download
# (seen in CI: nvidia-cublas stuck at 289 of 423 MB) must not fail the whole setup.
# pip resumes a broken download itself (PIP_RESUME_RETRIES); a failed install is
# retried whole, reusing the wheels already in pip's cache.
export PIP_RESUME_RETRIES="${PIP_RESUME_RETRIES:-20}"
pipi() {
  local attempt
  for attempt in 1 2 3; do
    .venv/bin/python -m pip install -q "$@" && return 0
    echo "setup: pip install $* failed (attempt $attempt of 3); free disk: $(df -h --output=avail . | tail -n 1 | tr -d ' ') here, $(df -h --output=avail "${TMPDIR:-/tmp}" | tail -n 1 | tr -d ' ') in ${TMPDIR:-/tmp} (the install needs about 7 GB)" >&2
    [ "$attempt" = 3 ] || sleep $((attempt * 15))
  done
  return 1
}
pipi --upgrade pip
pipi -e ".[test]"
# torchcodec, lerobot's default video decoder, loads FFmpeg's shared libraries (libavcodec, ...) from the
# system; without them every lerobot-train / lerobot-dataset-viz run prints ~10 OSError tracebacks and
# falls back to pyav.  Debian/Ubuntu as root: install them (the `ffmpeg` package pulls the distro's
# libav* of whatever version); otherwise say how.  Not fatal: pyav still decodes everything.
if ! .venv/bin/python -c 'import torchcodec' >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends ffmpeg; } >/dev/null 2>&1 \
      || echo "setup: warning: apt-get install ffmpeg failed; videos decode with pyav (lerobot prints torchcodec tracebacks)" >&2
  else
    echo "setup: note: torchcodec finds no FFmpeg libraries; install them (Debian/Ubuntu: sudo apt-get install ffmpeg)," \
      "or lerobot decodes videos with pyav after printing torchcodec tracebacks" >&2
  fi
fi
echo "setup: ready ($(.venv/bin/python --version), $(.venv/bin/python -c 'import mujoco, lerobot; print("mujoco", mujoco.__version__, "lerobot", lerobot.__version__)'), video decoder: $(.venv/bin/python -c 'import torchcodec; print("torchcodec")' 2>/dev/null || echo pyav))"

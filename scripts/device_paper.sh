#!/usr/bin/env bash
# Run `flatlab paper --preset paper` training stages on a lent GPU machine, side by side.
#
#   here:   bash scripts/device_paper.sh --prepare STAGE_INPUT_FOLDER...   (wheels + inputs into .devsite/)
#   there:  bash scripts/device_paper.sh STAGE...                          (through the `device` tool, carry .devsite)
#
# The GPU machine's image has torch 2.11 / CUDA, numpy, pandas, pyarrow, huggingface_hub, but not lerobot: its
# wheels (and those of datasets, draccus, gymnasium, mujoco, ...) travel in .devsite/ and are installed into
# /tmp/flatlab_site. Two packages stay behind because of their size: PyAV (40 MB with its ffmpeg;
# lerobot.datasets imports it at module level, only video features call it -- the strategy sets hold
# none) is replaced by a stand-in that raises when called, and diffusers (lerobot imports it only if present).
# The inputs (LeRobotDatasets made here by the same preset) travel as one .tar.xz and the stages find them
# done through their records in docs/results/paper/stages/ (same fingerprints). Each stage runs in its own
# process group, killed at $STAGE_TIMEOUT s; lerobot-train checkpoints every save_freq steps, so a killed
# stage resumes from its last checkpoint on the next run. Everything comes back under $OUT as tarballs.
set -o pipefail
cd "$(dirname "$0")/.."
DEV=.devsite

if [ "${1:-}" = "--prepare" ]; then
  shift
  mkdir -p "$DEV"
  grep -qx "/$DEV/" "$(git rev-parse --git-path info/exclude)" || echo "/$DEV/" >>"$(git rev-parse --git-path info/exclude)"
  rm -f "$DEV"/*.whl
  for spec in lerobot==0.6.1 datasets==4.8.5 dill==0.4.1 multiprocess==0.70.19 draccus==0.11.6 mergedeep==1.3.4 \
      gymnasium==1.4.0 Farama-Notifications==0.0.6 mujoco==4.0.0 mujoco-core==4.0.0 pytz==2026.6 termcolor==3.3.0; do
    .venv/bin/python -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
      --platform manylinux2014_x86_64 -d "$DEV" "$spec" 2>/dev/null || { echo "no wheel for $spec"; exit 1; }
  done
  tar -cJf "$DEV/inputs.tar.xz" "$@"
  git rev-parse HEAD >"$DEV/commit"
  du -sh "$DEV"
  exit 0
fi

OUT=${OUT:-outputs/device_out}
mkdir -p "$OUT"
SITE=/tmp/flatlab_site
t0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" "$DEV"/*.whl || exit 3
mkdir -p "$SITE/av" "$SITE/av-0.0.0.dist-info" "$SITE/lerobot_env_flatlab-0.1.0.dist-info"
printf 'Metadata-Version: 2.1\nName: av\nVersion: 0.0.0\n' >"$SITE/av-0.0.0.dist-info/METADATA"  # lerobot.datasets asks its version
cat >"$SITE/av/__init__.py" <<'EOF'
"""Stand-in for PyAV (not carried to the GPU machine): importable, raises when a video is touched."""


class _Missing:
    def __getattr__(self, name):
        return _Missing()

    def __call__(self, *a, **k):
        raise ImportError("PyAV is not installed on this machine (scripts/device_paper.sh stand-in)")

    def __or__(self, other):
        return self

    __ror__ = __or__


class VideoFrame:
    pass


def __getattr__(name):
    return _Missing()
EOF
# lerobot imports its plugins by distribution name (lerobot_env_*): the package itself is this tree
printf 'Metadata-Version: 2.1\nName: lerobot_env_flatlab\nVersion: 0.1.0\n' >"$SITE/lerobot_env_flatlab-0.1.0.dist-info/METADATA"
export PYTHONPATH="$SITE:$PWD" PATH="$SITE/bin:$PATH" HF_HUB_OFFLINE=1 HF_DATASETS_OFFLINE=1 PYTHONUNBUFFERED=1
export FLATLAB_GIT_COMMIT=$(cat "$DEV/commit" 2>/dev/null)
unset MUJOCO_GL
tar -xJf "$DEV/inputs.tar.xz" || exit 5
python3 - <<'EOF' || exit 4
import torch, lerobot, lerobot_env_flatlab  # noqa: F401
from lerobot.scripts.lerobot_train import main  # noqa: F401
print("torch", torch.__version__, "cuda", torch.cuda.is_available(), torch.cuda.get_device_name(0) if torch.cuda.is_available() else "-")
EOF
nproc; nvidia-smi -L
echo "setup $(( $(date +%s) - t0 )) s"

# a queue: at most $PARALLEL stages at a time, in the order given; a stage starts only while the time left
# exceeds 1.2 x the first finished stage's wall time (before one has finished: always)
PARALLEL=${PARALLEL:-2}
LOGS=/tmp/device_logs; mkdir -p $LOGS
deadline=$(( $(date +%s) + ${STAGE_TIMEOUT:-480} ))
queue=("$@"); declare -A pid start; first=0
while :; do
  now=$(date +%s)
  for s in "${!pid[@]}"; do
    if ! kill -0 "${pid[$s]}" 2>/dev/null; then
      wait "${pid[$s]}"; echo "[$s] exit $? after $(( now - start[$s] )) s"
      [ $first = 0 ] && first=$(( now - start[$s] )); unset "pid[$s]"
    fi
  done
  while [ ${#queue[@]} -gt 0 ] && [ ${#pid[@]} -lt $PARALLEL ]; do
    s=${queue[0]}; queue=("${queue[@]:1}")
    if [ $first -gt 0 ] && [ $(( deadline - now )) -lt $(( first * 12 / 10 )) ]; then echo "[$s] not started: $(( deadline - now )) s left"; continue; fi
    setsid python3 -m flatlab_lerobot.cli paper --preset paper --only "$s" --no-render >>"$LOGS/$s.log" 2>&1 &
    pid[$s]=$!; start[$s]=$now; echo "[$s] started"
  done
  [ ${#pid[@]} = 0 ] && break
  if [ "$now" -ge $deadline ]; then
    for s in "${!pid[@]}"; do echo "[$s] stopped at the deadline"; kill -TERM -- -"${pid[$s]}" 2>/dev/null; done
    sleep 5; break
  fi
  sleep 3
done
for s in "$@"; do
  [ -f "$LOGS/$s.log" ] || continue
  echo "== $s"; grep -E "^\[|step:[0-9]+ " "$LOGS/$s.log" | tail -3
  # the checkpoints' pretrained_model folders (what strategy-eval --select scores); no optimizer states
  [ -d "outputs/paper/paper/$s" ] && tar -czf "$OUT/$s.tar.gz" --exclude='training_state' "outputs/paper/paper/$s"
done
tar -czf "$OUT/records.tar.gz" docs/results/paper outputs/paper/paper/logs $LOGS 2>/dev/null
ls -la "$OUT"
echo "total $(( $(date +%s) - t0 )) s"

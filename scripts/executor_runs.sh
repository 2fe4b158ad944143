#!/usr/bin/env bash
# The action execution module's measured runs (issue 17): build the Train primitive set, export it
# for lerobot-train, train a recipe of policies/flatlab_executor/ with the real lerobot-train CLI,
# and report pose errors (P-MSE / R-Err) on the Train frames and on Test-alpha / Test-beta sets that
# are exported --eval-only (they can never train the executor; no checkpoint is selected on them:
# lerobot-train's last checkpoint is the one used).
# Re-running skips what is done.  Usage: scripts/executor_runs.sh [recipe ...]   (default: cpu)
# Env: DEMOS (Train demos per object, default 20), TEST_DEMOS (per Test object, default 2).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-python}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}  # 1 thread: see docs/executor.md "Speed"
BIN=$(dirname "$(command -v $PY)")
L=outputs/learning
DEMOS=${DEMOS:-20}
TEST_DEMOS=${TEST_DEMOS:-2}
timed() {  # json-out cmd...: run cmd, write {"command", "wall_s"} to json-out
  local out=$1; shift
  local t0; t0=$(date +%s)
  "$@"
  printf '{"command": "%s", "wall_s": %s, "machine": "%s CPU cores, no GPU"}\n' "$*" $(( $(date +%s) - t0 )) "$(nproc --all)" > "$out"
}
set_if() {  # out objects demos
  [ -f "$1/meta.json" ] || timed "$1.wall.json" $PY -m flatlab_lerobot.cli primitive-set --objects "$2" --demos "$3" --workers 2 --no-progress --out "$1"
}
export_if() {  # set out [--eval-only]
  local set=$1 out=$2; shift 2
  [ -f "$out/flatlab_export.json" ] || $PY -m flatlab_lerobot.cli primitive-export --set "$set" --out "$out" --overwrite "$@"
}
set_if $L/primitive_set_cpu split:train "$DEMOS"
export_if $L/primitive_set_cpu $L/primitive_dataset_cpu
mkdir -p docs/results
for r in ${*:-cpu}; do
  out=outputs/train/executor_$r
  if [ ! -f "$out/checkpoints/last/pretrained_model/model.safetensors" ]; then
    resume=()
    [ -f "$out/checkpoints/last/training_state/training_step.json" ] && resume=(--resume=true --config_path=$out/checkpoints/last/pretrained_model/train_config.json)
    if [ ${#resume[@]} -eq 0 ]; then rm -rf "$out"; resume=(--config_path=policies/flatlab_executor/$r.json --output_dir=$out --dataset.root=$L/primitive_dataset_cpu); fi
    mkdir -p outputs/logs
    timed outputs/logs/executor_train_$r.wall.json $BIN/lerobot-train "${resume[@]}" > outputs/logs/train_executor_$r.log 2>&1
    cp outputs/logs/executor_train_$r.wall.json "$out/train_wall.json"
  fi
  set_if $L/primitive_set_alpha split:test_alpha "$TEST_DEMOS"
  export_if $L/primitive_set_alpha $L/primitive_dataset_alpha --eval-only
  set_if $L/primitive_set_beta split:test_beta "$TEST_DEMOS"
  export_if $L/primitive_set_beta $L/primitive_dataset_beta --eval-only
  res=docs/results/executor_$r.json
  [ -f "$res" ] || $PY -m flatlab_lerobot.cli executor-metrics --policy.path $out/checkpoints/last/pretrained_model \
      --dataset $L/primitive_dataset_cpu --dataset $L/primitive_dataset_alpha --dataset $L/primitive_dataset_beta --out "$res"
done

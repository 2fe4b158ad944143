#!/usr/bin/env bash
# The strategy generator's measured runs (issue 16): export the strategy set for lerobot-train,
# train each recipe of policies/flatlab_strategy/ with the real lerobot-train CLI, select the
# checkpoint on held-out TRAIN views, score on the benchmark objects in fresh placements.
# Re-running skips what is done.  Usage: scripts/strategy_runs.sh [recipe ...]  (default: cpu + ablations)
# Needs: outputs/learning/strategy_set (flatlab strategy-set --splits train --views 3 --image-size 256
#        --extras scene,rgb) and outputs/learning/strategy_eval_set (--splits all --scales 0
#        --no-counterparts --views 3 --seed 1000 --image-size 256 --extras scene,rgb).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-python}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}  # 1 thread: 10x faster than 2 on a contended 2-core machine
BIN=$(dirname "$(command -v $PY)")
L=outputs/learning
export_if() {  # out args...
  local out=$1; shift
  [ -f "$out/meta/flatlab_strategy_export.json" ] || $PY -m flatlab_lerobot.cli strategy-export --set $L/strategy_set --out "$out" "$@"
}
export_if $L/strategy_lerobot_cpu --points 512
export_if $L/strategy_lerobot_cpu_orig --points 512 --originals-only
export_if $L/strategy_lerobot_cpu_scene --inputs scene --points 512
export_if $L/strategy_lerobot_cpu_rgb --inputs rgb
export_if $L/strategy_lerobot_cpu_nocp --points 512 --no-counterparts
RECIPES=${*:-cpu ablation_A1 ablation_A2 ablation_A3 ablation_A7 ablation_A8}
mkdir -p docs/results
for r in $RECIPES; do
  out=outputs/train/strategy_$r
  if [ "$r" = paper ]; then export_if $L/strategy_lerobot; fi
  if [ ! -f "$out/checkpoints/last/pretrained_model/model.safetensors" ]; then
    rm -rf "$out"
    t0=$(date +%s)
    $BIN/lerobot-train --config_path=policies/flatlab_strategy/$r.json --output_dir=$out > outputs/train_strategy_$r.log 2>&1
    echo "{\"recipe\": \"$r\", \"train_wall_s\": $(( $(date +%s) - t0 )), \"command\": \"lerobot-train --config_path=policies/flatlab_strategy/$r.json --output_dir=$out\", \"machine\": \"2 CPU cores, no GPU (shared)\"}" > $out/train_wall.json
  fi
  res=docs/results/strategy_$r.json
  [ -f "$res" ] || $PY -m flatlab_lerobot.cli strategy-eval --policy $out --set $L/strategy_eval_set \
      --label "policies/flatlab_strategy/$r.json" --train-wall "$out/train_wall.json" --out "$res"
done

#!/usr/bin/env bash
# The end-to-end baselines' measured runs (issue 18), resumable: for each recipe id (act, diffusion,
# flatlab_dp3) train policies/<id>/cpu.json with the real lerobot-train on the successful demos of
# outputs/datasets/baselines_cpu (or RECIPE's recipe on its demos, below; resuming from the last checkpoint when one exists), then score the
# last checkpoint with `flatlab eval` (resuming an interrupted one) and write docs/results/eval_<id>.json (eval_dp3.json for flatlab_dp3: the stage names of flatlab paper) (command, seeds, wall, commit).
# Usage: scripts/baseline_runs.sh [id ...]   env: STEPS / SAVE_FREQ (override the recipe's), TRIALS (default 1), STAGE=train|eval|all,
#   RECIPE (default cpu: policies/<id>/$RECIPE.json, its demos datasets/<basename of its dataset.root>.yaml),
#   OBJECTS (flatlab eval --objects; default: the 104 benchmark objects), SEED (default 1000).
# RECIPE=overfit_box_shoe OBJECTS=box_shoe TRIALS=10: the overfit check of docs/baselines.md (records eval_<id>_overfit_box_shoe[_s<SEED>].json).
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} MUJOCO_GL=${MUJOCO_GL:-egl} PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
BIN=${BIN:-$PWD/.venv/bin}
TRIALS=${TRIALS:-1}; STAGE=${STAGE:-all}; RECIPE=${RECIPE:-cpu}; SEED=${SEED:-1000}
MACHINE=$($BIN/python -c "from flatlab_lerobot.paper.pipeline import machine_line; print(machine_line())")
for id in ${*:-act flatlab_dp3 diffusion}; do
  conf=policies/$id/$RECIPE.json
  DATA=$(python3 -c "import json; print(json.load(open('$conf'))['dataset']['root'])")
  demos=datasets/$(basename "$DATA").yaml
  [ -d "$DATA/meta" ] || $BIN/flatlab collect --recipe $demos
  OK=$($BIN/flatlab collect --recipe $demos --successful-episodes)
  out=$(python3 -c "import json; print(json.load(open('$conf'))['output_dir'])")
  suffix=; how=; [ "$RECIPE" = cpu ] || { suffix=_$RECIPE; how="RECIPE=$RECIPE ${OBJECTS:+OBJECTS=$OBJECTS }TRIALS=$TRIALS "; }
  [ "$SEED" = 1000 ] || { suffix=${suffix}_s$SEED; how="${how}SEED=$SEED "; }
  if [ -n "${OBJECTS:-}" ]; then objs=(--objects "$OBJECTS"); scope="$OBJECTS"; else objs=(); scope="the 104 benchmark objects"; fi
  case $id in
    flatlab_dp3) flags=(--env.obs_pixels=false --env.n_points=1024) ;;
    *) flags=(--env.image_size=64 --env.obs_pointcloud=false) ;;
  esac
  if [ "$STAGE" != eval ]; then
    cmd=($BIN/lerobot-train --config_path=$conf --dataset.episodes="$OK" --output_dir=$out ${STEPS:+--steps=$STEPS} ${SAVE_FREQ:+--save_freq=$SAVE_FREQ})
    last=$out/checkpoints/last/pretrained_model/train_config.json
    if [ -f "$last" ]; then cmd=($BIN/lerobot-train --config_path=$last --resume=true ${STEPS:+--steps=$STEPS}); else rm -rf "$out"; fi
    t0=$(date +%s)
    "${cmd[@]}" >> outputs/logs/train_$(basename $out).log 2>&1
    prev=$(python3 -c "import json;print(json.load(open('$out/train_wall.json'))['train_wall_s'])" 2>/dev/null || echo 0)
    echo "{\"recipe\": \"$conf\", \"train_wall_s\": $(( prev + $(date +%s) - t0 )), \"episodes\": \"successful demos of $DATA ($(echo "$OK" | tr ',' '\n' | wc -l))\", \"machine\": \"$MACHINE\"}" > $out/train_wall.json
  fi
  if [ "$STAGE" != train ]; then
    ev=outputs/eval/$(basename $out)_t$TRIALS; [ "$SEED" = 1000 ] || ev=${ev}_s$SEED
    # an interrupted evaluation resumes (flatlab eval keeps finished trials); one of an older checkpoint restarts
    [ -f "$ev/run.json" ] && [ "$out/checkpoints/last/pretrained_model/model.safetensors" -nt "$ev/run.json" ] && rm -rf "$ev"
    prev=$(cat "$ev/wall_s" 2>/dev/null || echo 0); t0=$(date +%s)
    $BIN/flatlab eval --policy $out/checkpoints/last/pretrained_model --trials $TRIALS --seed $SEED --workers 2 "${objs[@]}" "${flags[@]}" --out $ev --quiet --no-plot \
      || { echo $(( prev + $(date +%s) - t0 )) > "$ev/wall_s"; echo "eval of $id stopped: rerun to resume"; exit 1; }
    wall=$(( prev + $(date +%s) - t0 )); echo $wall > "$ev/wall_s"
    $BIN/python scripts/eval_record.py --results $ev/results.json --out docs/results/eval_${id#flatlab_}$suffix.json --wall $wall \
      --train $out/train_wall.json --what "$id $RECIPE recipe, last checkpoint; $scope x $TRIALS trial(s), seed $SEED" \
      --command "${how}scripts/baseline_runs.sh $id  (lerobot-train --config_path=$conf --dataset.episodes=<successful>; flatlab eval --policy $out/checkpoints/last/pretrained_model --trials $TRIALS --seed $SEED --workers 2 ${objs[*]} ${flags[*]})"
  fi
done

"""Trace one ``flatlab eval`` trial: at each change of stage, the object's position and both hands' positions.

    python scripts/trace_episode.py --policy outputs/paper/cpu/unified_cpu_one_rot15 --object disk_vinyl_lp \
        --trial 0 -- --env.pointcloud_cameras=[front,top,left,right] --env.n_points=4096 ... --policy.executor_tta=8

Runs the trial exactly as ``flatlab eval`` does (its Evaluator: lerobot's ``eval_policy``, seed ``--seed`` +
``--trial``) and prints one line per stage the policy enters: step, stage index, primitive, the object's
position and both TCP positions (m, world frame), then the policy's per-stage decisions (``flatlab_unified``).
``--attempts`` prints instead one line per attempt (``flatlab_unified``): the step it began, the object the env
targets then (on a ``clear_desk`` desk, the one the policy's object cloud shows), the strategy, its steps and how
it ended (carried, gone home, ruled out by a response, out of reach).
``--policy oracle`` (or another built-in) traces the scripted expert on the same seed.  The trace reads the
simulator's state for the person looking; the policy never sees it.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.evaluation.protocol import evaluator_for


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True, help="pretrained_model folder or a built-in policy name (oracle, ...)")
    ap.add_argument("--object", required=True, help="catalog object id")
    ap.add_argument("--trial", type=int, default=0, help="flatlab eval's trial index (episode seed = --seed + trial)")
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--attempts", action="store_true", help="one line per attempt instead of per stage")
    args, extra = ap.parse_known_args(argv)
    ev = evaluator_for(args.policy, args.seed, [a for a in extra if a != "--"])
    rows: list[tuple] = []
    marks: list[tuple] = []  # (step, target object id, decision entry) for every decision as it is logged
    step = FlatLabEnv.step

    def traced(env, action):
        out = step(env, action)
        logged = ev.policy.decisions[0] if hasattr(ev.policy, "decisions") else []
        marks.extend((env.steps, env.sim.obj.id, e) for e in logged[len(marks):])
        index = (getattr(ev.policy, "stage_indices", None) or [-1])[0]
        stage = (getattr(ev.policy, "stages", None) or [""])[0]
        pos = [env.sim.object_pose()[0]] + [env.sim.tcp_pose(a)[0] for a in ("left", "right")]
        rows.append((env.steps, index, str(stage), *np.round(np.concatenate(pos), 3)))
        return out

    FlatLabEnv.step = traced
    try:
        rec = next(ev.run_object(args.object, [args.trial]))
    finally:
        FlatLabEnv.step = step
    print(json.dumps({k: rec[k] for k in ("object_id", "seed", "strategy", "G", "failure_reason", "final_clearance_m", "steps")}))
    if args.attempts:
        print_attempts(marks, rec["steps"])
        return 0
    print("step  idx stage     object (x y z)          left hand (x y z)       right hand (x y z)")
    fmt = "%4d %4d %-8s" + "  %6.3f %6.3f %6.3f" * 3
    for k, r in enumerate(rows):
        if k == 0 or (r[1], r[2]) != (rows[k - 1][1], rows[k - 1][2]):
            print(fmt % r)
    if rows:
        print("end:", fmt % rows[-1])
    for entry in getattr(ev.policy, "decisions", [[]])[0] if hasattr(ev.policy, "decisions") else []:
        print({k: v for k, v in entry.items() if k not in ("active",)})
    return 0


def print_attempts(marks: list[tuple], steps: int) -> None:
    """One line per attempt: first step, target object, strategy, steps, how it ended."""
    starts = [k for k, (_, _, e) in enumerate(marks) if "retry" in e or (k == 0 and "index" in e)]
    print("step  steps object                      strategy  ended")
    for n, k in enumerate(starts):
        end = starts[n + 1] if n + 1 < len(starts) else len(marks)
        entries = [e for _, _, e in marks[k:end]]
        first, obj = marks[k][0], marks[k][1]
        last = marks[end][0] if end < len(marks) else steps
        how = [f"after={e['after']}" for e in entries if "after" in e]
        how += [f"{key}={e[key]}" for e in entries for key in ("unreachable", "quick_retry", "retry_failed")
                if key in e]
        how += [f"response({'fold' if 'fold_rise' in e else 'droop'})" for e in entries if e.get("response_failed")]
        chosen = next((e["retry"]["chosen"] for e in entries if "retry" in e), "?")
        print(f"{first:4d} {last - first:6d} {obj:27s} {chosen:9s} {' '.join(map(str, how))}")


if __name__ == "__main__":
    sys.exit(main())

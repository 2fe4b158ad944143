"""How fast the arms' joints move in ``flatlab eval`` trials, against the Panda's rated joint speeds.

    python scripts/joint_speeds.py --policy oracle --objects ref_box,ref_towel --trials 1 --out F.json
    python scripts/joint_speeds.py --policy outputs/paper/cpu/unified_cpu_top_a --objects book_a5_notebook \
        --trials 1 --out F.json -- --env.pointcloud_cameras=[front,top,left,right] ... --policy.executor_tta=8

Runs each trial exactly as ``flatlab eval`` does (its Evaluator: lerobot's ``eval_policy``, seed ``--seed`` + trial)
and, at every control step, takes the commanded arm joints (the joint action) and the simulated joint speeds.  Per
stage the policy reports (``move``: a transit; ``flatlab_scripted`` and ``flatlab_unified`` name their stages), it
writes the largest commanded speed (the change of the joint target over one 0.1-s step) and measured speed, each as a
multiple of the joint's rated speed (``sim.robot.PANDA_MAX_JOINT_SPEED``), and how many steps went past the rating.
The record names the machine, the
commit and the command line, as the pipeline's records do.  Prints one line per stage.  The simulator's state is read
for the person looking; the policy never sees it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.evaluation.protocol import evaluator_for
from flatlab_lerobot.paper.pipeline import git_commit, machine
from flatlab_lerobot.sim.robot import ARM_JOINTS, ARMS, PANDA_MAX_JOINT_SPEED

RATED = np.tile(PANDA_MAX_JOINT_SPEED, 2)  # (14,): left then right, as the joint action orders them


def record_trial(ev, object_id: str, trial: int) -> tuple[dict, list[tuple[str, np.ndarray, np.ndarray]]]:
    """One trial: its record and, per control step, (stage, commanded joint speeds (14,), measured ones (14,))."""
    step = FlatLabEnv.step
    rows: list[tuple[str, np.ndarray, np.ndarray]] = []
    last: dict[str, np.ndarray] = {}

    def traced(env, action):
        out = step(env, action)
        a = np.asarray(action, float).reshape(-1)
        if a.size != 16:
            raise SystemExit(f"joint_speeds: the joint action has 16 numbers; got {a.size} (--env.action_mode must be joint)")
        q = np.r_[a[0:7], a[8:15]]
        cmd = np.abs(q - last["q"]) / env.sim.control_dt if "q" in last else np.zeros(14)
        last["q"] = q
        stage = str((getattr(ev.policy, "stages", None) or [""])[0]) or "?"
        dofs = np.concatenate([env.sim.arms[arm].dof for arm in ARMS])  # the sim's own address book, left then right
        rows.append((stage, cmd, np.abs(env.sim.data.qvel[dofs])))
        return out

    FlatLabEnv.step = traced
    try:
        rec = next(ev.run_object(object_id, [trial]))
    finally:
        FlatLabEnv.step = step
    return rec, rows[1:]  # the first step has no commanded change to measure


def summarize(rows: list[tuple[str, np.ndarray, np.ndarray]]) -> dict[str, dict]:
    """Per stage: steps, the largest commanded and measured speed as a multiple of the rating (and which joint), and
    the steps on which any joint went past its rating, commanded or measured."""
    out: dict[str, dict] = {}
    for stage in sorted({r[0] for r in rows}):
        cmd = np.array([r[1] for r in rows if r[0] == stage]) / RATED
        meas = np.array([r[2] for r in rows if r[0] == stage]) / RATED
        joint = lambda x: f"{ARMS[int(x.argmax()) % 14 // 7]}/{ARM_JOINTS[int(x.argmax()) % 7]}"  # noqa: E731
        out[stage] = {"steps": len(cmd),
                      "max_commanded_x_rated": round(float(cmd.max()), 2), "max_commanded_joint": joint(cmd),
                      "max_measured_x_rated": round(float(meas.max()), 2), "max_measured_joint": joint(meas),
                      "steps_commanded_over": int((cmd > 1.0).any(axis=1).sum()),
                      "steps_measured_over": int((meas > 1.0).any(axis=1).sum())}  # fmt: skip
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True, help="pretrained_model folder or a built-in policy name (oracle, ...)")
    ap.add_argument("--objects", required=True, help="comma-separated catalog object ids")
    ap.add_argument("--trials", type=int, default=1, help="trials per object (episode seed = --seed + trial)")
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--out", required=True, help="JSON file to write: per stage over all trials, and per trial")
    args, extra = ap.parse_known_args(argv)
    if args.trials < 1:
        ap.error(f"--trials: must be >= 1, got {args.trials}")
    objects = [o for o in args.objects.split(",") if o]
    if not objects:
        ap.error("--objects: give at least one catalog object id")
    ev = evaluator_for(args.policy, args.seed, [a for a in extra if a != "--"])
    t0, rows, trials = time.time(), [], []
    for obj in objects:
        for t in range(args.trials):
            rec, r = record_trial(ev, obj, t)
            rows += r
            s = summarize(r)
            trials.append({"object_id": obj, "seed": rec["seed"], "G": rec["G"], "steps": rec["steps"],
                           "steps_commanded_over": sum(v["steps_commanded_over"] for v in s.values()),
                           "steps_measured_over": sum(v["steps_measured_over"] for v in s.values())})  # fmt: skip
    result = {"policy": args.policy, "flags": [a for a in extra if a != "--"], "seed": args.seed, "trials": args.trials,
              "rated_rad_s": PANDA_MAX_JOINT_SPEED.tolist(), "steps": len(rows), "per_stage": summarize(rows),
              "per_trial": trials, "wall_s": round(time.time() - t0, 1), "machine": machine(), "git": git_commit(),
              "command": " ".join(["python", "scripts/joint_speeds.py", *(argv if argv is not None else sys.argv[1:])])}  # fmt: skip
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print("stage      steps  max cmd/rated (joint)        max meas/rated (joint)       steps over: cmd  meas")
    for stage, v in result["per_stage"].items():
        print(f"{stage:9s} {v['steps']:6d}  {v['max_commanded_x_rated']:5.2f} ({v['max_commanded_joint']:13s})      "
              f"{v['max_measured_x_rated']:5.2f} ({v['max_measured_joint']:13s})      {v['steps_commanded_over']:5d} "
              f"{v['steps_measured_over']:5d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

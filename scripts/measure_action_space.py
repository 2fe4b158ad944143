"""Which action space can an end-to-end baseline learn from our expert demos: ``joint`` or ``ee``?

For each object: run the scripted expert in ``joint`` mode (what ``flatlab collect`` records),
turn each commanded joint target into the TCP pose forward kinematics gives for it (+ the gripper
width), then replay those poses in a fresh env with ``action_mode="ee"`` (the sim's IK turns them
back into joint targets).  A perfect ee policy -- one that reproduces the expert's poses exactly --
reaches at most the replay's success.  Also prints the per-step action change (what a policy must
resolve) and the wall time per env step in each mode.

    python scripts/measure_action_space.py --objects ref_box ref_book --seeds 0 1
"""

from __future__ import annotations

import argparse
import json
import time

import mujoco
import numpy as np

from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.rollout import ExpertPolicy, rollout
from flatlab_lerobot.sim.robot import ARMS


def fk_actions(env: FlatLabEnv, joint_actions: np.ndarray) -> np.ndarray:
    """(T, 16) joint targets -> (T, 14) per arm [TCP xyz, rotvec, gripper] by forward kinematics."""
    from scipy.spatial.transform import Rotation

    m, d = env.sim.model, mujoco.MjData(env.sim.model)
    out = []
    for a in joint_actions:
        row = []
        for i, arm in enumerate(ARMS):
            idx = env.sim.arms[arm]
            d.qpos[idx.qpos] = a[8 * i : 8 * i + 7]
            mujoco.mj_kinematics(m, d)
            pos, R = d.site_xpos[idx.tcp_site].copy(), d.site_xmat[idx.tcp_site].reshape(3, 3)
            row.append(np.r_[pos, Rotation.from_matrix(R).as_rotvec(), a[8 * i + 7]])
        out.append(np.concatenate(row))
    return np.asarray(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--objects", nargs="+", default=["ref_box", "ref_book"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--episode-length", type=int, default=300)
    ap.add_argument("--out", default=None, help="also write the rows as JSON here")
    args = ap.parse_args(argv)
    rows = []
    for oid in args.objects:
        for seed in args.seeds:
            kw = {"object_id": oid, "obs_pixels": False, "obs_pointcloud": False, "episode_length": args.episode_length}
            env = FlatLabEnv(**kw)
            env.reset(seed=seed)
            from flatlab_lerobot.catalog import get_object

            strategy = get_object(oid).strategy
            expert = ExpertPolicy(strategy, env.cell, env.control_dt)
            actions, states = [], []

            def policy(o, _e=expert, _actions=actions, _states=states):
                a = _e(o)
                _actions.append(np.asarray(a, float))
                _states.append(np.asarray(o["agent_pos"], float))
                return a

            policy.reset = expert.reset
            t0 = time.perf_counter()
            ep = rollout(env, policy, seed=seed)
            t_joint = (time.perf_counter() - t0) / max(1, ep.steps)
            ja = np.asarray(actions)
            ee = fk_actions(env, ja)
            env.close()
            env2 = FlatLabEnv(action_mode="ee", **kw)
            env2.reset(seed=seed)
            t0 = time.perf_counter()
            it = iter(ee)
            last = ee[-1]

            def replay(o, _it=it, _last=last):
                return next(_it, _last)

            replay.reset = lambda: None
            ep2 = rollout(env2, replay, seed=seed)
            t_ee = (time.perf_counter() - t0) / max(1, ep2.steps)
            env2.close()
            dj, de = np.abs(np.diff(ja, axis=0)), np.abs(np.diff(ee, axis=0))
            row = {
                "object": oid, "seed": seed, "strategy": strategy,
                "joint": {"success": bool(ep.success), "steps": ep.steps, "failure": ep.failure_reason,
                          "s_per_step": round(t_joint, 4)},
                "ee_replay": {"success": bool(ep2.success), "steps": ep2.steps, "failure": ep2.failure_reason,
                              "s_per_step": round(t_ee, 4)},
                "joint_action_std": float(ja[:, [*range(7), *range(8, 15)]].std(0).mean()),
                "ee_pos_std": float(ee[:, [0, 1, 2, 7, 8, 9]].std(0).mean()),
                "p99_step_change_joint_rad": float(np.quantile(dj[:, [*range(7), *range(8, 15)]], 0.99)),
                "p99_step_change_ee_pos_m": float(np.quantile(de[:, [0, 1, 2, 7, 8, 9]], 0.99)),
                "p99_step_change_ee_rotvec": float(np.quantile(de[:, [3, 4, 5, 10, 11, 12]], 0.99)),
                "max_step_change_ee_rotvec": float(de[:, [3, 4, 5, 10, 11, 12]].max()),
            }  # fmt: skip
            print(json.dumps(row), flush=True)
            rows.append(row)
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"command": "python scripts/measure_action_space.py " + " ".join(argv or __import__("sys").argv[1:]),
                       "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

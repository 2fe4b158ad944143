"""Where an end-to-end baseline leaves its own demonstration (docs/baselines.md, the overfit check).

Replays demo episode E of a collected dataset twice with a trained checkpoint:

* closed loop: the checkpoint drives the env from the demo's own seed (same placement, same start
  state), through lerobot's own ``rollout`` and the processors ``flatlab eval`` builds; per step, the
  largest joint gap to the demo's state and action;
* open loop: the checkpoint's action chunk on the demo's own observations (for policies with
  ``predict_action_chunk`` over ``n_obs_steps`` inputs), against the demo's actions.

Writes a small JSON (``--out``).  Example:
  python scripts/baseline_divergence.py --policy outputs/train/flatlab_dp3_overfit_box_shoe/checkpoints/last/pretrained_model \
      --dataset outputs/datasets/overfit_box_shoe --episode 0 --out docs/results/dp3_overfit_divergence.json -- --obs_pixels=false --n_points=1024
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import time
from pathlib import Path

import numpy as np
import torch


def dumps(rec: dict) -> str:
    """JSON with every list of numbers on one line (a per-step record stays one screen per step)."""
    text = json.dumps(rec, indent=1)
    return re.sub(r"\[\s*([-0-9.e,\s]+?)\s*\]", lambda m: "[" + ", ".join(m.group(1).split()).replace(",,", ",") + "]", text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True, help="pretrained_model folder")
    ap.add_argument("--dataset", type=Path, required=True, help="the LeRobotDataset it was trained on")
    ap.add_argument("--episode", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("env_args", nargs="*", help="after --: the flatlab env flags without the --env. prefix")
    a = ap.parse_args()

    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.envs import make_env
    from lerobot.scripts import lerobot_eval

    from flatlab_lerobot.atomic import write_text
    from flatlab_lerobot.evaluation.protocol import Evaluator
    from flatlab_lerobot.paper.pipeline import git_commit, machine_line

    if not (a.dataset / "meta" / "info.json").is_file():
        raise SystemExit(f"--dataset {a.dataset}: no LeRobotDataset there (meta/info.json missing)")
    t0 = time.perf_counter()
    ds = LeRobotDataset("local/divergence", root=a.dataset, video_backend="pyav")
    if not 0 <= a.episode < ds.meta.total_episodes:
        raise SystemExit(f"--episode {a.episode}: the dataset has {ds.meta.total_episodes} episodes")
    ep = ds.meta.episodes[a.episode]
    lo, hi = ep["dataset_from_index"], ep["dataset_to_index"]
    rows = ds.hf_dataset.select(range(lo, hi))
    seed = int(rows[0]["episode_seed"]) if "episode_seed" in rows.column_names else None
    if seed is None:
        raise SystemExit(f"--dataset {a.dataset}: no episode_seed column: not a flatlab collect dataset")
    state = np.stack([np.asarray(r) for r in rows["observation.state"]])
    action = np.stack([np.asarray(r) for r in rows["action"]])
    object_id = rows[0]["object_id"]

    ev = Evaluator({"builtin": False, "policy": a.policy, "policy_args": [], "env_args": [f"--{x.lstrip('-')}" for x in a.env_args],
                    "seed": seed, "rename_map": {}})  # fmt: skip
    env_cfg = dataclasses.replace(ev.env_cfg, object_id=object_id)
    vec = make_env(env_cfg, n_envs=1, use_async_envs=False)[env_cfg.type][0]
    with torch.no_grad():
        out = lerobot_eval.rollout(vec, ev.policy, ev.env_pre, ev.env_post, ev.pre, ev.post, seeds=[seed], return_observations=True)
    vec.close()
    run_state = out["observation"]["observation.state"][0].numpy()
    run_action = out["action"][0].numpy()
    n = min(len(state), len(run_action))
    closed = [
        {"step": t, "max_state_gap_rad": round(float(np.abs(run_state[t] - state[t]).max()), 4),
         "max_action_gap_rad": round(float(np.abs(run_action[t] - action[t]).max()), 4),
         "state_gap_per_joint_rad": [round(float(x), 3) for x in np.abs(run_state[t] - state[t])]}
        for t in range(n)
    ]  # fmt: skip

    open_loop = None
    pol = ev.policy
    k = int(getattr(pol.config, "n_obs_steps", 1))
    m = int(getattr(pol.config, "n_action_steps", 1))
    cloud_key = "observation.pointcloud"
    if hasattr(pol, "predict_action_chunk") and cloud_key in pol.config.input_features:
        cloud = np.stack([np.asarray(r) for r in rows[cloud_key]])
        errs = []
        for t in range(k - 1, len(state) - m, m):
            batch = {"observation.state": torch.tensor(state[t - k + 1 : t + 1])[None].float(),
                     cloud_key: torch.tensor(cloud[t - k + 1 : t + 1])[None].float()}  # fmt: skip
            pol.reset()
            chunk = ev.post(pol.predict_action_chunk(ev.pre(batch))[0]).numpy()
            errs.append(float(np.abs(chunk - action[t : t + m]).max()))
        open_loop = {"chunks": len(errs), "median_max_gap_rad": round(float(np.median(errs)), 4),
                     "max_gap_rad": round(float(np.max(errs)), 4)}  # fmt: skip

    rec = {
        "what": "a trained baseline replaying its own demo: closed loop from the demo's seed, open loop on the demo's frames",
        "policy": a.policy, "dataset": str(a.dataset), "episode": a.episode, "seed": seed, "object_id": object_id,
        "demo_frames": len(state), "run_steps": len(run_action), "run_success": bool(out["success"][0].any()),
        "start_state_gap_rad": round(float(np.abs(run_state[0] - state[0]).max()), 6),
        "closed_loop": closed, "open_loop": open_loop,
        "demo_action_span_rad": [round(float(x), 3) for x in action.max(0) - action.min(0)],
        "command": "python scripts/baseline_divergence.py --policy {} --dataset {} --episode {} --out {} -- {}".format(
            a.policy, a.dataset, a.episode, a.out, " ".join(a.env_args)),
        "wall_s": round(time.perf_counter() - t0, 1), "git_commit": (git_commit()["commit"] or "")[:7],
        "machine": machine_line(),
    }  # fmt: skip
    write_text(a.out, dumps(rec) + "\n")
    print(f"wrote {a.out}: start gap {rec['start_state_gap_rad']}, open loop {open_loop}")
    for c in closed[:: max(1, n // 12)]:
        print(c["step"], c["max_state_gap_rad"], c["max_action_gap_rad"], np.round(c["state_gap_per_joint_rad"], 2))


if __name__ == "__main__":
    main()

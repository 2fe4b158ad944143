"""Which way the scripted expert turns each wrist, as a function of the object's yaw (docs/baselines.md).

For each object (default: the Train split's B-labelled objects) and each yaw of a grid over the benchmark's
±30°, the expert's episode runs at the table centre (no pixels, no cloud) and this records the final
commanded angle of each arm's wrist joint (joint 7; Panda limit ±2.8973 rad) and whether it succeeded.
A wrist whose final angle jumps by several radians between neighbouring yaws makes joint-space demos
discontinuous in the placement.  Writes a small JSON (``--out``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def dumps(rec: dict) -> str:
    """JSON with one line per list item (an episode, a jump): small and diff-friendly."""
    lines = ["{"]
    for i, (k, v) in enumerate(rec.items()):
        end = "," if i < len(rec) - 1 else ""
        if isinstance(v, list) and v and isinstance(v[0], dict):
            items = ",\n".join("  " + json.dumps(x) for x in v)
            lines.append(f" {json.dumps(k)}: [\n{items}\n ]{end}")
        else:
            lines.append(f" {json.dumps(k)}: {json.dumps(v)}{end}")
    return "\n".join(lines + ["}"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--objects", default="", help="comma-separated object ids (default: the Train split's B-labelled objects)")
    ap.add_argument("--yaws", default="-30,-20,-10,0,10,15,20,25,30", help="yaw grid, degrees")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--right-finger-flip", action="store_true",
                    help="the expert's option b_right_half_turn (ExpertOptions): B's right hand posed a half turn about "
                         "its approach axis (finger axis -f; the parallel gripper cannot tell the two apart)")  # fmt: skip
    a = ap.parse_args()

    from flatlab_lerobot.atomic import write_text
    from flatlab_lerobot.catalog import load_objects
    from flatlab_lerobot.env import FlatLabEnv
    from flatlab_lerobot.paper.pipeline import git_commit, machine_line
    from flatlab_lerobot.rollout import ExpertPolicy, rollout
    from flatlab_lerobot.strategies.expert import ExpertOptions

    options = ExpertOptions(b_right_half_turn=a.right_finger_flip)

    cat = load_objects()
    objects = [o for o in a.objects.split(",") if o] or sorted(o for o, s in cat.items() if s.split == "train" and s.strategy == "B")
    for o in objects:
        if o not in cat:
            raise SystemExit(f"--objects: unknown object id {o!r}")
    yaws = [float(y) for y in a.yaws.split(",")]
    t0 = time.perf_counter()
    rows = []
    for o in objects:
        env = FlatLabEnv(object_id=o, obs_pixels=False, obs_pointcloud=False)
        try:
            for yaw in yaws:
                strategy = cat[o].strategy
                ep = rollout(env, ExpertPolicy(strategy, env.cell, env.control_dt, options=options), seed=0,
                             options={"placement": (0.0, 0.0, np.deg2rad(yaw))}, before_step=lambda st: np.asarray(st.action))
                acts = np.stack(ep.frames)
                rows.append({"object_id": o, "strategy": strategy, "yaw_deg": yaw, "success": ep.success, "steps": ep.steps,
                             "final_wrist_rad": {"left": round(float(acts[-1, 6]), 3), "right": round(float(acts[-1, 14]), 3)}})
                print(rows[-1], flush=True)
        finally:
            env.close()
    jumps = []
    for o in objects:
        r = [x for x in rows if x["object_id"] == o]
        for arm in ("left", "right"):
            w = [x["final_wrist_rad"][arm] for x in r]
            big = [(r[i]["yaw_deg"], r[i + 1]["yaw_deg"]) for i in range(len(w) - 1) if abs(w[i + 1] - w[i]) > 2.0]
            if big:
                jumps.append({"object_id": o, "arm": arm, "between_yaws_deg": big})
    rec = {"what": __doc__.strip().splitlines()[0], "objects": objects, "yaws_deg": yaws, "episodes": rows,
           "jumps_over_2_rad": jumps, "objects_with_a_jump": sorted({j["object_id"] for j in jumps}),
           "right_finger_flip": a.right_finger_flip,
           "command": f"python scripts/expert_wrist_branches.py --yaws {a.yaws}" + (f" --objects {a.objects}" if a.objects else "")
           + (" --right-finger-flip" if a.right_finger_flip else "") + f" --out {a.out}",
           "wall_s": round(time.perf_counter() - t0, 1), "git_commit": (git_commit()["commit"] or "")[:7],
           "machine": machine_line()}  # fmt: skip
    write_text(a.out, dumps(rec) + "\n")
    print(f"wrote {a.out}: {len(rec['objects_with_a_jump'])} of {len(objects)} objects with a wrist jump > 2 rad: {jumps}")


if __name__ == "__main__":
    main()

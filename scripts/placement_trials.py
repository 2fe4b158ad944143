"""``flatlab eval``'s trials of one object at placements you choose (a diagnosis: where does a policy fail?).

    python scripts/placement_trials.py --policy outputs/paper/cpu/unified_cpu_top_a --object cutboard_marble \
        --placements "0,0.1,0;-0.05,-0.15,-15" -- --env.pointcloud_cameras=[front,top,left,right] ... --policy.strategy=B

Trial k runs as ``flatlab eval``'s trial k (its Evaluator, episode seed ``--seed`` + k) with the env reset at the
k-th placement (x, y in m in the table frame, yaw in degrees; ``FlatLabEnv.reset(options={"placement": ...})``)
instead of the benchmark's drawn one.  Prints one line per trial: placement, G, steps.  Extra arguments after
``--`` go to the evaluator, as with ``flatlab eval``.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.evaluation.protocol import evaluator_for


def parse_placements(text: str) -> list[tuple[float, float, float]]:
    out = []
    for part in text.split(";"):
        vals = [float(v) for v in part.split(",")]
        if len(vals) != 3:
            raise ValueError(f"{part!r}: want x,y,yaw_deg")
        out.append((vals[0], vals[1], vals[2]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True, help="pretrained_model folder or a built-in policy name")
    ap.add_argument("--object", required=True, help="catalog object id")
    ap.add_argument("--placements", required=True, help="'x,y,yaw_deg;x,y,yaw_deg;...' (m, m, degrees)")
    ap.add_argument("--seed", type=int, default=1000)
    args, extra = ap.parse_known_args(argv)
    try:
        placements = parse_placements(args.placements)
    except ValueError as e:
        ap.error(f"--placements: {e}")
    current: dict = {}
    reset = FlatLabEnv.reset

    def placed(env, *, seed=None, options=None):
        options = dict(options or {})
        x, y, yaw = current["placement"]
        options["placement"] = (x, y, np.deg2rad(yaw))
        return reset(env, seed=seed, options=options)

    ev = evaluator_for(args.policy, args.seed, [a for a in extra if a != "--"])
    FlatLabEnv.reset = placed
    try:
        for k, p in enumerate(placements):
            current["placement"] = p
            rec = next(ev.run_object(args.object, [k]))
            print(json.dumps({"placement": p, "G": rec["G"], "steps": rec["steps"], "strategy": rec["strategy"]}),
                  flush=True)  # fmt: skip
    finally:
        FlatLabEnv.reset = reset
    return 0


if __name__ == "__main__":
    sys.exit(main())

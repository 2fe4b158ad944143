"""The desk's two-hand carry on single objects: the scripted B lifts one object, then the carry off.

    python scripts/carry_bench.py --split train --poses 6 --squeeze off --out outputs/carry/train_off.json
    python scripts/carry_bench.py --split train --poses 6 --mass 2.2 --thickness 0.015 --squeeze 0.01 --out ...

Every B-labelled object the desk draws from ``--split`` (``tasks.clear_desk.eligible_objects``), at ``--poses``
seeded planar poses from the desk's B region (x in +-0.1 m, |y| <= 0.2 m, yaw in +-20 deg), alone in the desk
cell.  The lift is the expert's and does not depend on ``--squeeze``, so runs that differ only in it carry the
same held objects: what changes is the carry (``run_desk_episode(carry_squeeze=...)``).  ``--mass-scale`` /
``--mass`` / ``--thickness`` transform the objects (a stress set of Train objects: thin and heavy like a marble
board).  Prints and writes per object: lifted, and carried off the table once lifted.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default="train", choices=("train", "test_alpha", "test_beta"))
    ap.add_argument("--poses", type=int, default=6, help="seeded poses per object")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--mass-scale", default="1", help="comma list: each object at mass x each factor")
    ap.add_argument("--mass", type=float, default=None, help="kg: every object at this mass (instead of --mass-scale)")
    ap.add_argument("--thickness", type=float, default=None, help="m: every object this thick")
    ap.add_argument("--squeeze", default="off", help="the carry's re-based squeeze in m, or off (run_desk_episode)")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    from flatlab_lerobot.paper.desk import parse_carry_squeeze
    from flatlab_lerobot.paper.pipeline import git_commit, machine_line
    from flatlab_lerobot.tasks.clear_desk import DeskConfig, DeskItem, DeskLayout, eligible_objects, run_desk_episode

    try:
        squeeze = parse_carry_squeeze(a.squeeze)
        scales = [float(v) for v in a.mass_scale.split(",")]
    except (argparse.ArgumentTypeError, ValueError) as e:
        ap.error(f"--squeeze / --mass-scale: {e}")
    cfg = replace(DeskConfig(), split=a.split)
    base = [o for objs in eligible_objects(cfg).values() for o in objs if o.strategy == "B"]
    objects = []
    for f in [1.0] if a.mass is not None else scales:
        for o in base:
            size = (*o.size[:2], a.thickness) if a.thickness else o.size
            objects.append(replace(o, mass=a.mass if a.mass is not None else o.mass * f, size=size))
    rng = np.random.default_rng(a.seed)
    t0, rows = time.perf_counter(), []
    for o in objects:
        for k in range(a.poses):
            x, y, yaw = rng.uniform(-0.1, 0.1), rng.uniform(-0.2, 0.2), np.deg2rad(rng.uniform(-20, 20))
            ep = run_desk_episode(layout=DeskLayout(0, (DeskItem(o, x, y, yaw),)), carry_squeeze=squeeze)
            r = ep.per_object[0]
            rows.append({"object_id": o.id, "mass": round(o.mass, 4), "size": list(o.size), "pose": [x, y, yaw],
                         "lifted": bool(r["lifted"]), "carried_off": bool(r["lifted"] and r["cleared"])})  # fmt: skip
    lifted = [r for r in rows if r["lifted"]]
    per = {}
    for r in lifted:
        per.setdefault(r["object_id"], [0, 0])
        per[r["object_id"]][0] += r["carried_off"]
        per[r["object_id"]][1] += 1
    res = {
        "what": "single B objects: the expert's lift, then the desk's carry off the table",
        "command": "python scripts/carry_bench.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "split": a.split, "poses": a.poses, "seed": a.seed, "carry_squeeze": squeeze,
        "lifted": len(lifted), "trials": len(rows), "carried_off": sum(r["carried_off"] for r in lifted),
        "carried_off_per_object": per, "wall_s": round(time.perf_counter() - t0, 1), "machine": machine_line(),
        "commit": git_commit(), "trials_detail": rows,
    }  # fmt: skip
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"carry off the table: {res['carried_off']} / {res['lifted']} lifted ({len(rows)} trials); {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

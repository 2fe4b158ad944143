"""What became of every object of ``clear_desk`` desks run by a policy: when it left the table, and whether the
benchmark's hold rule had been met for it by then.

    python scripts/desk_objects.py --policy outputs/paper/cpu/unified_cpu_top_a --desks 22,28 \
        --out outputs/desk_objects.jsonl -- --env.pointcloud_cameras=[front,top,left,right] ... --env.task=clear_desk

Runs each desk exactly as ``flatlab eval --seed 0`` runs trial ``d`` (the desk of layout seed ``d``; its Evaluator:
lerobot's ``eval_policy``) and writes one JSON line per desk: the objects, which were cleared, the attempts' strategies,
per object the step it left the table, whether it had been lifted (the hold rule met) then, the longest hold timer it
reached and the policy's stage then, and the policy's carry / go-home decisions (``flatlab_unified``).  An object off
the table but never lifted is lost for good: the desk can no longer be cleared.  With ``--hold-trace`` the line also
holds every step at which a hand touches an object: the hold rule's view of it (clearance above the table, table
contact, the touching arms, slip in the hands, the hold timer) and the policy's stage, so one sees why a timer
restarted.  The script reads the simulator's state for the person looking; the policy never sees it.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.evaluation.protocol import evaluator_for

DESK_OBJECT = "book_a5_notebook"  # the object id the evaluator is handed: a desk ignores it (its seed picks the objects)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True, help="pretrained_model folder or a built-in policy name (oracle, ...)")
    ap.add_argument("--desks", required=True, help="comma-separated desk layout seeds (flatlab eval --seed 0 trials)")
    ap.add_argument("--out", required=True, help="JSON lines file to append one line per desk to")
    ap.add_argument("--hold-trace", action="store_true",
                    help="also write, per step, the hold rule's status of every object a hand touches")
    args, extra = ap.parse_known_args(argv)
    try:
        desks = [int(d) for d in args.desks.split(",")]
    except ValueError:
        ap.error(f"--desks: comma-separated integers, got {args.desks!r}")
    extra = [a for a in extra if a != "--"]
    if "--env.task=clear_desk" not in extra:
        ap.error("pass the desk's flags after --, with --env.task=clear_desk (e.g. the desk row's)")
    ev = evaluator_for(args.policy, 0, extra)
    seen: dict = {}
    step = FlatLabEnv.step

    def traced(env, action):
        out = step(env, action)
        sim = env.sim
        if seen.get("sim") is not sim:
            seen.clear()
            seen.update(sim=sim, max_held=np.zeros(len(sim.objects)), off={})
        seen["max_held"] = np.maximum(seen["max_held"], sim._time_held)
        stage = str((getattr(ev.policy, "stages", None) or [""])[0])  # the policy's stage at this step
        if args.hold_trace:
            for i in range(len(sim.objects)):
                if sim.holding_arms(i):
                    st = sim.grasp_status(i)
                    seen.setdefault("trace", []).append(
                        {"step": env.steps, "object": sim.objects[i].obj.id, "clearance": round(st.clearance, 4),
                         "table_contact": st.table_contact, "arms": list(st.holding_arms), "slip": round(st.slip, 4),
                         "held_s": round(st.held_for, 2), "stage": stage})  # fmt: skip
        for i in range(len(sim.objects)):
            if i not in seen["off"] and sim.off_table(i):
                seen["off"][i] = {"step": env.steps, "lifted": bool(sim.lifted[i]),
                                  "longest_hold_s": round(float(seen["max_held"][i]), 2), "stage": stage}
        return out

    FlatLabEnv.step = traced
    try:
        with open(args.out, "a") as f:
            for rec in ev.run_object(DESK_OBJECT, desks):
                ids = [o.obj.id for o in seen["sim"].objects]
                decisions = ev.policy.decisions[0] if hasattr(ev.policy, "decisions") and ev.policy.decisions else []
                row = {"desk": rec["trial"], "objects": ids, "cleared": rec["desk"]["cleared"],
                       "attempts": "".join(rec["desk"].get("attempts", [])),  # flatlab_unified logs them
                       "off_table": {ids[i]: v for i, v in sorted(seen["off"].items())},
                       "longest_hold_s": dict(zip(ids, np.round(seen["max_held"], 2).tolist())),
                       "after": [{k: d[k] for k in ("after", "arms", "hold_still") if k in d}
                                 for d in decisions if "after" in d or "hold_still" in d]}
                if args.hold_trace:
                    row["hold_trace"] = seen.get("trace", [])
                lost = [o for o, v in row["off_table"].items() if not v["lifted"]]
                print(f"desk {row['desk']}: cleared {sum(row['cleared'])}/5, attempts {row['attempts']}, "
                      f"off the table uncounted: {lost or 'none'}", flush=True)
                f.write(json.dumps(row) + "\n")
                f.flush()
    finally:
        FlatLabEnv.step = step
    return 0


if __name__ == "__main__":
    sys.exit(main())

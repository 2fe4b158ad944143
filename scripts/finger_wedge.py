"""Count the control steps where an object is wedged *inside* a finger: touching a finger's box and the
same finger's pad on the faces that look into the gap between the two (the finger model until stop 70).

    python scripts/finger_wedge.py --policy oracle --objects disk_compact_disc book_a5_notebook --trials 5

Runs ``flatlab eval``'s trials exactly (its Evaluator, seed ``--seed`` + trial) and prints one JSON line
per trial: G, failure reason, the steps with a wedged object, and whether the object was wedged on the
step the hold rule was first met (a lift the finger's gap, not a grasp, held).  Reads the simulator's
contacts for the person measuring; the policy never sees them.  Extra arguments after ``--`` go to the
evaluator as in ``flatlab eval``.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from flatlab_lerobot.catalog import benchmark_objects
from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.evaluation.protocol import evaluator_for


def finger_parts(sim) -> dict[int, tuple[set[int], set[int]]]:
    """Per finger body id: (its box geoms, its pad geoms), from the sim's finger geoms (``finger_geoms``)."""
    m = sim.model
    parts: dict[int, tuple[set[int], set[int]]] = {}
    for g in np.concatenate(list(sim.finger_geoms.values())):
        box, pad = parts.setdefault(int(m.geom_bodyid[g]), (set(), set()))
        (pad if (m.geom(g).name or "").endswith("pad") else box).add(int(g))
    return parts


def wedged(sim, parts) -> bool:
    """Is any object (rigid body or cloth flex) caught between a finger's box and its pad: touching the
    pad's back face and the box's inner face, both contact normals (finger -> object) pointing into the
    slot between them?  A cloth pinched between the pads and wrapped round a finger's outside is not."""
    m, d = sim.model, sim.data
    geom, flex = sim._contact_pairs()
    # per contact side: is it one of the cell's objects (a rigid body's geom or a cloth's flex: FlatLabSim.is_object)?
    is_obj = np.zeros(geom.shape, bool)
    for i in range(len(sim.objects)):
        is_obj |= sim.is_object(geom, flex, i)
    normals: dict[tuple[int, str], list[np.ndarray]] = {}
    for k in range(len(geom)):
        normal = np.array(d.contact[k].frame[:3])  # from side 0 to side 1
        for fg, other, sign in ((geom[k, 0], 1, 1.0), (geom[k, 1], 0, -1.0)):
            if not is_obj[k, other] or fg < 0:
                continue
            b = int(m.geom_bodyid[fg])
            if b not in parts:
                continue
            kind = "pad" if fg in parts[b][1] else "box"
            normals.setdefault((b, kind), []).append(sign * normal)
    for b, (box, _) in parts.items():
        if (b, "pad") not in normals or (b, "box") not in normals:
            continue
        # the finger's closing axis, pointing from the pad to the box (outwards): the slot between them
        out = d.xmat[b].reshape(3, 3)[:, 1] * np.sign(m.geom_pos[next(iter(box))][1])
        pad_out = any(float(n @ out) > 0.5 for n in normals[(b, "pad")])  # the pad's back face touches it
        box_in = any(float(n @ out) < -0.5 for n in normals[(b, "box")])  # the box's inner face touches it
        if pad_out and box_in:
            return True
    return False


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True)
    ap.add_argument("--objects", nargs="*", default=None, help="catalog ids (default: all benchmark objects)")
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1000)
    args, extra = ap.parse_known_args(argv)
    ev = evaluator_for(args.policy, args.seed, [a for a in extra if a != "--"])
    objects = args.objects or [o.id for o in benchmark_objects()]
    state: dict = {}
    step = FlatLabEnv.step

    def traced(env, action):
        out = step(env, action)
        s = env.sim
        if state.get("model") is not s.model:
            state.update(model=s.model, parts=finger_parts(s))
        w = wedged(s, state["parts"])
        state["wedged"] += int(w)
        if s.lifted.any() and state["at_lift"] is None:
            state["at_lift"] = w
        return out

    FlatLabEnv.step = traced
    try:
        for oid in objects:
            state.update(wedged=0, at_lift=None)
            for t, rec in enumerate(ev.run_object(oid, list(range(args.trials)))):
                print(json.dumps({"object_id": oid, "trial": t, "G": rec["G"], "failure_reason": rec["failure_reason"],
                                  "wedged_steps": state["wedged"], "wedged_at_lift": state["at_lift"]}), flush=True)
                state.update(wedged=0, at_lift=None)
    finally:
        FlatLabEnv.step = step
    return 0


if __name__ == "__main__":
    sys.exit(main())

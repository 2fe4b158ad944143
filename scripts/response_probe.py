"""How objects answer the unified policy's stages: per trial, the attempts, G and the ``retry_on_response``
readings (C's fold rise after the squeeze, its fold as the straddle and as the pinch begin, the droop below the table
top after each of A's push passes).

    python scripts/response_probe.py --policy outputs/paper/cpu/unified_cpu_top_a --objects board_plywood,fabric_cotton \
        --trials 3 --out outputs/probe/c_first.jsonl -- --policy.first_attempt=C --policy.retry_failed=true ...

Runs each trial exactly as ``flatlab eval`` does (its Evaluator, seed ``--seed`` + trial) and appends one JSON line
per trial to ``--out`` (a trial already there is skipped, so a re-run resumes).  The readings are what the policy
logged from the clouds it observed; nothing here reads the simulator's state.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from flatlab_lerobot.evaluation.protocol import evaluator_for

KEYS = ("fold_rise", "fold_kept", "droop", "retry_failed", "retry")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True, help="flatlab_unified pretrained_model folder")
    ap.add_argument("--objects", required=True, help="comma-separated catalog object ids")
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--out", required=True, type=Path, help="JSON lines file (appended; resumes)")
    args, extra = ap.parse_known_args(argv)
    ev = evaluator_for(args.policy, args.seed, [a for a in extra if a != "--"])
    done = set()
    if args.out.exists():
        done = {(r["object_id"], r["trial"]) for r in map(json.loads, args.out.read_text().splitlines())}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for obj in args.objects.split(","):
        todo = [t for t in range(args.trials) if (obj, t) not in done]
        for t in todo:
            rec = next(ev.run_object(obj, [t]))
            log = ev.policy.decisions[0]
            row = {k: rec.get(k) for k in ("object_id", "trial", "seed", "label", "strategy", "G", "failure_reason", "steps")}
            row["attempts"] = (getattr(ev.policy, "attempts", None) or [[]])[0]
            row["responses"] = [{k: v for k, v in e.items() if k in KEYS + ("index", "response_failed")}
                                for e in log if any(k in e for k in KEYS)]  # fmt: skip
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

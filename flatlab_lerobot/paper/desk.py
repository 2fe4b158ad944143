"""``flatlab desk``: the five-object desk (the ``clear_desk`` scenario) with the scripted expert.

Each seed draws one desk layout (five rigid Test-beta objects, :mod:`flatlab_lerobot.tasks.clear_desk`;
``--split train``: Train objects, a development desk on which a policy's desk switches are chosen)
and runs one physics episode in which every object is cleared in turn with its labelled strategy
(``--policy oracle``) or one fixed strategy (``slide_only``: A, ``lift_only``: B), each lifted object
carried past the usable edge (two hands first re-base their squeeze ``--carry-squeeze`` past where they
are measured, default ``CARRY_SQUEEZE``: 0.01 m; ``off`` is the carry of the desks measured up to stop 72).
Success: all five objects lifted (the 2-s hold rule) and none left on the table.  The paper reports 73.3 % for its
learned framework on its desk (App., baseline comparison).

Finished desks are appended to ``<out>.jsonl``; a rerun skips them (resumable).  The JSON holds the
per-desk results, the success rate, the mean number of objects cleared, seeds and wall time.

    flatlab desk --seeds 0-29 --out outputs/desk/oracle.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from flatlab_lerobot.catalog import BENCHMARK_SPLITS
from flatlab_lerobot.strategies.b_squeeze import B_SQUEEZE
from flatlab_lerobot.tasks.clear_desk import CARRY_SQUEEZE

POLICIES = {"oracle": "expert", "slide_only": "A", "lift_only": "B"}


def parse_seeds(text: str) -> list[int]:
    seeds: list[int] = []
    for part in text.split(","):
        a, _, b = part.strip().partition("-")
        seeds += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return seeds


def parse_carry_squeeze(text: str) -> float | None:
    """--carry-squeeze: 'off' or metres in [0, B_SQUEEZE] (B commands each hand B_SQUEEZE past the face it touched)."""
    if text == "off":
        return None
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: want metres (e.g. 0.01) or off") from None
    if not 0.0 <= v <= B_SQUEEZE:
        raise argparse.ArgumentTypeError(f"{v}: want 0 to {B_SQUEEZE} m (B's own squeeze) or off")
    return v


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="flatlab desk", description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", default="oracle", help=f"one of {', '.join(POLICIES)} (default oracle)")
    ap.add_argument("--seeds", default="0-29", help="layout seeds: '0-29', '3,5,8' (default 0-29)")
    ap.add_argument("--split", default="test_beta", choices=BENCHMARK_SPLITS,
                    help="catalog split of the desk's objects (default test_beta, the benchmark's desk; train: a "
                         "development desk)")
    ap.add_argument("--carry-squeeze", type=parse_carry_squeeze, default=CARRY_SQUEEZE,
                    help=f"m: a two-hand carry first re-bases its squeeze this far past where the hands are (default "
                         f"{CARRY_SQUEEZE}; off: the commanded squeeze as it is, the desks measured up to stop 72)")
    ap.add_argument("--out", type=Path, required=True, help="JSON to write (finished desks go to <out>.jsonl)")
    a = ap.parse_args(argv)
    if a.policy not in POLICIES:
        ap.error(f"--policy {a.policy}: the desk runs the scripted expert ({', '.join(POLICIES)}); a learned policy "
                 "runs it through `flatlab eval --env.task=clear_desk --env.episode_length=1450`")  # fmt: skip
    try:
        seeds = parse_seeds(a.seeds)
    except ValueError:
        ap.error(f"--seeds {a.seeds!r}: want e.g. 0-29 or 3,5,8")
    from flatlab_lerobot.tasks import run_scenario

    a.out.parent.mkdir(parents=True, exist_ok=True)
    partial = a.out.with_name(a.out.name + ".jsonl")
    done: dict[int, dict] = {}
    if partial.is_file():
        for line in partial.read_text().splitlines():
            try:
                r = json.loads(line)
            except json.JSONDecodeError:
                continue  # a half-written last line
            same = (r.get("policy"), r.get("split", "test_beta"), r.get("carry_squeeze"))
            if same == (a.policy, a.split, a.carry_squeeze):
                done[r["seed"]] = r
    t0 = time.perf_counter()
    with open(partial, "a") as f:
        for s in seeds:
            if s in done:
                continue
            r = run_scenario("clear_desk", s, POLICIES[a.policy], a.split, a.carry_squeeze)
            r = {"policy": a.policy, **{k: v for k, v in r.items() if k != "objects"},
                 "objects": [{k: v for k, v in o.items() if isinstance(v, (str, int, float, bool, type(None)))}
                             for o in r["objects"]]}  # fmt: skip
            f.write(json.dumps(r) + "\n")
            f.flush()
            os.fsync(f.fileno())
            done[s] = r
            print(f"desk seed {s}: {'cleared' if r['success'] else 'not cleared'} ({r['cleared']}/{r['n_objects']})", flush=True)
    per = [done[s] for s in seeds]
    n_ok = sum(bool(r["success"]) for r in per)
    res = {
        "what": f"clear_desk (five rigid {a.split} objects, one cell) with the scripted expert",
        "command": "flatlab desk " + " ".join(sys.argv[1:] if argv is None else argv),
        "policy": a.policy, "split": a.split, "carry_squeeze": a.carry_squeeze, "seeds": seeds, "success": n_ok,
        "trials": len(per),
        "rate": n_ok / len(per) if per else None,
        "cleared_mean": sum(r["cleared"] for r in per) / len(per) if per else None,
        "wall_s_this_run": round(time.perf_counter() - t0, 1),
        "per_desk": per,
    }  # fmt: skip
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"{n_ok}/{len(per)} desks cleared; {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

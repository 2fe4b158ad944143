"""Diagnosis only, never selection: score every saved checkpoint of `flatlab_strategy` runs on a strategy eval set.

    python scripts/strategy_checkpoints.py --set EVAL_SET --out OUT.json RUN_DIR:RESULT_JSON [...]

RUN_DIR is a lerobot-train output folder, RESULT_JSON its `flatlab strategy-eval` result (which holds the held-out
Train validation score of every checkpoint and the checkpoint chosen on it).  Shows how much the Test splits move
between checkpoints that the validation cannot tell apart; the reported row of a run stays its chosen checkpoint.
"""

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from flatlab_lerobot.learning.checkpoint_average import saved_checkpoints
from flatlab_lerobot.learning.strategy_eval import LETTERS, load_policy, metrics, predict, set_inputs
from flatlab_lerobot.learning.strategy_set import load


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", type=Path, required=True, help="strategy eval set (flatlab strategy-set)")
    ap.add_argument("--out", type=Path, required=True, help="JSON to write")
    ap.add_argument("runs", nargs="+", help="RUN_DIR:RESULT_JSON")
    args = ap.parse_args(argv)
    pairs = []
    for arg in args.runs:
        run, sep, result = arg.partition(":")
        if not sep or not (Path(run) / "checkpoints").is_dir() or not Path(result).is_file():
            ap.error(f"run {arg!r}: need RUN_DIR:RESULT_JSON, RUN_DIR holding checkpoints/ and RESULT_JSON a file")
        pairs.append((Path(run), Path(result)))
    index = load(args.set)[1]
    t0 = time.perf_counter()
    res = {"what": "diagnosis, not selection: every saved checkpoint of each run scored on the eval set; the "
           "reported row of each run stays the checkpoint chosen on held-out Train views (val_acc)",
           "eval_set": str(args.set), "command": "python scripts/strategy_checkpoints.py " + " ".join(sys.argv[1:]),
           "runs": {}}  # fmt: skip
    for run, result in pairs:
        sel = json.loads(result.read_text())["selection"]
        rows, x = {}, None
        for pm in saved_checkpoints(run):
            ck, pol = pm.parent, load_policy(pm)
            x = set_inputs(pol, args.set) if x is None else x
            ps = metrics(index, [LETTERS[i] for i in predict(pol, x).argmax(1)])["per_split"]
            rows[ck.name] = {"val_acc": sel["scores"][ck.name]["val_acc"], **{s: ps[s]["acc_catalog"] for s in ps},
                             "test_beta_cloth_views_called_ABC": ps["test_beta"]["confusion_catalog"][2]}  # fmt: skip
            print(run.name, ck.name, rows[ck.name], flush=True)
        res["runs"][str(run)] = {"result": str(result), "selected": sel["selected"], "checkpoints": rows}
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    res.update(wall_s=round(time.perf_counter() - t0, 1), machine=f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores",
               git_commit=commit, python=platform.python_version())  # fmt: skip
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Turn a `flatlab eval` results.json into a committed results record (docs/results/eval_<id>.json):
the metrics as they are, plus what ran, the command, seeds, wall time, training budget, machine, commit."""

import argparse
import json
from pathlib import Path

from flatlab_lerobot.atomic import write_json
from flatlab_lerobot.paper.pipeline import git_commit, machine_line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--results", type=Path, required=True, help="flatlab eval's results.json")
    ap.add_argument("--out", type=Path, required=True, help="record to write (docs/results/eval_<id>.json)")
    ap.add_argument("--what", required=True)
    ap.add_argument("--command", required=True)
    ap.add_argument("--wall", type=float, required=True, help="evaluation wall time, s")
    ap.add_argument("--train", type=Path, help="train_wall.json of the checkpoint's training (folded in as 'training')")
    ap.add_argument("--note", default="")
    a = ap.parse_args()
    try:
        rec = json.loads(a.results.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SystemExit(f"--results {a.results}: cannot read flatlab eval results ({e})")
    rec.update(what=a.what, command=a.command, wall_s=round(a.wall), git_commit=(git_commit()["commit"] or "")[:7],
               machine=machine_line())  # the same facts flatlab paper's stage records carry  # fmt: skip
    if a.note:
        rec["wall_note"] = a.note
    if a.train:
        try:
            rec["training"] = json.loads(a.train.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise SystemExit(f"--train {a.train}: cannot read ({e})")
    write_json(a.out, rec)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

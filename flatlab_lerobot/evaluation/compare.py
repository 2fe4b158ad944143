"""Two ``flatlab eval`` runs, trial by trial (``flatlab eval-compare RUN_A RUN_B``).

The simulation is deterministic and trial ``t`` of object ``o`` has the same placement in every run
with the same ``--seed``, so two policies evaluated with the same seed and env flags can be compared
pair by pair instead of by their two rates: per split, the trials both lift, only A lifts, only B
lifts, neither; and the exact two-sided sign test on the discordant pairs (McNemar's exact test),
which says whether "B lifts n more" is more than the placement-by-placement luck of two policies
that are equally good.  Also: how often the two chose the same strategy, label -> chosen
strategy (lifted / trials) for each, and the objects whose outcomes differ most.

    flatlab eval-compare outputs/eval/last outputs/eval/avg5 [--json outputs/eval/last_vs_avg5.json]

Each RUN is a ``flatlab eval --out`` folder (``results.jsonl`` + ``run.json``).  Runs with another
``--seed`` or other env flags are refused (the pairs would not share placements) unless
``--allow-different-settings``; trials present in only one run are counted and left out.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import Counter
from pathlib import Path

from flatlab_lerobot.atomic import write_text
from flatlab_lerobot.evaluation.protocol import RESULTS_JSONL, RUN_JSON


class CompareError(SystemExit):
    """A bad input, with the file or flag it concerns (``SystemExit``: the CLI prints it)."""


def sign_test_p(only_a: int, only_b: int) -> float:
    """Exact two-sided sign test (McNemar's exact test) on the discordant pairs: the probability,
    if either outcome of a discordant pair were equally likely, of a split at least this uneven."""
    n = only_a + only_b
    if n == 0:
        return 1.0
    k = min(only_a, only_b)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2**n
    return min(1.0, 2 * tail)


def load_run(path: Path, name: str) -> tuple[dict, dict[tuple[str, int], dict]]:
    """``run.json`` (what the trials mean) and the trials of ``results.jsonl`` by (object, trial)."""
    folder = path.parent if path.name == RESULTS_JSONL else path
    jsonl, run_json = folder / RESULTS_JSONL, folder / RUN_JSON
    if not jsonl.is_file():
        raise CompareError(f"{name} {path}: no {RESULTS_JSONL} (expected a `flatlab eval --out` folder)")
    run = {}
    if run_json.is_file():
        try:
            run = json.loads(run_json.read_text())
        except json.JSONDecodeError as e:
            raise CompareError(f"{name} {run_json}: not valid JSON ({e})") from None
    trials: dict[tuple[str, int], dict] = {}
    lines = jsonl.read_text().splitlines()
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            trials[(rec["object_id"], int(rec["trial"]))] = rec
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
            if i == len(lines):  # a half-written last line: the run was interrupted (flatlab eval drops it too)
                continue
            raise CompareError(f"{name} {jsonl}: line {i} is not a trial record ({e})") from None
    if not trials:
        raise CompareError(f"{name} {jsonl}: no trials")
    return run, trials


def settings_differ(run_a: dict, run_b: dict) -> dict:
    """The run.json fields that make two runs' trials incomparable: the seed and the env flags
    (fields only one run's env records, added to the env since, are not counted)."""
    diff = {}
    if run_a.get("seed") != run_b.get("seed"):
        diff["seed"] = [run_a.get("seed"), run_b.get("seed")]
    env_a, env_b = run_a.get("env", {}), run_b.get("env", {})
    for k in sorted(set(env_a) & set(env_b)):
        if env_a[k] != env_b[k]:
            diff[f"env.{k}"] = [env_a[k], env_b[k]]
    return diff


def _label_to_chosen(recs) -> dict[str, str]:
    n, lifted = Counter(), Counter()
    for r in recs:
        key = f"{r.get('label', '?')}->{r.get('strategy') or '-'}"
        n[key] += 1
        lifted[key] += int(bool(r["G"]))
    return {k: f"{lifted[k]}/{n[k]}" for k in sorted(n)}


def _pairs(keys, a, b) -> dict:
    both = sum(1 for k in keys if a[k]["G"] and b[k]["G"])
    only_a = sum(1 for k in keys if a[k]["G"] and not b[k]["G"])
    only_b = sum(1 for k in keys if b[k]["G"] and not a[k]["G"])
    return {
        "trials": len(keys),
        "G_a": sum(1 for k in keys if a[k]["G"]),
        "G_b": sum(1 for k in keys if b[k]["G"]),
        "both": both,
        "only_a": only_a,
        "only_b": only_b,
        "neither": len(keys) - both - only_a - only_b,
        "sign_test_p": round(sign_test_p(only_a, only_b), 4),
    }


def compare(a: dict, b: dict) -> dict:
    """The paired comparison of two runs' trials (dicts by (object, trial))."""
    keys = sorted(set(a) & set(b))
    if not keys:
        raise CompareError("the two runs share no (object, trial): nothing to compare")
    splits = list(dict.fromkeys(a[k].get("split", "?") for k in keys))
    per_object = Counter()
    for k in keys:
        per_object[k[0]] += int(bool(b[k]["G"])) - int(bool(a[k]["G"]))
    return {
        "paired": _pairs(keys, a, b),
        "per_split": {s: _pairs([k for k in keys if a[k].get("split", "?") == s], a, b) for s in splits},
        "same_strategy": sum(1 for k in keys if a[k].get("strategy") == b[k].get("strategy")),
        "same_outcome": sum(1 for k in keys if bool(a[k]["G"]) == bool(b[k]["G"])),
        "only_in_a": len(set(a) - set(b)),
        "only_in_b": len(set(b) - set(a)),
        "label_to_chosen_lifted": {"a": _label_to_chosen(a[k] for k in keys), "b": _label_to_chosen(b[k] for k in keys)},
        "objects_b_minus_a": {o: d for o, d in sorted(per_object.items(), key=lambda x: (-abs(x[1]), x[0])) if d},
    }


def markdown(res: dict, name_a: str, name_b: str) -> str:
    lines = [f"A = {name_a}", f"B = {name_b}", "",
             "| split | trials | G A | G B | both | only A | only B | neither | sign test p |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    rows = list(res["per_split"].items()) + [("all", res["paired"])]
    for split, p in rows:
        n = p["trials"]
        lines.append(f"| {split} | {n} | {p['G_a']} ({100 * p['G_a'] / n:.1f} %) | {p['G_b']} ({100 * p['G_b'] / n:.1f} %) | "
                     f"{p['both']} | {p['only_a']} | {p['only_b']} | {p['neither']} | {p['sign_test_p']:.3f} |")  # fmt: skip
    n = res["paired"]["trials"]
    lines += ["", f"same strategy chosen: {res['same_strategy']} / {n}; same outcome: {res['same_outcome']} / {n}"]
    if res["only_in_a"] or res["only_in_b"]:
        lines.append(f"left out (in one run only): {res['only_in_a']} trials of A, {res['only_in_b']} of B")
    la, lb = res["label_to_chosen_lifted"]["a"], res["label_to_chosen_lifted"]["b"]
    lines += ["", "| label -> chosen | A lifted | B lifted |", "|---|---|---|"]
    lines += [f"| {k} | {la.get(k, '-')} | {lb.get(k, '-')} |" for k in sorted(set(la) | set(lb))]
    diffs = res["objects_b_minus_a"]
    if diffs:
        lines += ["", "objects whose lifted trials differ (B - A): " + ", ".join(f"{o} {d:+d}" for o, d in diffs.items())]
    return "\n".join(lines) + "\n"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="flatlab eval-compare", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("run_a", type=Path, help="a `flatlab eval --out` folder (A)")
    ap.add_argument("run_b", type=Path, help="a `flatlab eval --out` folder (B)")
    ap.add_argument("--json", type=Path, help="also write the comparison as JSON here")
    ap.add_argument("--allow-different-settings", action="store_true",
                    help="compare runs with another --seed or other env flags (their trials do not share placements)")  # fmt: skip
    return ap


def main(argv=None) -> int:
    a = build_parser().parse_args(argv)
    run_a, trials_a = load_run(a.run_a, "RUN_A")
    run_b, trials_b = load_run(a.run_b, "RUN_B")
    diff = settings_differ(run_a, run_b)
    if diff and not a.allow_different_settings:
        raise CompareError(f"{a.run_a / RUN_JSON} and {a.run_b / RUN_JSON} differ in {', '.join(diff)} ({diff}): "
                           "their trials are not the same placements (--allow-different-settings to compare anyway)")  # fmt: skip
    res = compare(trials_a, trials_b)
    res.update(run_a=str(a.run_a), run_b=str(a.run_b), policy_a=run_a.get("policy"), policy_b=run_b.get("policy"),
               settings_differ=diff)  # fmt: skip
    print(markdown(res, f"{a.run_a} ({run_a.get('policy', '?')})", f"{a.run_b} ({run_b.get('policy', '?')})"), end="")
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        write_text(a.json, json.dumps(res, indent=1) + "\n")
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The evaluation protocol (``flatlab eval``-style): strategy choice S and grasp success G.

A *policy* here picks a strategy per object and the scripted expert executes it:

* ``oracle``: the object's label strategy (the upper bound of strategy choice),
* ``slide_only``: always A (slide to the edge, grasp the overhang),
* ``lift_only``: always B (two-arm squeeze and lift).

For every object of the chosen splits and every trial ``t`` (seed = ``--seed`` + t, the
benchmark's placement distribution), S = the chosen strategy equals the label and G = the
grasp succeeded (:func:`flatlab_lerobot.demo.run_expert_episode`, the core success rule).

Runs in ``--workers`` processes.  Every finished trial is appended to ``results.jsonl`` (one
JSON line, written by the parent only, flushed and fsynced) and a restart skips the
``(object, trial)`` keys already there, so an interrupted run resumes without repeating or
losing trials (a half-written last line is dropped).  When every trial is done it writes
``results.json``, ``results.md`` (per object S and G as successes/trials, per-split averages)
and ``results.png``.

    python -m flatlab_lerobot.bench.protocol --policy oracle --splits train --trials 5 --out outputs/eval/oracle
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import time
from pathlib import Path

from flatlab_lerobot.catalog import BENCHMARK_SPLITS, benchmark_objects, get_object

POLICIES = {
    "oracle": lambda spec: spec.strategy,
    "slide_only": lambda spec: "A",
    "lift_only": lambda spec: "B",
}
RESULTS_JSONL = "results.jsonl"


def choose_strategy(policy: str, object_id: str) -> str:
    return POLICIES[policy](get_object(object_id))


def run_trial(job: dict) -> dict:
    """One (object, trial): choose a strategy, run the expert, judge S and G."""
    from flatlab_lerobot.demo import run_expert_episode

    spec = get_object(job["object_id"])
    strategy = choose_strategy(job["policy"], spec.id)
    t0 = time.perf_counter()
    rec = run_expert_episode(spec.id, strategy, job["seed"], max_time=job["max_time"])
    rec.pop("_sim", None)
    return {
        "policy": job["policy"],
        "object_id": spec.id,
        "trial": job["trial"],
        "seed": job["seed"],
        "split": spec.split,
        "category": spec.category,
        "label": spec.strategy,
        "strategy": strategy,
        "S": strategy == spec.strategy,
        "G": bool(rec["success"]),
        "sim_time_s": rec["sim_time_s"],
        "primitives": rec["primitives"],
        "failure_reason": rec["failure_reason"],
        "wall_s": round(time.perf_counter() - t0, 3),
        "pid": os.getpid(),
    }


def load_done(path: Path, policy: str) -> dict[tuple[str, int], dict]:
    """Finished trials in ``results.jsonl`` by (object_id, trial).  A half-written last line
    (an interrupted write) is cut off the file so later appends start on a clean line."""
    done: dict[tuple[str, int], dict] = {}
    if not path.exists():
        return done
    raw = path.read_bytes()
    good_end = raw.rfind(b"\n") + 1
    if good_end < len(raw):
        with open(path, "r+b") as f:
            f.truncate(good_end)
    for line in raw[:good_end].decode().splitlines():
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if rec.get("policy") != policy:
            raise SystemExit(f"{path} holds results of policy {rec.get('policy')!r}, not {policy!r}: use another --out")
        done[(rec["object_id"], int(rec["trial"]))] = rec
    return done


def select_objects(splits, objects) -> list[str]:
    if objects:
        return [get_object(o).id for o in objects]
    return [o.id for s in splits for o in sorted(benchmark_objects(s), key=lambda o: o.id)]


def _rate(recs, key) -> float:
    return sum(r[key] for r in recs) / len(recs) if recs else float("nan")


def summarize(records: list[dict], config: dict) -> dict:
    per_object: dict[str, dict] = {}
    for r in sorted(records, key=lambda r: (r["split"], r["object_id"], r["trial"])):
        o = per_object.setdefault(
            r["object_id"],
            {"object_id": r["object_id"], "split": r["split"], "category": r["category"], "label": r["label"],
             "trials": 0, "S": 0, "G": 0, "strategies": {}},
        )  # fmt: skip
        o["trials"] += 1
        o["S"] += int(r["S"])
        o["G"] += int(r["G"])
        o["strategies"][r["strategy"]] = o["strategies"].get(r["strategy"], 0) + 1
    per_split = {}
    for split in dict.fromkeys(o["split"] for o in per_object.values()):
        recs = [r for r in records if r["split"] == split]
        per_split[split] = {
            "objects": sum(1 for o in per_object.values() if o["split"] == split),
            "trials": len(recs),
            "S": _rate(recs, "S"),
            "G": _rate(recs, "G"),
        }
    return {
        "config": config,
        "per_object": list(per_object.values()),
        "per_split": per_split,
        "overall": {"trials": len(records), "S": _rate(records, "S"), "G": _rate(records, "G")},
    }


def markdown(summary: dict) -> str:
    c = summary["config"]
    lines = [
        f"# FlatLab evaluation: policy `{c['policy']}`",
        "",
        (
            f"{c['trials']} trials per object, seeds {c['seed']}..{c['seed'] + c['trials'] - 1}; "
            "S = strategy choice correct, G = grasp success (successes/trials)."
        ),
        "",
        "| split | category | object | label | S | G |",
        "|---|---|---|---|---|---|",
    ]
    for o in summary["per_object"]:
        n = o["trials"]
        lines.append(f"| {o['split']} | {o['category']} | {o['object_id']} | {o['label']} | {o['S']}/{n} | {o['G']}/{n} |")
    lines += ["", "| split | objects | trials | S (%) | G (%) |", "|---|---|---|---|---|"]
    for split, s in summary["per_split"].items():
        lines.append(f"| {split} | {s['objects']} | {s['trials']} | {100 * s['S']:.1f} | {100 * s['G']:.1f} |")
    ov = summary["overall"]
    lines.append(f"| **all** | {len(summary['per_object'])} | {ov['trials']} | {100 * ov['S']:.1f} | {100 * ov['G']:.1f} |")
    return "\n".join(lines) + "\n"


def plot(summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    splits = list(summary["per_split"])
    s = [100 * summary["per_split"][k]["S"] for k in splits]
    g = [100 * summary["per_split"][k]["G"] for k in splits]
    x = np.arange(len(splits))
    fig, ax = plt.subplots(figsize=(1.8 * len(splits) + 2, 3.2))
    ax.bar(x - 0.2, s, 0.4, label="S: strategy choice")
    ax.bar(x + 0.2, g, 0.4, label="G: grasp success")
    ax.set_xticks(x, splits)
    ax.set_ylim(0, 105)
    ax.set_ylabel("%")
    ax.set_title(f"policy {summary['config']['policy']}")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    tmp = path.with_name(".partial_" + path.name)
    fig.savefig(tmp, format="png", dpi=120)
    plt.close(fig)
    os.replace(tmp, path)


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(".partial_" + path.name)
    tmp.write_text(text)
    os.replace(tmp, path)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="flatlab eval", description="S/G evaluation of a strategy-choosing policy over objects x trials")
    ap.add_argument("--policy", choices=sorted(POLICIES), default="oracle")
    ap.add_argument("--splits", default=",".join(BENCHMARK_SPLITS), help="comma-separated splits (default: all three)")
    ap.add_argument("--objects", default="", help="comma-separated object ids (overrides --splits; ref_* allowed)")
    ap.add_argument("--trials", type=int, default=5, help="trials per object (default 5)")
    ap.add_argument("--seed", type=int, default=0, help="trial t uses placement seed SEED + t")
    ap.add_argument("--workers", type=int, default=2, help="worker processes (default 2; 1 = in-process)")
    ap.add_argument("--max-time", type=float, default=25.0, help="simulated seconds per episode")
    ap.add_argument("--max-trials", type=int, default=None, help="stop after this many newly finished trials (resume later)")
    ap.add_argument("--out", type=Path, default=None, help="output folder (default outputs/eval/<policy>)")
    ap.add_argument("--no-plot", action="store_true")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from flatlab_lerobot.paths import OUTPUTS_DIR

    out = args.out or OUTPUTS_DIR / "eval" / args.policy
    out.mkdir(parents=True, exist_ok=True)
    splits = [s.strip() for s in args.splits.split(",") if s.strip()]
    objects = select_objects(splits, [o.strip() for o in args.objects.split(",") if o.strip()])
    config = {"policy": args.policy, "objects": objects, "trials": args.trials, "seed": args.seed, "max_time": args.max_time}
    jsonl = out / RESULTS_JSONL
    done = load_done(jsonl, args.policy)
    jobs = [
        {"policy": args.policy, "object_id": o, "trial": t, "seed": args.seed + t, "max_time": args.max_time}
        for o in objects
        for t in range(args.trials)
        if (o, t) not in done
    ]
    total = len(objects) * args.trials
    budget = len(jobs) if args.max_trials is None else min(len(jobs), args.max_trials)
    from tqdm import tqdm

    bar = tqdm(total=total, initial=total - len(jobs), desc=f"eval {args.policy}", unit="trial", disable=args.quiet)
    finished = 0
    with open(jsonl, "a") as f:

        def record(rec):
            f.write(json.dumps(rec) + "\n")
            f.flush()
            os.fsync(f.fileno())
            done[(rec["object_id"], rec["trial"])] = rec
            bar.update(1)
            bar.set_postfix(G=f"{_rate(list(done.values()), 'G'):.2f}")

        if budget > 0 and args.workers <= 1:
            for job in jobs[:budget]:
                record(run_trial(job))
                finished += 1
        elif budget > 0:
            pool = mp.get_context("fork").Pool(args.workers, maxtasksperchild=20)
            try:
                for rec in pool.imap_unordered(run_trial, jobs, chunksize=1):
                    record(rec)
                    finished += 1
                    if finished >= budget:
                        break
            finally:
                pool.terminate()
                pool.join()
    bar.close()
    remaining = sum(1 for o in objects for t in range(args.trials) if (o, t) not in done)
    if remaining:
        print(f"{finished} trials finished this run, {remaining} left: run the same command again to resume ({jsonl})")
        return 0
    records = [done[(o, t)] for o in objects for t in range(args.trials)]
    summary = summarize(records, config)
    _atomic_text(out / "results.json", json.dumps(summary, indent=2))
    _atomic_text(out / "results.md", markdown(summary))
    if not args.no_plot:
        plot(summary, out / "results.png")
    ov = summary["overall"]
    print(f"policy {args.policy}: S {100 * ov['S']:.1f}%  G {100 * ov['G']:.1f}% over {ov['trials']} trials; {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

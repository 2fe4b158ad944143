"""The asset-library validation report (``flatlab assets report``).

Every benchmark object is tried with *every* strategy: the scripted expert runs strategy A, B and
C on it, ``--trials`` randomized placements each (the protocol's reset distribution and seeds),
through the same resumable ``flatlab eval`` runs as the benchmark (policies ``slide_only`` = A,
``lift_only`` = B, ``fold_only`` = C).  From those runs the report gives:

* the labelled strategy's success per object, per category (the bar: >= 90 % in every
  category) and per split;
* the *physically grounded* label of each object: the strategy that works best in simulation
  (ties keep the catalog label), and where it differs from the catalog's thin / thick /
  deformable rule;
* the wrong-strategy matrix (category x strategy success), checked against the paper's
  pattern: pushing (A) fails on boxes and fabrics, dual-arm lifting (B) fails on thin and
  deformable objects;
* how long the validation took and the slowest assets.

    flatlab assets report --trials 5 --out outputs/validation
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

from flatlab_lerobot.atomic import replacing, write_text
from flatlab_lerobot.catalog import BENCHMARK_SPLITS, benchmark_objects
from flatlab_lerobot.transforms import label as rule_label

STRATEGY_POLICY = {"A": "slide_only", "B": "lift_only", "C": "fold_only"}
"""The ``flatlab eval`` policy that forces each strategy."""
CATEGORY_BAR = 0.9  # the labelled strategy must succeed this often in every category
WORKS = 0.5  # a strategy "works" on an object when it succeeds in at least this share of trials
GROUNDED_MARGIN = 0.4  # another strategy must beat the current label by this much to relabel an object
BOX_CATEGORIES = ("Box",)
FABRIC_CATEGORIES = ("Fabric", "Towel", "Scarf")


def read_runs(run_dirs: dict[str, Path]) -> dict[str, dict[str, list[dict]]]:
    """``{strategy: {object_id: [trial records]}}`` from each run's ``results.jsonl``."""
    out: dict[str, dict[str, list[dict]]] = {}
    for strategy, d in run_dirs.items():
        path = Path(d) / "results.jsonl"
        per: dict[str, list[dict]] = defaultdict(list)
        if path.exists():
            for n, line in enumerate(path.read_text().splitlines(), 1):
                if not line.strip():
                    continue
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    continue  # a half-written last line: that trial is simply not counted
                if rec.get("strategy") not in (None, strategy):
                    raise ValueError(f"{path}:{n}: field strategy is {rec.get('strategy')!r}, expected {strategy!r}")
                per[rec["object_id"]].append(rec)
        out[strategy] = dict(per)
    return out


def _rate(recs: list[dict]) -> float | None:
    return sum(bool(r["G"]) for r in recs) / len(recs) if recs else None


def _frac(recs: list[dict]) -> str:
    return f"{sum(bool(r['G']) for r in recs)}/{len(recs)}" if recs else "-"


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f}%"


def grounded_label(label: str, rates: dict[str, float | None]) -> str:
    """The strategy that works best.  The object's current label is kept unless another strategy
    beats it by at least GROUNDED_MARGIN (2 of 5 trials: one lucky trial does not relabel), and
    when nothing works or nothing was run."""
    known = {s: r for s, r in rates.items() if r is not None}
    if not known:
        return label
    best = max(known.values())
    if best == 0.0 or (label in known and best - known[label] < GROUNDED_MARGIN - 1e-9):
        return label
    return min(s for s, r in known.items() if r == best)


def analyse(runs: dict[str, dict[str, list[dict]]], objects=None) -> dict:
    objects = objects if objects is not None else benchmark_objects()
    rows = []
    for o in objects:
        per = {s: runs.get(s, {}).get(o.id, []) for s in "ABC"}
        rates = {s: _rate(r) for s, r in per.items()}
        g = grounded_label(o.strategy, rates)
        rows.append({
            "object_id": o.id, "category": o.category, "split": o.split, "family": o.family,
            "thickness_m": float(o.size[2]), "deformable": o.deformable, "label": o.strategy,
            "paper": o.paper_strategy, "rule": rule_label(o), "source": o.source,
            "trials": {s: len(r) for s, r in per.items()},
            "successes": {s: sum(bool(x["G"]) for x in r) for s, r in per.items()},
            "rates": rates, "grounded": g,
            "wall_s": sum(x.get("wall_s", 0.0) for r in per.values() for x in r),
        })  # fmt: skip
    cats: dict[str, dict] = {}
    for r in rows:
        c = cats.setdefault(r["category"], {"objects": 0, "labels": set(), "labelled": [0, 0], "by": {s: [0, 0] for s in "ABC"}})
        c["objects"] += 1
        c["labels"].add(r["label"])
        c["labelled"][0] += r["successes"][r["label"]]
        c["labelled"][1] += r["trials"][r["label"]]
        for s in "ABC":
            c["by"][s][0] += r["successes"][s]
            c["by"][s][1] += r["trials"][s]
    splits = {}
    for sp in BENCHMARK_SPLITS:
        sel = [r for r in rows if r["split"] == sp]
        k = sum(r["successes"][r["label"]] for r in sel)
        n = sum(r["trials"][r["label"]] for r in sel)
        splits[sp] = (k, n)

    def rate_of(cat_names, strategy):
        k = sum(cats[c]["by"][strategy][0] for c in cat_names if c in cats)
        n = sum(cats[c]["by"][strategy][1] for c in cat_names if c in cats)
        return (k / n if n else None), n

    thin = [r for r in rows if r["paper"] == "A"]  # the paper's sets, whatever the grounded labels
    deform = [r for r in rows if r["deformable"]]

    def rows_rate(sel, strategy):
        n = sum(r["trials"][strategy] for r in sel)
        return (sum(r["successes"][strategy] for r in sel) / n if n else None), n

    pattern = {
        "A on boxes": rate_of(BOX_CATEGORIES, "A"),
        "A on fabrics (Fabric, Towel, Scarf)": rate_of(FABRIC_CATEGORIES, "A"),
        "B on thin rigid objects (paper label A)": rows_rate(thin, "B"),
        "B on deformable objects": rows_rate(deform, "B"),
    }
    return {"rows": rows, "categories": cats, "splits": splits, "pattern": pattern}


def markdown(result: dict, meta: dict) -> str:
    rows, cats = result["rows"], result["categories"]
    L = ["# FlatLab asset validation report", ""]
    L += [
        f"Generated by `flatlab assets report` on {meta['date']}: {meta['objects']} objects, "
        f"{meta['trials']} randomized trials per object and strategy (placement seeds {meta['seed']}..{meta['seed'] + meta['trials'] - 1}, "
        f"planar ±5 cm, yaw ±30°), {meta['workers']} worker processes.  Wall time of the runs: "
        + ", ".join(f"{s} {meta['wall_s'].get(s, 0) / 60:.1f} min" for s in "ABC")
        + f" (total {sum(meta['wall_s'].values()) / 60:.1f} min; runs resumed from earlier output count only the new part).",
        "",
        (
            "Success is the core rule: lowest object point >= 5 cm above the table, no table contact, held by the "
            "gripper(s) for 2 s, slipping < 1 cm."
        ),
        "",
        "## The labelled strategy, per category (bar: >= 90 %)",
        "",
        "| category | objects | label | successes / trials | rate | >= 90 % |",
        "|---|---|---|---|---|---|",
    ]
    for c, v in sorted(cats.items()):
        k, n = v["labelled"]
        rate = k / n if n else None
        ok = "-" if rate is None else ("yes" if rate >= CATEGORY_BAR else "**no**")
        L.append(f"| {c} | {v['objects']} | {'/'.join(sorted(v['labels']))} | {k}/{n} | {_pct(rate)} | {ok} |")
    L += ["", "Per split (labelled strategy):", "", "| split | successes / trials | rate |", "|---|---|---|"]
    for sp, (k, n) in result["splits"].items():
        L.append(f"| {sp} | {k}/{n} | {_pct(k / n if n else None)} |")
    L += [
        "",
        "## Wrong-strategy matrix (success rate of each strategy, per category)",
        "",
        "| category | label | A (push to edge) | B (dual-arm lift) | C (fold) |",
        "|---|---|---|---|---|",
    ]
    for c, v in sorted(cats.items()):
        cells = [f"{_pct(v['by'][s][0] / v['by'][s][1] if v['by'][s][1] else None)} ({v['by'][s][0]}/{v['by'][s][1]})" for s in "ABC"]
        L.append(f"| {c} | {'/'.join(sorted(v['labels']))} | " + " | ".join(cells) + " |")
    L += ["", "The paper's pattern (a wrong strategy should fail):", ""]
    for name, (rate, n) in result["pattern"].items():
        L.append(f"- {name}: {_pct(rate)} over {n} trials")
    diff = [r for r in rows if r["grounded"] != r["label"]]
    off_rule = [r for r in rows if r["grounded"] != r["rule"]]
    relabelled = [r for r in rows if r["label"] != r["paper"]]
    L += [
        "",
        "## Physically grounded labels",
        "",
        (
            "The grounded label is the strategy with the highest success rate on the object; the current "
            f"label stays unless another strategy beats it by at least {GROUNDED_MARGIN:.0%} of the trials, "
            "or when no strategy lifts the object."
        ),
        "",
        (
            f"- {len(diff)} of {len(rows)} objects have a grounded label other than their current catalog label "
            "(relabel candidates, table below)."
        ),
        (
            f"- {len(relabelled)} objects already carry a grounded label that differs from the paper's "
            f"({', '.join(r['object_id'] for r in relabelled) or 'none'})."
        ),
        (
            f"- {len(off_rule)} objects have a grounded label other than the thin (A) / thick (B) / deformable (C) "
            f"rule's ({', '.join(r['object_id'] for r in off_rule) or 'none'})."
        ),
        "",
    ]
    if diff:
        L += ["| object | category | thickness (mm) | paper | rule | label | grounded | A | B | C |", "|---|---|---|---|---|---|---|---|---|---|"]
        for r in diff:
            L.append(
                f"| {r['object_id']} | {r['category']} | {1000 * r['thickness_m']:.0f} | {r['paper']} | {r['rule']} | {r['label']} | **{r['grounded']}** | "
                + " | ".join(f"{r['successes'][s]}/{r['trials'][s]}" for s in "ABC") + " |"
            )
    nothing = [r["object_id"] for r in rows if all((r["rates"][s] or 0.0) == 0.0 for s in "ABC")]
    L += ["", f"Objects no strategy lifted: {', '.join(nothing) if nothing else 'none'}."]
    L += [
        "",
        "## Per object",
        "",
        "| object | category | split | label | A | B | C | grounded | wall (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        L.append(
            f"| {r['object_id']} | {r['category']} | {r['split']} | {r['label']} | "
            + " | ".join(f"{r['successes'][s]}/{r['trials'][s]}" for s in "ABC")
            + f" | {r['grounded']} | {r['wall_s']:.0f} |"
        )
    slow = sorted(rows, key=lambda r: -r["wall_s"])[:10]
    L += ["", "## Slowest assets (wall time summed over all strategies and trials, one worker)", ""]
    L += [f"- {r['object_id']} ({r['category']}): {r['wall_s']:.0f} s" for r in slow]
    return "\n".join(L) + "\n"


def apply_labels(rows: list[dict], trials_note: str) -> list[str]:
    """Write every row's grounded label into its catalog YAML (the row's ``source``), in place:
    ``strategy: <grounded>  # grounded: A k/n, B k/n, C k/n (<trials_note>)`` plus
    ``paper_strategy: <paper label>``; an object whose grounded label is the paper's again loses
    both.  Only the object's own ``strategy`` / ``paper_strategy`` lines change (comments and the
    rest of the file stay); each file is re-parsed before it replaces the old one.  Returns the ids
    whose label changed."""
    import re

    import yaml

    from flatlab_lerobot.catalog import parse_object

    by_file: dict[Path, list[dict]] = defaultdict(list)
    for r in rows:
        if r["grounded"] != r["label"]:
            by_file[Path(r["source"])].append(r)
    changed = []
    for path, todo in by_file.items():
        lines = path.read_text().splitlines(keepends=True)
        for r in todo:
            start = next((i for i, ln in enumerate(lines) if re.match(rf"\s*-\s+id:\s*{re.escape(r['object_id'])}\s*$", ln)), None)
            if start is None:
                raise ValueError(f"{path}: object '{r['object_id']}': no '- id: {r['object_id']}' line to relabel")
            end = next((i for i in range(start + 1, len(lines)) if re.match(r"\s*-\s+id:", lines[i])), len(lines))
            block = [ln for ln in lines[start:end] if not re.match(r"\s+paper_strategy:", ln)]
            k = next(i for i, ln in enumerate(block) if re.match(r"\s+strategy:", ln))
            indent = re.match(r"(\s+)", block[k]).group(1)
            if r["grounded"] == r["paper"]:
                block[k] = f"{indent}strategy: {r['paper']}\n"
            else:
                evidence = ", ".join(f"{s} {r['successes'][s]}/{r['trials'][s]}" for s in "ABC")
                block[k] = f"{indent}strategy: {r['grounded']}  # grounded: {evidence} ({trials_note})\n"
                block.insert(k + 1, f"{indent}paper_strategy: {r['paper']}\n")
            lines[start:end] = block
            changed.append(r["object_id"])
        with replacing(path, mkdir=False) as tmp:  # replaced only if the edit still parses into the same objects
            tmp.write_text("".join(lines))
            for raw in yaml.safe_load(tmp.read_text())["objects"]:
                parse_object(raw, str(path))
    return changed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="flatlab assets report", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="output folder (default outputs/validation)")
    ap.add_argument("--trials", type=int, default=5, help="randomized trials per object and strategy (default 5)")
    ap.add_argument("--seed", type=int, default=1000, help="trial t uses seed SEED + t (flatlab eval's and lerobot-eval's default)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--splits", default=",".join(BENCHMARK_SPLITS))
    ap.add_argument("--objects", default="", help="comma-separated object ids (overrides --splits)")
    ap.add_argument("--strategies", default="A,B,C", help="which strategies to run now (the report reads all three)")
    ap.add_argument("--report-only", action="store_true", help="only (re)write the report from the runs already there")
    ap.add_argument("--apply-labels", action="store_true",
                    help="write the grounded labels into the catalog YAML files (the paper's label is kept as paper_strategy)")
    args = ap.parse_args(argv)
    from flatlab_lerobot.paths import OUTPUTS_DIR

    out = args.out or OUTPUTS_DIR / "validation"
    out.mkdir(parents=True, exist_ok=True)
    run_dirs = {s: out / f"strategy_{s}" for s in "ABC"}
    timing_path = out / "timing.json"
    timing = json.loads(timing_path.read_text()) if timing_path.exists() else {}
    if not args.report_only:
        for s in [x.strip() for x in args.strategies.split(",") if x.strip()]:
            if s not in STRATEGY_POLICY:
                print(f"error: --strategies: unknown strategy {s!r} (A, B or C)", file=sys.stderr)
                return 2
            cmd = [sys.executable, "-m", "flatlab_lerobot.cli", "eval", "--policy", STRATEGY_POLICY[s],
                   "--trials", str(args.trials), "--seed", str(args.seed), "--workers", str(args.workers),
                   "--out", str(run_dirs[s]), "--no-plot"]  # fmt: skip
            cmd += ["--objects", args.objects] if args.objects else ["--splits", args.splits]
            print(f"[report] strategy {s}: {' '.join(cmd[3:])}", flush=True)
            t0 = time.perf_counter()
            rc = subprocess.call(cmd)
            timing[s] = timing.get(s, 0.0) + time.perf_counter() - t0
            write_text(timing_path, json.dumps(timing))
            if rc != 0:
                print(f"error: the strategy-{s} run failed (exit {rc}); re-run to resume", file=sys.stderr)
                return rc
    runs = read_runs(run_dirs)
    if args.objects:
        from flatlab_lerobot.catalog import get_object

        objects = [get_object(o.strip()) for o in args.objects.split(",") if o.strip()]
    else:
        splits = [s.strip() for s in args.splits.split(",") if s.strip()]
        objects = [o for o in benchmark_objects() if o.split in splits]
    result = analyse(runs, objects)
    meta = {
        "date": time.strftime("%Y-%m-%d"), "objects": len(objects), "trials": args.trials, "seed": args.seed,
        "workers": args.workers, "wall_s": timing,
    }  # fmt: skip
    write_text(out / "report.md", markdown(result, meta))
    serial = {**result, "categories": {c: {**v, "labels": sorted(v["labels"])} for c, v in result["categories"].items()}}
    write_text(out / "report.json", json.dumps({"meta": meta, **serial}, indent=2))
    failing = [c for c, v in result["categories"].items() if v["labelled"][1] and v["labelled"][0] / v["labelled"][1] < CATEGORY_BAR]
    print(f"[report] {out / 'report.md'}: {len(result['categories']) - len(failing)}/{len(result['categories'])} categories "
          f">= {100 * CATEGORY_BAR:.0f} %" + (f"; below: {', '.join(sorted(failing))}" if failing else ""))  # fmt: skip
    if args.apply_labels:
        note = f"flatlab assets report, {args.trials} trials, seeds {args.seed}-{args.seed + args.trials - 1}"
        changed = apply_labels(result["rows"], note)
        print(f"[report] relabelled {len(changed)} object(s) in the catalog: {', '.join(changed) or 'none'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

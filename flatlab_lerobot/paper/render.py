"""``docs/results.md``, its plots and the README's headline table, from the results JSONs alone.

Every number comes from a record of a stage of the preset (``pipeline.statuses``): a record the
pipeline wrote (with its ``paper_stage`` provenance), or an earlier measured file in its own format
(``oracle.json``, ``strategy_*.json``, ``executor_smoke_*.json``), read through the small
normalizers below.  The paper's numbers come from ``paper_numbers.json``.  A row whose stage has
not run, or cannot run here, says so (``not run yet``, ``needs GPU``, ``not available: ...``) and
names the ``flatlab paper`` command that makes it.

:func:`tables` is deterministic for given records (no wall times, dates or commits); the page adds
the provenance (:func:`runs_table`) after it.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from flatlab_lerobot.paper.pipeline import REPO, Context, Status, display, statuses

PAPER = json.loads((Path(__file__).with_name("paper_numbers.json")).read_text())
SPLITS = ("train", "test_alpha", "test_beta")
SPLIT_NAMES = {"train": "Train", "test_alpha": "Test-α", "test_beta": "Test-β"}
T1_ROWS = [  # (our row label, the paper's Table 1 row); superseded runs: table "earlier" in the preset (earlier_runs)
    ("Slide", "Slide"), ("Lift", "Lift"), ("ACT", None), ("Diffusion Policy", "Diffusion Policy"),
    ("3D Diffusion Policy", "3D Diffusion Policy"), ("OpenVLA", "OpenVLA"), ("pi0", "pi0"), ("pi0.5", "pi0.5"),
    ("FlatLab", "FlatLab"), ("FlatLab, observed contact", None), ("Slide (scripted)", "Slide"),
    ("Lift (scripted)", "Lift"), ("oracle", None),
]  # fmt: skip
T1_VARIANT_ROWS = [  # (label, the paper's row, the row it is listed after): rows a preset may add when it runs them
    ("ACT, half-turn demos", None, "3D Diffusion Policy"),  # a baseline on other demos
    ("Diffusion Policy, half-turn demos", "Diffusion Policy", "3D Diffusion Policy"),
    ("3D Diffusion Policy, half-turn demos", "3D Diffusion Policy", "3D Diffusion Policy"),
    ("Slide, one attempt", "Slide", "Slide"),  # a learned row without retry_failed (the paper's protocol)
    ("Lift, one attempt", "Lift", "Lift"), ("FlatLab, one attempt", "FlatLab", "FlatLab"),
]  # fmt: skip
ROW_TEXT = {"oracle": "scripted oracle (expert, catalog label)", "Slide (scripted)": "Slide, scripted (expert, always A)",
            "Lift (scripted)": "Lift, scripted (expert, always B)",
            "Slide": "Slide (flatlab_unified, strategy A)", "Lift": "Lift (flatlab_unified, strategy B)",
            "FlatLab": "FlatLab (flatlab_unified)",
            **{f"{m}, one attempt": f"{m}, one attempt per episode (the paper's protocol: no retry of a "
                                    "failed lift)" for m in ("FlatLab", "Slide", "Lift")},
            "ACT": "ACT (not in the paper)",
            **{f"{m}, half-turn demos": f"{m} on half-turn demos (the expert's `b_right_half_turn`{'; not in the paper' if m == 'ACT' else ''})"
               for m in ("ACT", "Diffusion Policy", "3D Diffusion Policy")},
            "FlatLab, observed contact": "FlatLab, A's and C's contacts from the observed cloud: heights, A's slide, C's squeeze "
                                         "and pinch, A's continuing stages from the hand, A's grasp on the seen side's arm, "
                                         "its pusher backed off, a seen sheet lifted its length + 8 cm, the pinch kept closed; "
                                         "B posed by the executor (not in the paper)"}  # fmt: skip
RETRY_FLAG = "--policy.retry_failed=true"  # flatlab_unified retries a visibly failed lift (not in the paper)
ABLATIONS = ["A-1", "A-2", "A-3", "A-4", "A-5", "A-6", "A-7", "A-8", "Full"]
GENERATOR_ROWS = {"A-1", "A-2", "A-3", "A-7", "A-8", "Full"}  # the others share Full's generator
EXECUTOR_ROWS = {"A-4", "A-5", "A-6", "Full"}  # the others share Full's executor


# ----------------------------------------------------------------------------- normalizers
def _frac(k: int, n: int) -> tuple[int, int]:
    return int(k), int(n)


def grasp(rec: dict) -> dict:
    """S / G counts per split and per (split, category) from a ``flatlab eval`` results.json or the
    earlier oracle.json.  ``{"split": {s: {"G": (k, n), "S": (k, n) | None}}, "category": {(s, c): ...}}``."""
    out: dict = {"split": {}, "category": {}, "category_split_known": True}
    if "per_object" in rec:  # flatlab eval's summary
        for o in rec["per_object"]:
            for key, d in ((o["split"], out["split"]), ((o["split"], o["category"]), out["category"])):
                row = d.setdefault(key, {"G": [0, 0], "S": [0, 0]})
                row["G"][0] += o["G"]
                row["G"][1] += o["trials"]
                if o["S"] is None or row["S"] is None:
                    row["S"] = None
                else:
                    row["S"][0] += o["S"]
                    row["S"][1] += o["trials"]
        for d in (out["split"], out["category"]):
            for row in d.values():
                row["G"] = tuple(row["G"])
                row["S"] = None if row["S"] is None else tuple(row["S"])
        return out
    # the earlier oracle.json: G per split, S overall only, G per category over all splits
    s_all = rec.get("S") or {}
    perfect = s_all.get("trials") and s_all.get("correct") == s_all.get("trials")
    for s, v in (rec.get("per_split") or {}).items():
        out["split"][s] = {"G": _frac(v["G"], v["trials"]), "S": _frac(v["trials"], v["trials"]) if perfect else None}
    for c, v in (rec.get("per_category") or {}).items():
        out["category"][(None, c)] = {"G": _frac(v["G"], v["trials"]), "S": _frac(v["trials"], v["trials"]) if perfect else None}
    out["category_split_known"] = False
    return out


def strategy(rec: dict) -> dict:
    """Accuracy (%) per split against the catalog label (and the paper's label) from strategy-eval."""
    return {s: {"acc": v["acc_catalog"], "acc_paper_label": v.get("acc_paper"), "n": v["n"]}
            for s, v in (rec.get("per_split") or {}).items()}  # fmt: skip


def executor(rec: dict) -> dict:
    """Grasp P-MSE (m²) and R-Err (rad) per split from executor-metrics or the earlier smoke runs."""
    splits = rec.get("splits") or rec.get("pose_errors") or {}
    return {s: {"p_mse": v["grasp"]["p_mse_start_m2"], "r_err": v["grasp"]["r_err_start_rad"], "n": v["grasp"]["n_arm_samples"]}
            for s, v in splits.items() if "grasp" in v}  # fmt: skip


def desk(rec: dict) -> tuple[int, int]:
    """(desks cleared, desks) from ``flatlab desk`` or a ``flatlab eval --env.task=clear_desk`` summary."""
    if "per_desk" in rec:
        return rec["success"], rec["trials"]
    g = [grasp(rec)["split"][s]["G"] for s in grasp(rec)["split"]]
    return sum(k for k, _ in g), sum(n for _, n in g)


def desk_objects(rec: dict) -> float | None:
    """Mean objects cleared per desk (of 5), when the record has it."""
    if "per_desk" in rec:
        return rec.get("cleared_mean")
    return (rec.get("desk") or {}).get("cleared_mean")


def provenance(rec: dict | None) -> dict:
    """command, wall time (s), machine, device, commit of a record, whatever its format."""
    rec = rec or {}
    m = rec.get("paper_stage")
    if m:
        mach = m["machine"]
        return {"command": m["command"], "wall_s": m["wall_s"], "machine": f"{mach['cpu_count']} × {mach['cpu_model']}",
                "device": m["device"], "commit": (m["git"].get("commit") or "")[:7], "created": m["created"],
                "pipeline": True, "resumed": m.get("resumed"), "segments": m.get("wall_s_segments")}  # fmt: skip
    cmds = rec.get("commands") or ([rec["command"]] if isinstance(rec.get("command"), str) else [])
    if isinstance(rec.get("commands"), dict):
        cmds = list(rec["commands"].values())
    train = rec.get("training") or {}
    if train.get("command"):
        cmds = [train["command"], *cmds]
    wall = None
    if "train_wall_s" in train:  # strategy-eval with --train-wall
        wall = train["train_wall_s"] + rec.get("wall_s", 0)
    elif "wall_s" in train:  # executor smoke runs: training + metrics (their primitive sets: "shared")
        wall = train["wall_s"] + rec.get("metrics_wall_s", 0)
    elif (rec.get("runs") or {}).get("after_issue15_refactor"):
        wall = rec["runs"]["after_issue15_refactor"]["wall_s"]
    elif "wall_s" in rec:
        wall = rec["wall_s"]
    sets = rec.get("primitive_sets") or {}
    shared = {json.dumps(sets, sort_keys=True): sum(v.get("wall_s", 0) for v in sets.values())} if sets else {}
    # a training that ran elsewhere (e.g. on a lent GPU) names its device in the --train-wall JSON
    device = f"{train['device']} (training); cpu (evaluation)" if train.get("device") else "cpu"
    return {"command": " ; ".join(cmds), "wall_s": wall, "machine": rec.get("machine", ""), "device": device,
            "commit": (rec.get("git_commit") or rec.get("commit") or "")[:7], "created": "", "pipeline": False,
            "shared": shared}  # fmt: skip


# ----------------------------------------------------------------------------- helpers
def _rows(ctx: Context, st: dict[str, Status], table: str) -> dict[str, str]:
    """row label -> stage name, for the stages of ``table`` (the first stage wins)."""
    out: dict[str, str] = {}
    for name, stage in ctx.stages.items():
        if stage.report.get("table") == table and stage.report.get("row"):
            out.setdefault(stage.report["row"], name)
    return out


def _has(s: Status | None) -> bool:
    return s is not None and s.record is not None and s.state in ("done", "earlier", "stale")


# since this date every evaluation runs on the finger model whose pads sit flush on their fingers (stop 70); a record
# made before it ran with a 2-mm gap between pad and finger box that could hold a thin object (docs/expert.md)
FLUSH_PADS_SINCE = "2026-12-05T21:10"
OLD_FINGERS_NOTE = ("† measured before stop 70, on the finger model with a 2-mm gap between each pad and its "
                    "finger box, where a thin object could wedge (docs/expert.md); not re-run on the flush pads.")


def _old_fingers(s: Status | None) -> bool:
    """Was this evaluation record made on the finger model before the flush pads (``FLUSH_PADS_SINCE``)?"""
    if not _has(s):
        return False
    created = (s.record.get("paper_stage") or {}).get("created") or s.record.get("created")
    return not created or str(created) < FLUSH_PADS_SINCE


def _mark(*s: Status | None) -> str:
    """A row label's suffix: " †" where a record of the row (one per stage it pools) predates the flush finger pads."""
    return " †" if any(_old_fingers(x) for x in s) else ""


def _fingers_note(lines: list[str]) -> list[str]:
    """The note that explains the † mark, for a table where a row carries it (else nothing)."""
    return ["", OLD_FINGERS_NOTE] if any(" † |" in line for line in lines) else []


def _seed_runs(ctx: Context, st: dict[str, Status], name: str) -> list[tuple[int, str]]:
    """(training seed, stage) of a Table 1 row's stage ``name`` and of the stages that re-train its policy's recipe
    with another seed (``seeds_of`` its row in the preset), those with a record, in seed order."""
    label = ctx.stages[name].report.get("row")
    runs = [(stage.report.get("training_seed"), n) for n, stage in ctx.stages.items()
            if n == name or (label and stage.report.get("seeds_of") == label)]
    return sorted((int(seed), n) for seed, n in runs if seed not in ("", None) and _has(st.get(n)))


def _pooled(st: dict[str, Status], names: list[str], split: str) -> tuple[int, int] | None:
    """G's successes / trials on ``split`` summed over the records of ``names`` (None where one lacks the split)."""
    gs = [grasp(st[n].record)["split"].get(split) for n in names]
    if not gs or any(g is None for g in gs):
        return None
    return sum(g["G"][0] for g in gs), sum(g["G"][1] for g in gs)


def _seeds_row(ctx: Context, st: dict[str, Status], name: str, text: str, paper_row) -> str | None:
    """Table 1's row pooling a row's policy over its training seeds (each seed's G after the ';'), where two or more
    seeds have a record."""
    runs = _seed_runs(ctx, st, name)
    if len(runs) < 2:
        return None
    seeds, names = [s for s, _ in runs], [n for _, n in runs]
    cells = []
    for i, split in enumerate(SPLITS):
        kn = _pooled(st, names, split)
        per = " / ".join(_pct(*grasp(st[n].record)["split"][split]["G"]) for n in names) if kn else ""
        cells += [f"{_pct(*kn)} ({kn[0]}/{kn[1]}; {per})" if kn else "–", _paper_pct(paper_row[i]) if paper_row else "–"]
    what = f"{text}, pooled over training seeds {' / '.join(map(str, seeds))} (after the ';': each seed's G)"
    return (f"| {what}{_mark(*(st.get(n) for n in names))} | {' | '.join(cells)} | measured ({len(names)} trainings) | "
            f"{', '.join(f'`{n}`' for n in names)} |")


def _state(s: Status | None) -> str:
    if s is None:
        return "not in this preset"
    if s.state == "missing":
        return "not run yet"
    shown = {"done": "measured", "earlier": "measured (earlier run)", "stale": f"stale record ({s.reason})"}
    return shown.get(s.state, s.reason)


def _pct(k: int, n: int) -> str:
    return f"{100 * k / n:.1f}" if n else "–"


def _paper_pct(v) -> str:
    return "–" if v is None else f"{v:.1f}"


def _cmd(ctx: Context, name: str) -> str:
    return f"`flatlab paper --preset {ctx.preset['name']} --only {name}`"


def _commands(ctx: Context, st: dict[str, Status], names: list[str]) -> list[str]:
    """A 'commands' list: per stage the command that made (or will make) its result, each stage once (a stage can
    be both a table's row and listed again below it)."""
    lines = ["<details><summary>commands</summary>", ""]
    for n in dict.fromkeys(names):
        s = st[n]
        if s.state == "earlier":
            lines.append(f"- `{n}` (earlier run, {os.path.basename(str(s.record_path))}): `{provenance(s.record)['command']}`")
        else:
            lines.append(f"- `{n}`: {_cmd(ctx, n)} runs `{display(ctx, ctx.stages[n])}`")
    return [*lines, "", "</details>", ""]


# ----------------------------------------------------------------------------- tables
def table1(ctx: Context, st: dict[str, Status]) -> list[str]:
    rows = _rows(ctx, st, "grasp")
    paper = PAPER["table1_grasp_success_pct"]
    lines = ["## Table 1: grasp success G (%) per split", "",
             "Ours beside the paper's (`flatlab eval`: G = successes / trials; objects, trials and seeds in the commands below; "
             "the paper: 5 trials per object).", "",
             "| method | Train | paper | Test-α | paper | Test-β | paper | status | stage |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    used = []
    order = []
    for row in T1_ROWS:
        order += [row, *[(label, p) for label, p, after in T1_VARIANT_ROWS if after == row[0] and label in rows]]
    for label, paper_row in order:
        name = rows.get(label)
        s = st.get(name) if name else None
        p = paper.get(paper_row) if paper_row else None
        text = ROW_TEXT.get(label, label)
        if name and RETRY_FLAG in ctx.stages[name].cmd:  # the stage's own flags say whether it retries
            text = f"{text[:-1]}; a visibly failed lift retried, not in the paper)" if text.endswith(")") else f"{text} (retrying)"
        lines.append(f"| {text}{_mark(s)} | {' | '.join(_g_cells(s, p))} | {_state(s)} | "
                     f"{f'`{name}`' if name else '–'} |")
        if name:
            used.append(name)
            if pooled := _seeds_row(ctx, st, name, text, p):
                lines.append(pooled)
    lines += _fingers_note(lines)
    lines += ["", "The paper's Slide and Lift are fixed-strategy methods; we report both the scripted expert with the "
              "strategy fixed and the learned unified policy with the strategy fixed. The paper has no ACT row.", ""]
    return lines + earlier_runs(ctx, st, used) + _commands(ctx, st, used)


def _g_cells(s: Status | None, paper_row=None, with_paper: bool = True) -> list[str]:
    """Per split: our G (k/n) and, ``with_paper``, the paper's (``paper_row``; "–" where it has none)."""
    cells = []
    for i, split in enumerate(SPLITS):
        g = grasp(s.record)["split"].get(split) if _has(s) else None
        cells.append(f"{_pct(*g['G'])} ({g['G'][0]}/{g['G'][1]})" if g else "–")
        if with_paper:
            cells.append(_paper_pct(paper_row[i]) if paper_row else "–")
    return cells


def earlier_runs(ctx: Context, st: dict[str, Status], used: list[str]) -> list[str]:
    """Runs a newer stage superseded, and variants of a row (table "earlier" in the preset), in the preset's order,
    each with its own text; appends their stage names to ``used`` (their commands are listed with Table 1's)."""
    names = [n for n, stage in ctx.stages.items() if stage.report.get("table") == "earlier"]
    if not names:
        return []
    lines = ["### Earlier runs and variants of a row above (kept for comparison)", "",
             "| run | Train | Test-α | Test-β | status | stage |", "|---|---|---|---|---|---|"]  # fmt: skip
    for n in names:
        rep = ctx.stages[n].report
        lines.append(f"| {rep.get('text') or rep.get('row') or n} | {' | '.join(_g_cells(st.get(n), with_paper=False))} | {_state(st.get(n))} | `{n}` |")
        used.append(n)
    return [*lines, ""]


def table2(ctx: Context, st: dict[str, Status]) -> list[str]:
    srows, erows = _rows(ctx, st, "strategy"), _rows(ctx, st, "executor")
    pa, pp = PAPER["table2"]["strategy_accuracy_pct"], PAPER["table2"]["grasp_p_mse"]
    what = PAPER["table2"]["what"]
    head = "| ablation | what | Train | paper | Test-α | paper | Test-β | paper | status |"
    lines = ["## Table 2: ablations A-1 … A-8", "",
             "### Strategy accuracy (%) of the generator (`flatlab strategy-eval`)", "",
             "Against the grounded catalog label, on the 104 benchmark objects in fresh placements (3 views each). "
             "A-4 … A-6 change only the executor: their generator is Full's.", "", head, "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for ab in ABLATIONS:
        row_of = ab if ab in GENERATOR_ROWS else "Full"
        name = srows.get(row_of)
        s = st.get(name) if name else None
        m = strategy(s.record) if _has(s) else {}
        cells = []
        for i, split in enumerate(SPLITS):
            cells += [f"{m[split]['acc']:.1f}" if split in m else "–", _paper_pct(pa[ab][i])]
        state = _state(s) if row_of == ab else "= Full"
        lines.append(f"| {ab} | {what[ab]} | {' | '.join(cells)} | {state} |")
    lines += ["", "### Grasp P-MSE of the executor (`flatlab executor-metrics`)", "",
              "Mean squared error (m²) of the grasp primitive's start position over the commanded arms (the paper "
              "states no unit). A-1 … A-3, A-7, A-8 change only the generator: their executor is Full's.", "",
              head, "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for ab in ABLATIONS:
        row_of = ab if ab in EXECUTOR_ROWS else "Full"
        name = erows.get(row_of)
        s = st.get(name) if name else None
        m = executor(s.record) if _has(s) else {}
        cells = []
        for i, split in enumerate(SPLITS):
            cells += [f"{m[split]['p_mse']:.4f}" if split in m else "–", f"{pp[ab][i]:.4f}"]
        state = _state(s) if row_of == ab else "= Full"
        lines.append(f"| {ab} | {what[ab]} | {' | '.join(cells)} | {state} |")
    return lines + [""] + _commands(ctx, st, [*srows.values(), *erows.values()])


def per_category(ctx: Context, st: dict[str, Status]) -> list[str]:
    rows = _rows(ctx, st, "grasp")
    pc = PAPER["per_category"]
    ours = {}
    for label in ("FlatLab", "oracle", "Slide (scripted)", "Lift (scripted)", "Slide", "Lift", "Diffusion Policy", "3D Diffusion Policy"):
        s = st.get(rows.get(label, ""))
        ours[label] = grasp(s.record) if _has(s) else None
    lines = ["## Per category: strategy choice S and grasp success G", "",
             "Successes / trials per category (the paper's App. tables). FlatLab = the learned unified policy; "
             "the paper's Slide / Lift / DP / DP3 columns beside ours.", ""]  # fmt: skip
    note = False

    def cell(label, split, cat, key="G"):
        nonlocal note
        g = ours.get(label)
        if g is None:
            return "–"
        v = g["category"].get((split, cat))
        if v is None and not g["category_split_known"]:
            v = g["category"].get((None, cat))
            shared = sum(cat in pc["flatlab_S_G"][x] for x in SPLITS) > 1  # a Train and Test-alpha category
            note = note or shared
            return "–" if v is None or v[key] is None else f"{v[key][0]}/{v[key][1]}{'¹' if shared else ''}"
        return "–" if v is None or v[key] is None else f"{v[key][0]}/{v[key][1]}"

    for split in SPLITS:
        lines += [f"### {SPLIT_NAMES[split]}", "",
                  "| category | FlatLab S | paper | FlatLab G | paper | oracle G | Slide G (scripted) | paper | "
                  "Lift G (scripted) | paper | DP G | paper | DP3 G | paper |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for cat, (ps, pg) in pc["flatlab_S_G"][split].items():
            pb = pc["baselines_G"][split][cat]
            lines.append(
                f"| {cat} | {cell('FlatLab', split, cat, 'S')} | {ps} | {cell('FlatLab', split, cat)} | {pg} | "
                f"{cell('oracle', split, cat)} | {cell('Slide (scripted)', split, cat)} | {pb[0]} | "
                f"{cell('Lift (scripted)', split, cat)} | {pb[1]} | {cell('Diffusion Policy', split, cat)} | {pb[2]} | "
                f"{cell('3D Diffusion Policy', split, cat)} | {pb[3]} |"
            )
        lines.append("")
    if note:
        lines += ["¹ Train and Test-α together: the earlier run's file counts categories over all splits.", ""]
    return lines


def _sweep_points(ctx: Context, st: dict[str, Status], sw: dict) -> list[tuple[float, str, Status | None]]:
    prefix = "strategy_" if sw["list"] == "strategy_runs" else "executor_"
    return [(float(v), prefix + rid, st.get(prefix + rid)) for v, rid in sw["runs"].items()]


def sensitivity(ctx: Context, st: dict[str, Status], plots: Path | None, page_dir: Path | None = None) -> list[str]:
    lines = ["## Sensitivity (paper App.: λ, τ of the generator; λ_pos of the executor)", ""]
    if not ctx.preset["sweeps"]:
        return lines + ["No sweeps in this preset.", ""]
    paper_pos = PAPER["sensitivity"]["lambda_pos"]
    for sw in ctx.preset["sweeps"]:
        pts = _sweep_points(ctx, st, sw)
        strat = sw["list"] == "strategy_runs"
        lines += [f"### {sw['label']} (`{sw['flag']}`; default {sw['default']})", ""]
        if strat:
            note = PAPER["sensitivity"].get(sw["id"], {}).get("_note", "")
            lines += [f"Paper: {note}." if note else "", "", "| value | Train | Test-α | Test-β | status | stage |", "|---|---|---|---|---|---|"]
        else:
            lines += ["| value | P-MSE Test-α | paper | P-MSE Test-β | paper | R-Err Test-α (rad) | R-Err Test-β (rad) | status | stage |",
                      "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        measured = []
        for v, name, s in pts:
            if strat:
                m = strategy(s.record) if _has(s) else {}
                cells = [f"{m[x]['acc']:.1f}" if x in m else "–" for x in SPLITS]
            else:
                m = executor(s.record) if _has(s) else {}
                pv = dict(zip(map(float, paper_pos["values"]), range(len(paper_pos["values"]))))
                j = pv.get(v)
                cells = []
                for x in ("test_alpha", "test_beta"):
                    cells += [f"{m[x]['p_mse']:.4f}" if x in m else "–",
                              "–" if j is None else f"{paper_pos[x]['p_mse'][j]:.4f}"]  # fmt: skip
                cells += [f"{m[x]['r_err']:.3f}" if x in m else "–" for x in ("test_alpha", "test_beta")]
            if m:
                measured.append((v, m))
            lines.append(f"| {v:g} | {' | '.join(cells)} | {_state(s)} | `{name}` |")
        lines.append("")
        if len(measured) >= 2 and plots is not None:
            png = plots / f"{ctx.preset['results_prefix'].replace('/', '_')}sens_{sw['id']}.png"
            _plot(sw, measured, png, paper_pos if not strat else None)
            lines += [f"![{sw['label']}]({os.path.relpath(png, page_dir or plots)})", ""]
        elif len(measured) < 2:
            lines += [f"Plot: not drawn ({len(measured)} of {len(pts)} values measured; needs 2).", ""]
        lines += _commands(ctx, st, [n for _, n, _ in pts])
    return lines


def _plot(sw: dict, measured: list, png: Path, paper_pos: dict | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullLocator

    fig, ax = plt.subplots(figsize=(5.2, 3.2))
    xs = [v for v, _ in measured]
    colors = {"train": "tab:blue", "test_alpha": "tab:orange", "test_beta": "tab:green"}
    if paper_pos is None:
        for split in SPLITS:
            ys = [m.get(split, {}).get("acc") for _, m in measured]
            ax.plot(xs, ys, "o-", color=colors[split], label=SPLIT_NAMES[split])
        ax.set_ylabel("strategy accuracy (%)")
        ax.set_ylim(0, 100)
    else:
        for split in ("test_alpha", "test_beta"):
            ys = [m.get(split, {}).get("p_mse") for _, m in measured]
            ax.plot(xs, ys, "o-", color=colors[split], label=f"{SPLIT_NAMES[split]} (ours, m²)")
            ax.plot(paper_pos["values"], paper_pos[split]["p_mse"], "s--", color=colors[split], alpha=0.5,
                    label=f"{SPLIT_NAMES[split]} (paper)")  # fmt: skip
        ax.set_ylabel("grasp P-MSE")
    if min(xs) > 0:
        ax.set_xscale("log")
        ax.xaxis.set_minor_locator(NullLocator())  # the swept values only: no crowded minor labels
        ax.set_xticks(xs, [f"{v:g}" for v in xs])
    ax.axvline(float(sw["default"]), color="grey", lw=0.8, ls=":")
    ax.set_xlabel(sw["label"])
    ax.set_title("ours" + (" (solid) vs the paper (dashed)" if paper_pos else "") + "; dotted: the default", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110, metadata={"Software": None})
    plt.close(fig)


def desk_table(ctx: Context, st: dict[str, Status]) -> list[str]:
    rows = _rows(ctx, st, "desk")
    paper = PAPER["clear_desk"]
    lines = ["## The five-object desk (`clear_desk`)", "",
             "Five rigid Test-β objects of five categories in one cell, cleared one after another; success = all five "
             "lifted (2-s hold) and none left on the table.", "",
             "| method | desks cleared | rate (%) | paper (%) | objects cleared per desk (of 5) | status | stage |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    shown = set()
    for label, paper_key in (("oracle", None), ("FlatLab", "FlatLab"), ("FlatLab, observed contact", None),
                             ("GPT-4o", "GPT-4o + same executor")):  # fmt: skip
        name = rows.get(label)
        shown.add(name)
        s = st.get(name) if name else None
        k_n = desk(s.record) if _has(s) else None
        per = desk_objects(s.record) if _has(s) else None
        text = (ctx.stages[name].report.get("text") if name else None) or {  # a stage's own text: what it ran
            "oracle": "scripted oracle (expert, labels)", "FlatLab": "FlatLab (flatlab_unified)",
            "GPT-4o": "GPT-4o + the same executor"}.get(label) or ROW_TEXT[label]  # fmt: skip
        ours = f"{k_n[0]}/{k_n[1]}" if k_n else "–"
        rate = _pct(*k_n) if k_n else "–"
        state = _state(s) if label != "GPT-4o" else "not rebuilt (needs the OpenAI API)"
        lines.append(f"| {text}{_mark(s)} | {ours} | {rate} | "
                     f"{_paper_pct(paper.get(paper_key)) if paper_key else '–'} | "
                     f"{'–' if per is None else f'{per:.2f}'} | {state} | "
                     f"{f'`{name}`' if name else '–'} |")  # fmt: skip
    # desk stages a newer one of the same row superseded (the preset's first wins), or of a row of their own: in a
    # table of their own below, with their own text
    earlier = [n for n, stage in ctx.stages.items() if stage.report.get("table") == "desk" and n not in shown]
    if earlier:
        lines += ["", "### Earlier desk runs and variants (kept for comparison)", "",
                  "Rows a newer run above superseded, and variants measured beside them; each says what it ran.", "",
                  "| method | desks cleared | rate (%) | paper (%) | objects cleared per desk (of 5) | status | stage |",
                  "|---|---|---|---|---|---|---|"]  # fmt: skip
    for n in earlier:
        s, rep = st.get(n), ctx.stages[n].report
        k_n = desk(s.record) if _has(s) else None
        per = desk_objects(s.record) if _has(s) else None
        lines.append(f"| {rep.get('text') or rep.get('row') or n} | {f'{k_n[0]}/{k_n[1]}' if k_n else '–'} | "
                     f"{_pct(*k_n) if k_n else '–'} | – | {'–' if per is None else f'{per:.2f}'} | {_state(s)} | `{n}` |")  # fmt: skip
    return [*lines, *_fingers_note(lines), "", *_commands(ctx, st, [*rows.values(), *earlier])]


def tables(ctx: Context, st: dict[str, Status] | None = None, plots: Path | None = None, page_dir: Path | None = None) -> str:
    """Every results table of the preset, deterministic for given records (no times, dates, commits);
    sweep plots are drawn into ``plots`` (linked relative to ``page_dir``) when given."""
    st = st or statuses(ctx)
    parts = (table1(ctx, st) + table2(ctx, st) + per_category(ctx, st) + sensitivity(ctx, st, plots, page_dir)
             + desk_table(ctx, st))
    return "\n".join(parts).rstrip() + "\n"


def runs_table(ctx: Context, st: dict[str, Status]) -> str:
    """Wall time, machine, device and commit per stage; totals per kind and for the preset."""
    lines = ["## Runs: wall time per stage", "",
             "Measured records only; an earlier run's file gives one wall time for its whole chain (training + "
             "evaluation; the executor's: training + metrics, its primitive sets counted once below); a stage that "
             "resumed an interrupted run sums its runs (marked with their number); one resumed before stop 60 gives the "
             "wall time of the trials it ran (marked resumed). `$OUT` = "
             f"`outputs/paper/{ctx.preset['name']}`, `$RESULTS` = `docs/results`.", "",
             "| stage | kind | status | wall (s) | machine | device | commit | created |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    totals: dict[str, float] = {}
    seen: set = set()
    shared_note: list[str] = []
    for name, stage in ctx.stages.items():
        s = st[name]
        if s.record is None or s.state == "blocked":
            continue
        p = provenance(s.record)
        key = str(s.record_path)
        wall = p["wall_s"] if key not in seen else None  # one earlier file may stand for several stages
        seen.add(key)
        if wall is not None:
            totals[stage.kind] = totals.get(stage.kind, 0) + wall
        for k, w in p.get("shared", {}).items():  # primitive sets that several earlier executor runs used
            if k not in seen:
                seen.add(k)
                totals["learning-set"] = totals.get("learning-set", 0) + w
                shared_note.append(f"`{name}`'s primitive sets: {w:.0f} s (counted once)")
        cell = "–" if wall is None else f"{wall:.0f}"
        if wall is not None and p.get("segments"):  # a resumed stage whose log held its earlier runs: their sum
            cell += f" ({len(p['segments'])} runs)"
        elif wall is not None and p.get("resumed"):  # the run resumed an interrupted one: its wall is its own trials'
            r = p["resumed"]
            cell += f" (resumed: {r['trials_this_run']} of {r['trials_before'] + r['trials_this_run']} trials)"
        lines.append(f"| `{name}` | {stage.kind} | {_state(s)} | {cell} | {p['machine']} | "
                     f"{p['device']} | {p['commit'] or '–'} | {p['created'] or '–'} |")  # fmt: skip
    n_left = sum(1 for n in ctx.stages if st[n].state in ("missing", "stale"))
    n_blocked = sum(1 for n in ctx.stages if st[n].state == "blocked")
    lines += ["", "| kind | wall (s) | wall (h) |", "|---|---|---|"]
    for kind, w in totals.items():
        lines.append(f"| {kind} | {w:.0f} | {w / 3600:.2f} |")
    total = sum(totals.values())
    lines += [f"| **preset {ctx.preset['name']} (measured part)** | **{total:.0f}** | **{total / 3600:.2f}** |", "",
              f"Stages not run yet: {n_left}; blocked here: {n_blocked}; total: {len(ctx.stages)}."
              + (f" Earlier runs' learning sets: {'; '.join(shared_note)}." if shared_note else ""), ""]  # fmt: skip
    return "\n".join(lines)


def _scored_input(ctx: Context, stage: str | None, kind: str) -> str | None:
    """The metrics stage that scores the ``kind`` (``strategy`` or ``executor``) model ``stage``'s policy holds: the
    first ``<kind>_train_<id>`` up its inputs, scored by ``<kind>_<id>`` (None where there is none, e.g. a scripted
    policy; the build's first executor is its main one, before ``--alt-executor``)."""
    todo, seen = [stage] if stage in ctx.stages else [], set()
    while todo:
        name = todo.pop(0)
        for i in ctx.stages[name].inputs:
            if i.startswith(f"{kind}_train_") and (m := f"{kind}_" + i.removeprefix(f"{kind}_train_")) in ctx.stages:
                return m
            if i not in seen:
                seen.add(i)
                todo.append(i)
    return None


def headline(ctx: Context, st: dict[str, Status] | None = None) -> str:
    """The README's headline table: ours (paper) per split."""
    st = st or statuses(ctx)
    g, s_, e = _rows(ctx, st, "grasp"), _rows(ctx, st, "strategy"), _rows(ctx, st, "executor")
    pt1, pa, pp = PAPER["table1_grasp_success_pct"], PAPER["table2"]["strategy_accuracy_pct"]["Full"], PAPER["table2"]["grasp_p_mse"]["Full"]
    lines = [f"| result (`--preset {ctx.preset['name']}`) | Train | Test-α | Test-β |", "|---|---|---|---|"]

    def row(text, name, fmt, paper):
        s = st.get(name) if name else None
        if not _has(s):
            why = _state(s).split(": ", 1)[-1].split(" (")[0]  # "not available", "needs GPU", "not run yet"
            return f"| {text} | {why} (paper {paper[0]}) | – (paper {paper[1]}) | – (paper {paper[2]}) |"
        return f"| {text} | " + " | ".join(f"{fmt(s.record, x)} (paper {paper[i]})" for i, x in enumerate(SPLITS)) + " |"

    def g_fmt(rec, x):
        v = grasp(rec)["split"].get(x)
        return f"**{_pct(*v['G'])} %**" if v else "–"

    def g_row(text, name, paper):  # marked where the record predates the flush finger pads
        return row(f"{text}{_mark(st.get(name) if name else None)}", name, g_fmt, paper)

    lines.append(g_row("FlatLab (learned) grasp success G", g.get("FlatLab"), pt1["FlatLab"]))
    if "FlatLab, one attempt" in g:  # the row without the retries the paper's method does not make
        lines.append(g_row("FlatLab, one attempt per episode, G", g["FlatLab, one attempt"], pt1["FlatLab"]))
    # the paper's strongest end-to-end baseline: each of its rows (default demos, half-turn demos) measured on the flush
    # finger pads, so the headline picks neither by its score; where none was, the default demos' row
    dp3 = [(r, t) for r, t in (("3D Diffusion Policy", ""), ("3D Diffusion Policy, half-turn demos", ", half-turn demos")) if r in g]
    current = [(r, t) for r, t in dp3 if _has(st.get(g[r])) and not _old_fingers(st.get(g[r]))]
    for r, t in current or dp3[:1]:
        seeds = [n for _, n in _seed_runs(ctx, st, g[r])]
        if len(seeds) > 1:  # one training's luck moves it (stops 83-84): the row pooled over its training seeds
            def pooled(_rec, x):  # the cell from the seeds' records, not from the first one's
                return f"**{_pct(*kn)} %**" if (kn := _pooled(st, seeds, x)) else "–"

            lines.append(row(f"3D Diffusion Policy (end-to-end{t}; {len(seeds)} training seeds pooled) G"
                             f"{_mark(*(st.get(n) for n in seeds))}", seeds[0], pooled, pt1["3D Diffusion Policy"]))
        else:
            lines.append(g_row(f"3D Diffusion Policy (end-to-end{t}) G", g[r], pt1["3D Diffusion Policy"]))
    lines.append(g_row("scripted oracle grasp success G", g.get("oracle"), ["–"] * 3))

    def shipped(kind: str, full: str | None, what: str) -> tuple[str | None, str]:
        """The FlatLab row's own model's metrics stage (the Full recipe's until it has a record) and the row's text."""
        name = _scored_input(ctx, g.get("FlatLab"), kind)
        if not _has(st.get(name)):
            name = full
        recipe = (ctx.stages[name].report.get("row") or name.removeprefix(f"{kind}_")) if name in ctx.stages else "Full"
        return name, what + ("" if recipe == "Full" else f" (the {recipe} recipe FlatLab ships; paper: Full)")

    gen, text = shipped("strategy", s_.get("Full"), "strategy generator accuracy")
    lines.append(row(text, gen, lambda r, x: f"{strategy(r)[x]['acc']:.1f} %" if x in strategy(r) else "–", pa))
    exe, text = shipped("executor", e.get("Full"), "executor grasp P-MSE (m²)")
    lines.append(row(text, exe, lambda r, x: f"{executor(r)[x]['p_mse']:.4f}" if x in executor(r) else "–",
                     [f"{v:.4f}" for v in pp]))  # fmt: skip
    return "\n".join(lines + _fingers_note(lines)) + "\n"


def write_page(ctx: Context, page: Path | None = None) -> Path:
    st = statuses(ctx)
    default_dir = (REPO / "docs" / "results").resolve()
    if page is None:
        if ctx.results_dir != default_dir:
            page = ctx.results_dir / "results.md"
        else:  # the cpu preset's page is the main one; another preset's sits beside it
            page = REPO / "docs" / ("results.md" if ctx.preset["name"] == "cpu" else f"results_{ctx.preset['name']}.md")
    plots = ctx.results_dir / "plots"
    body = tables(ctx, st, plots, page.parent)
    p = ctx.preset
    head = [f"# Results: the paper's tables, measured (`--preset {p['name']}`)", "",
            "<!-- generated by `flatlab paper --render-only` from docs/results/*.json: do not edit by hand -->", "",
            f"Preset `{p['name']}`: {p.get('description', '')}. Every number below comes from a results JSON under "
            "`docs/results/` (command, seeds, commit, wall time, machine, device inside); the paper's numbers from "
            f"`flatlab_lerobot/paper/paper_numbers.json`. Rebuild the page with `flatlab paper --preset {p['name']} --render-only`; "
            f"run what is missing with `flatlab paper --preset {p['name']}` (`--dry-run` shows the plan).", ""]  # fmt: skip
    notes = [Path(__file__).with_name(f) for f in (f"notes_{p['name']}.md", "reproducibility.md")]
    extra = "".join("\n" + f.read_text() for f in notes if f.is_file())
    text = "\n".join(head) + "\n" + body + "\n" + runs_table(ctx, st) + extra
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text(text)
    return page

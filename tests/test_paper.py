"""``flatlab paper``: the stage registry and presets as data, caching, blocked stages, the renderer
against the committed results, the README headline, and the whole pipeline on the tiny preset."""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import shutil
from pathlib import Path

import pytest

from flatlab_lerobot.paper import pipeline as P
from flatlab_lerobot.paper import render as R
from flatlab_lerobot.paper.main import main as paper_main

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "docs" / "results"


def ctx_for(preset, tmp_path=None, results=None):
    return P.context(preset, tmp_path / "out" if tmp_path else None, results)


# ----------------------------------------------------------------------------- registry
@pytest.mark.parametrize("preset", P.presets())
def test_presets_expand_into_a_consistent_registry(preset):
    ctx = ctx_for(preset)
    names = list(ctx.stages)
    for i, (name, st) in enumerate(ctx.stages.items()):
        assert st.kind in P.KINDS
        assert all(names.index(inp) < i for inp in st.inputs), f"{name}: an input comes later"
        assert not any("${" in a for a in st.cmd), f"{name}: unexpanded variable in {st.cmd}"
        if st.is_result:
            assert st.metrics and st.report.get("table") in {"grasp", "earlier", "strategy", "executor", "desk"}
            if st.report.get("table") == "earlier":  # a superseded run says what it was
                assert st.report.get("text"), name
    # every Table 1 / Table 2 row of the paper has a stage in the cpu and paper presets
    if preset in ("cpu", "paper"):
        rows = {(s.report["table"], s.report["row"]) for s in ctx.stages.values() if s.report.get("row")}
        for label, paper_row in R.T1_ROWS:
            assert ("grasp", label) in rows, label
        # a Table 1 stage's row is the paper's or a listed variant (else table1 would drop it)
        known = {label for label, _ in R.T1_ROWS} | {label for label, *_ in R.T1_VARIANT_ROWS}
        assert {after for *_, after in R.T1_VARIANT_ROWS} <= {label for label, _ in R.T1_ROWS}
        assert {s.report["row"] for s in ctx.stages.values() if s.report.get("table") == "grasp"} <= known
        assert {("strategy", r) for r in R.GENERATOR_ROWS} <= rows
        assert {("executor", r) for r in R.EXECUTOR_ROWS} <= rows
        assert ("desk", "FlatLab") in rows and ("desk", "oracle") in rows


def test_sweeps_are_generated_from_one_list_and_reuse_existing_runs():
    ctx = ctx_for("cpu")
    lam = next(s for s in ctx.preset["sweeps"] if s["id"] == "lambda")
    assert lam["runs"][0.5] == "cpu" and lam["runs"][0.0] == "ablation_A1"  # the default and A-1 (lambda = 0)
    tr = ctx.stages["strategy_train_lambda_1.0"]
    assert tr.cmd[-1] == "--policy.contrast_weight=1.0" and "--config_path=policies/flatlab_strategy/cpu.json" in tr.cmd
    pos = ctx.stages["executor_train_lambda_pos_3.0"]
    assert pos.cmd[-1] == "--policy.lambda_pos=3.0" and "strategy_train_tau_0.2" in ctx.stages
    assert "executor_train_lambda_pos_10.0" not in ctx.stages  # the default is the base run itself


def test_a_stage_names_a_shared_flag_list_and_a_self_reference_fails():
    ctx = ctx_for("cpu")
    v12_extra = ["--policy.retry_track=true", "--policy.reach_check=true"]
    # args: ["${desk_twelve_switches}"], spliced in, with its own "${desk_switches}" (shared with the one-build desk)
    shared = P._subst(["${desk_twelve_switches}"], ctx.preset["vars"], "here")
    assert ctx.preset["vars"]["desk_twelve_switches"][-1] == "${desk_switches}"
    assert shared[1:] == ctx.preset["vars"]["desk_switches"]
    one = ctx.stages["eval_desk_flatlab_contact_one_rot15"].cmd
    assert one[-len(shared) - 1 : -2] == shared[1:] and one[-2:] == v12_extra
    v11 = ctx.stages["eval_desk_flatlab_contact_v11h_rot15"].cmd
    v12 = ctx.stages["eval_desk_flatlab_contact_v12h_rot15"].cmd
    assert v11[-len(shared) :] == shared
    assert v12[: len(v11)] == v11 and v12[len(v11) :] == v12_extra
    env = {"a": ["x", "${b}"], "b": ["${a}"]}
    with pytest.raises(P.PaperError, match=r"\$\{a\} refers to itself \(through a -> b\)"):
        P._subst(["${a}"], env, "here")
    assert P._subst(["${a}", "y"], {"a": ["x", "${c}"], "c": ["z"]}, "here") == ["x", "z", "y"]


def test_fingerprint_follows_command_recipe_and_inputs(tmp_path, monkeypatch):
    ctx = ctx_for("tiny", tmp_path)
    fp = P.fingerprints(ctx)
    assert fp == P.fingerprints(ctx_for("tiny", tmp_path / "elsewhere"))  # not the output location
    ctx.stages["strategy_export_cpu"].cmd.append("--seed=3")
    fp2 = P.fingerprints(ctx)
    assert fp2["strategy_export_cpu"] != fp["strategy_export_cpu"]
    assert fp2["strategy_cpu"] != fp["strategy_cpu"]  # downstream of the change
    assert fp2["eval_oracle"] == fp["eval_oracle"]  # not downstream
    real = P._file_hash
    monkeypatch.setattr(P, "_file_hash", lambda rel: "edited" if rel.endswith("flatlab_executor/cpu.json") else real(rel))
    assert P.fingerprints(ctx)["executor_train_cpu"] != fp["executor_train_cpu"]


def test_unmet_needs_block_a_stage_and_its_users(monkeypatch, tmp_path):
    # the measured records, less unified_cpu's own stage record and eval_slide's and eval_desk_flatlab's:
    # a stage not run here and users of it without a record
    res = tmp_path / "results"
    skip = ("plots", "unified_cpu.json", "eval_slide.json", "eval_desk_flatlab.json")
    shutil.copytree(RESULTS, res, ignore=shutil.ignore_patterns(*skip))
    ctx = ctx_for("cpu", tmp_path, res)
    st = P.statuses(ctx)
    assert st["eval_pi0"].state == "blocked" and "needs weights" in st["eval_pi0"].reason
    assert st["eval_desk_flatlab"].state != "blocked"  # flatlab_unified --policy.clear_all=true clears desks
    ctx.stages["eval_desk_flatlab"].needs.append("todo:what is still missing")
    ctx.stages["unified_cpu"].needs.append("module:flatlab_lerobot.no_such_module")
    st = P.statuses(ctx)
    assert st["eval_desk_flatlab"].state == "blocked" and "what is still missing" in st["eval_desk_flatlab"].reason
    assert st["unified_cpu"].state == "blocked" and "no_such_module not in this tree" in st["unified_cpu"].reason
    # a user of the blocked stage without a record of its own is blocked too (eval_flatlab has one: earlier)
    assert st["eval_flatlab"].state == "earlier"
    assert st["eval_slide"].state == "blocked" and st["eval_slide"].reason.startswith("unified_cpu:")
    monkeypatch.setattr(P, "_CUDA", [False])
    paper = P.statuses(ctx_for("paper"))
    ex = paper["executor_train_paper"]  # not run on a GPU yet
    assert ex.state == "blocked" and ex.reason == "needs GPU"
    assert paper["executor_paper"].reason == "executor_train_paper: needs GPU"
    assert paper["primitive_set_train"].state == "missing"  # learning sets need no GPU
    # a training recorded on a GPU machine (scripts/device_paper.sh) is done here, and so are its users' inputs
    for train, metrics in (("strategy_train_paper", "strategy_paper"), ("strategy_train_ablation_A1", "strategy_ablation_A1"),
                           ("strategy_train_ablation_A8", "strategy_ablation_A8"),
                           ("strategy_train_ablation_A3", "strategy_ablation_A3")):
        assert paper[train].state == "done" and paper[metrics].state == "done"
    with pytest.raises(P.PaperError, match="unknown need"):
        P.unmet("tpu")


def test_dry_run_plan_reports_earlier_runs_and_blocked_stages(capsys):
    assert paper_main(["--preset", "cpu", "--dry-run", "--no-render"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"eval_act\s+eval\s+earlier\s+\(measured before `flatlab paper`", out)
    assert re.search(r"eval_oracle\s+eval\s+earlier\s+\(earlier run: oracle.json\)", out)
    assert re.search(r"eval_pi0\s+eval\s+blocked\s+\(needs weights \(lerobot/pi0\)\)", out)
    # stages with a measured record are planned only when asked for (--force)
    assert paper_main(["--preset", "cpu", "--dry-run", "--no-render", "--only", "baseline_train_diffusion",
                       "strategy_train_lambda_0.1", "--force", "strategy_train_lambda_0.1", "baseline_train_diffusion"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "$ lerobot-train --config_path=policies/flatlab_strategy/cpu.json" in out
    assert re.search(r"baseline_train_diffusion\s+train\s+run", out)
    assert "--dataset.episodes=$(flatlab collect --recipe datasets/baselines_cpu.yaml" in out
    with pytest.raises(P.PaperError, match="no such stage"):
        paper_main(["--preset", "cpu", "--only", "nope", "--dry-run"])


# ----------------------------------------------------------------------------- renderer
def test_tables_from_the_committed_results(tmp_path):
    ctx = ctx_for("cpu")
    text = R.tables(ctx)
    oracle = json.loads((RESULTS / "eval_oracle_flush_pads.json").read_text())  # the oracle row since stop 70
    for split in R.SPLITS:
        g = oracle["per_split"][split]
        k = round(g["G"] * g["trials"])
        cell = f"{100 * k / g['trials']:.1f} ({k}/{g['trials']})"
        assert re.search(rf"\| scripted oracle \(expert, catalog label\) \|.*{re.escape(cell)}", text), cell
    # since stop 87 every Table 1 row is measured on the flush finger pads (stop 70): no row carries the mark, so the
    # table has no note for it; a row made before them would get both (below, and the headline test with old records)
    table1 = text.split("## Table 2")[0]
    assert "| 3D Diffusion Policy | 0.0 (0/150) |" in table1  # DP3 re-run, stop 85
    assert "| Diffusion Policy | 0.0 (0/150) |" in table1  # re-run on the flush finger pads, stop 86
    assert "| ACT (not in the paper) | 0.7 (1/150) |" in table1  # re-run on the flush finger pads, stop 87
    assert "| FlatLab, one attempt per episode (the paper's protocol: no retry of a failed lift) |" in table1  # stop 79
    assert "| scripted oracle (expert, catalog label) |" in table1
    assert " † |" not in table1 and R.OLD_FINGERS_NOTE not in table1
    assert R._fingers_note(["| ACT † | 0.0 |"]) == ["", R.OLD_FINGERS_NOTE] and R._fingers_note(["| ACT | 0.0 |"]) == []
    full = json.loads((RESULTS / "strategy_cpu.json").read_text())["per_split"]
    row = next(line for line in text.splitlines() if line.startswith("| Full | the full model | ") and "." in line)
    assert row.split(" | ")[2] == f"{full['train']['acc_catalog']:.1f}"
    ex = json.loads((RESULTS / "executor_cpu.json").read_text())["splits"]  # the cpu run (its legacy: the smoke run)
    assert f"| {ex['test_beta']['grasp']['p_mse_start_m2']:.4f} | 0.0040 |" in text
    assert "needs weights (lerobot/pi0)" in text
    desk = text.split("## The five-object desk")[1]  # every desk stage has a table row, whatever its row label
    desk_rows = "\n".join(line for line in desk.splitlines() if line.startswith("|"))
    assert all(f"`{n}` |" in desk_rows for n, s in ctx.stages.items() if s.report.get("table") == "desk")
    # a stage without its record renders as not run (the committed results hold every cpu sweep point)
    shutil.copytree(RESULTS, tmp_path / "results")
    (tmp_path / "results" / "executor_lambda_pos_3.0.json").unlink()
    partial = R.tables(ctx_for("cpu", tmp_path, tmp_path / "results"))
    assert re.search(r"\| 3 \| – \|.*\| not run yet \| `executor_lambda_pos_3.0` \|", partial)
    assert "| 81.1 |" in text.split("## Table 2")[0]  # the paper's FlatLab Train


def test_sweep_plot_is_drawn_from_records(tmp_path):
    """Two lambda_pos records (one earlier file, one written here) give a table row each and a PNG."""
    res = tmp_path / "results"
    shutil.copytree(RESULTS, res, ignore=shutil.ignore_patterns("plots"))
    rec = json.loads((RESULTS / "executor_smoke_cpu2000.json").read_text())
    new = {"splits": rec["pose_errors"], "paper_stage": {"fingerprint": "x", "machine": {}, "git": {}}}
    (res / "executor_lambda_pos_3.0.json").write_text(json.dumps(new))
    ctx = ctx_for("cpu", tmp_path, res)
    text = R.tables(ctx, plots=tmp_path / "plots", page_dir=tmp_path)
    assert "![λ_pos (position loss weight, λ_rot = 1)](plots/sens_lambda_pos.png)" in text
    assert (tmp_path / "plots" / "sens_lambda_pos.png").stat().st_size > 5000
    assert "| 3 | 0.0047 | 0.0047 |" in text  # ours (the copied record) beside the paper's lambda_pos = 3
    assert "stale record" in text  # its fingerprint is not this registry's


def test_headline_scores_the_models_the_flatlab_row_runs():
    """The headline's generator accuracy is the one the FlatLab row's policy holds (found up its inputs), not
    another recipe's; a scripted policy holds none."""
    ctx = ctx_for("cpu")
    row = R._rows(ctx, P.statuses(ctx), "grasp")["FlatLab"]
    build = next(i for i in ctx.stages[row].inputs if i.startswith("unified_"))
    train = next(i for i in ctx.stages[build].inputs if i.startswith("strategy_train_"))
    assert R._scored_input(ctx, row, "strategy") == "strategy_" + train.removeprefix("strategy_train_")
    executor = next(i for i in ctx.stages[build].inputs if i.startswith("executor_train_"))  # the main one, first
    assert R._scored_input(ctx, row, "executor") == "executor_" + executor.removeprefix("executor_train_")
    assert R._scored_input(ctx, "eval_oracle_flush_pads", "strategy") is None
    assert R._scored_input(ctx, None, "strategy") is None
    generator = ctx.stages[R._scored_input(ctx, row, "strategy")].report["row"]
    assert f"the {generator} recipe FlatLab ships" in R.headline(ctx)


def test_headline_dp3_rows_are_the_runs_on_the_flush_pads():
    """The headline shows each DP3 row (default demos, half-turn demos) measured on the flush finger pads, whatever
    its score; with both records on the old finger model, the default demos' row alone."""
    ctx = ctx_for("cpu")
    st = P.statuses(ctx)
    g = R._rows(ctx, st, "grasp")
    default, half = g["3D Diffusion Policy"], g["3D Diffusion Policy, half-turn demos"]

    def lines(statuses):
        return [x for x in R.headline(ctx, statuses).splitlines() if x.startswith("| 3D Diffusion Policy")]

    def created(name, when):
        s = st[name]
        rec = json.loads(json.dumps(s.record))
        rec.setdefault("paper_stage", {})["created"] = when
        return P.Status(s.state, s.reason, rec, s.record_path)

    old, new = "2026-11-01T00:00:00+00:00", "2026-12-07T00:00:00+00:00"
    only_half = lines({**st, default: created(default, old), half: created(half, new)})
    assert len(only_half) == 1 and "half-turn demos" in only_half[0]
    both = lines({**st, default: created(default, new), half: created(half, new)})
    assert len(both) == 2 and "half-turn demos" not in both[0] and "half-turn demos" in both[1]
    neither = lines({**st, default: created(default, old), half: created(half, old)})
    assert len(neither) == 1 and "half-turn demos" not in neither[0] and " † |" in neither[0]


def test_table1_pools_a_row_over_its_training_seeds(tmp_path):
    """DP3's half-turn row gets a row pooled over the seeds its recipe was trained with (``seeds_of`` in the preset):
    the records' successes and trials summed per split, each seed's G beside them, and the headline pools them too;
    with one seed's record alone there is no pooled row, and the headline is that seed's row."""
    ctx = ctx_for("cpu")
    st = P.statuses(ctx)
    half = R._rows(ctx, st, "grasp")["3D Diffusion Policy, half-turn demos"]
    runs = R._seed_runs(ctx, st, half)
    assert [s for s, _ in runs][:2] == [1000, 2000] and runs[0][1] == half
    recs = [json.loads((RESULTS / f"{n}.json").read_text())["per_split"]["test_beta"] for _, n in runs]
    k, n = sum(round(r["G"] * r["trials"]) for r in recs), sum(r["trials"] for r in recs)
    table1 = R.tables(ctx).split("## Table 2")[0]
    row = next(x for x in table1.splitlines() if "pooled over training seeds 1000 / 2000" in x)
    assert f"| {100 * k / n:.1f} ({k}/{n}; " in row and f"`{runs[1][1]}`" in row
    assert f"{len(runs)} training seeds pooled) G | " in R.headline(ctx)
    # without the seed-2000 record (and any later seed's): the single run only
    shutil.copytree(RESULTS, tmp_path / "results")
    for _, name in runs[1:]:
        (tmp_path / "results" / f"{name}.json").unlink()
    alone = ctx_for("cpu", tmp_path, tmp_path / "results")
    assert "pooled over training seeds" not in R.tables(alone)
    assert "| 3D Diffusion Policy (end-to-end, half-turn demos) G | " in R.headline(alone)


def test_readme_headline_is_the_rendered_one():
    text = (REPO / "README.md").read_text()
    m = re.search(r"<!-- results:headline -->\n(.*?)<!-- /results:headline -->", text, re.S)
    assert m, "README.md lacks the <!-- results:headline --> block"
    assert m[1] == R.headline(ctx_for("cpu")), "README headline is stale: flatlab paper --headline"


@pytest.mark.parametrize("preset,page", [("cpu", "results.md"), ("paper", "results_paper.md")])
def test_results_page_is_the_rendered_one(preset, page):
    """docs/results.md (docs/results_paper.md) holds exactly the tables --render-only makes from docs/results/ (plots aside)."""
    ctx = ctx_for(preset)

    def strip(text):  # without plot links / notes, blank lines collapsed
        text = re.sub(r"^(!\[[^\]]*\]\([^)]*\)|Plot: not drawn.*)$", "", text, flags=re.M)
        return re.sub(r"\n{2,}", "\n\n", text)

    body = strip(R.tables(ctx, P.statuses(ctx), None, REPO / "docs"))
    assert body in strip((REPO / "docs" / page).read_text()), f"docs/{page} is stale: flatlab paper --preset {preset} --render-only"


# ----------------------------------------------------------------------------- the tiny preset end to end
def _table_lines(text: str, start: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith(start)]


@pytest.mark.slow
def test_tiny_pipeline_end_to_end_and_reproducible(tmp_path, capsys):
    out, res = tmp_path / "out", tmp_path / "res"
    args = ["--preset", "tiny", "--out", str(out), "--results-dir", str(res)]
    assert paper_main(args) == 0
    ctx = P.context("tiny", out, res)
    st = P.statuses(ctx)
    ran = [n for n, s in st.items() if s.state == "done"]
    assert set(ran) == set(ctx.stages)
    for n in ran:  # every record carries its provenance
        meta = st[n].record["paper_stage"]
        assert {"command", "fingerprint", "seeds", "git", "wall_s", "machine", "device", "preset", "created"} <= set(meta)
        assert meta["preset"] == "tiny" and meta["machine"]["cpu_count"] and meta["device"].startswith(("cpu", "cuda"))
        assert "metrics" in st[n].record or ctx.stages[n].is_result
    page = (res / "results.md").read_text()
    # the rendered numbers are the results files' numbers
    ev = json.loads((res / "tiny" / "eval_oracle.json").read_text())
    for o in ev["per_object"]:
        cell = f"{100 * o['G'] / o['trials']:.1f} ({o['G']}/{o['trials']})"
        assert cell in _table_lines(page, "| scripted oracle")[0]
    acc = json.loads((res / "tiny" / "strategy_cpu.json").read_text())["per_split"]
    full = next(line for line in _table_lines(page, "| Full | the full model |") if "strategy" not in line)
    assert full.split(" | ")[2] == f"{acc['train']['acc_catalog']:.1f}"
    ex = json.loads((res / "tiny" / "executor_cpu.json").read_text())["splits"]["train"]["grasp"]
    assert f"| {ex['p_mse_start_m2']:.4f} | 0.0032 |" in page
    uni = json.loads((res / "tiny" / "eval_flatlab.json").read_text())["per_split"]["train"]
    assert f"{100 * uni['G']:.1f} (" in _table_lines(page, "| FlatLab (flatlab_unified)")[0]
    first = R.tables(ctx)
    # cached: nothing to run
    capsys.readouterr()
    assert paper_main([*args, "--dry-run"]) == 0
    assert not re.search(r"\s(run)\s", capsys.readouterr().out)
    # same preset and seeds: a forced rerun of the training and its evaluation gives the same tables
    before = json.loads((res / "tiny" / "strategy_cpu.json").read_text())
    trained = st["strategy_train_cpu"].record["metrics"]
    assert len(trained["model_sha256"]) == 64 and len(trained["content_sha256"]) == 64
    assert paper_main([*args, "--only", "strategy_cpu", "--force", "strategy_train_cpu", "--no-render"]) == 0
    after = json.loads((res / "tiny" / "strategy_cpu.json").read_text())
    st_after = P.statuses(P.context("tiny", out, res))
    retrained = st_after["strategy_train_cpu"].record["metrics"]
    assert retrained["model_sha256"] == trained["model_sha256"]  # bit-identical weights, and the record says so
    # the metrics stage reran with the forced training; the other users of its weights stay done (same digest)
    assert after["paper_stage"]["input_digests"]["strategy_train_cpu"] == retrained["content_sha256"]
    assert {n for n, s in st_after.items() if s.state != "done"} == set()
    assert after["paper_stage"]["created"] >= before["paper_stage"]["created"]
    for key in ("per_split", "per_category", "per_object", "selection"):
        assert after[key] == before[key], key
    assert R.tables(P.context("tiny", out, res)) == first
    # an interrupted evaluation resumes after its saved trials (a half-written last line dropped), gives the same
    # numbers, and its record sums the wall times of its runs (the earlier one from the stage's log)
    rec_path, jsonl = res / "tiny" / "eval_oracle.json", ctx.out("eval_oracle") / "results.jsonl"
    whole, lines = json.loads(rec_path.read_text()), jsonl.read_text().splitlines(keepends=True)
    assert len(lines) == 2
    jsonl.write_text(lines[0] + lines[1][:20])
    rec_path.unlink()
    assert paper_main([*args, "--only", "eval_oracle", "--no-render"]) == 0
    resumed = json.loads(rec_path.read_text())
    assert resumed["paper_stage"]["resumed"] == {"trials_before": 1, "trials_this_run": 1}
    assert resumed["per_object"] == whole["per_object"] and resumed["per_split"] == whole["per_split"]
    segments = resumed["paper_stage"]["wall_s_segments"]
    assert len(segments) == 2 and segments[0] == whole["paper_stage"]["wall_s"]
    assert resumed["paper_stage"]["wall_s"] == pytest.approx(sum(segments), abs=0.11)
    log = ctx.log_path("eval_oracle").read_text()
    assert log.count("# segment started ") == 2 and log.count("# segment ended ") == 2
    ctx = P.context("tiny", out, res)
    row = next(line for line in R.runs_table(ctx, P.statuses(ctx)).splitlines() if line.startswith("| `eval_oracle` |"))
    assert "(2 runs)" in row


def test_a_record_is_stale_once_its_input_is_rebuilt_and_a_forced_stage_reruns_its_users(tmp_path):
    """A record keeps its inputs' data digests: when an input's record later carries another digest (a rebuilt
    training), the record is stale though its config is the same; forcing a stage reruns the selected stages
    downstream of it, whose records describe the output it replaces."""
    ctx = ctx_for("tiny", tmp_path, tmp_path / "res")
    fps = P.fingerprints(ctx)
    train, metrics = "strategy_train_cpu", "strategy_cpu"
    assert train in ctx.stages[metrics].inputs
    upstream, todo = set(), [metrics]
    while todo:  # every stage the metrics stage needs, done, with its output in place
        upstream.update(ins := ctx.stages[todo.pop()].inputs)
        todo += ins
    for name in upstream:
        P.write_json(ctx.record_path(name), {"metrics": {"content_sha256": f"{name}-1"},
                                             "paper_stage": {"fingerprint": fps[name]}})  # fmt: skip
    digests = {i: f"{i}-1" for i in ctx.stages[metrics].inputs}
    P.write_json(ctx.record_path(metrics), {"paper_stage": {"fingerprint": fps[metrics], "input_digests": digests}})
    for name in (metrics, *upstream):
        ctx.out(name).mkdir(parents=True)
    assert P.statuses(ctx)[metrics].state == "done"
    assert P.plan(ctx, [metrics], set(), P.statuses(ctx)) == []
    assert P.plan(ctx, [metrics], {train}, P.statuses(ctx)) == [train, metrics]  # downstream of the forced one
    rebuilt = {"metrics": {"content_sha256": "rebuilt"}, "paper_stage": {"fingerprint": fps[train]}}
    P.write_json(ctx.record_path(train), rebuilt)
    st = P.statuses(ctx)
    assert st[metrics].state == "stale" and st[metrics].reason == f"input {train} rebuilt since its record"
    assert P.plan(ctx, [metrics], set(), st) == [metrics]
    assert "stale record (input strategy_train_cpu rebuilt since its record)" == R._state(st[metrics])
    # a record from before the digests (no input_digests) cannot tell, and stays done
    P.write_json(ctx.record_path(metrics), {"paper_stage": {"fingerprint": fps[metrics]}})
    assert P.statuses(ctx)[metrics].state == "done"


def test_output_digests_follow_the_data_not_the_run(tmp_path):
    """A stage record's ``content_sha256`` hashes arrays, tables and weights, not a json's wall time; its
    ``model_sha256`` is the last numbered checkpoint's weights (``last`` is a link to it)."""
    out = tmp_path / "train"
    for step, w in (("000002", b"w2"), ("000004", b"w4")):
        (out / "checkpoints" / step / "pretrained_model").mkdir(parents=True)
        (out / "checkpoints" / step / "pretrained_model" / "model.safetensors").write_bytes(w)
    (out / "train_config.json").write_text('{"wall_s": 1.0}')
    files = lambda: [p for p in out.rglob("*") if p.is_file()]  # noqa: E731
    first = P.content_hashes(out, files())
    assert first["model_sha256"] == __import__("hashlib").sha256(b"w4").hexdigest()
    (out / "train_config.json").write_text('{"wall_s": 2.0}')
    assert P.content_hashes(out, files()) == first
    (out / "checkpoints" / "000002" / "pretrained_model" / "model.safetensors").write_bytes(b"other")
    moved = P.content_hashes(out, files())
    assert moved["content_sha256"] != first["content_sha256"] and moved["model_sha256"] == first["model_sha256"]
    assert P.content_hashes(tmp_path / "none", []) == {}


def test_a_killed_run_ends_at_its_logs_last_write_and_a_resume_adds_it(tmp_path):
    """A stage killed mid-run (the GPU machine's deadline) wrote no end to its log; the run that resumes it
    closes that segment at the log's last write and counts it in the stage's wall time."""
    log = tmp_path / "stage.log"
    assert P._earlier_segments(log) == []
    log.write_text("$ lerobot-train ...\nstep:10 loss:1.0\n")  # a log from before the segment markers
    assert P._earlier_segments(log) == []
    log.write_text("# segment started 2026-12-04T10:00:00+00:00\n$ lerobot-train ...\n\n"
                   "# segment ended 2026-12-04T10:01:40+00:00 after 100.0 s (exit 0)\n"
                   "# segment started 2026-12-04T11:00:00+00:00\n$ lerobot-train --resume=true\nstep:20 loss:0.5\n")  # fmt: skip
    killed_at = _dt.datetime(2026, 12, 4, 11, 4, 10, tzinfo=_dt.timezone.utc).timestamp()
    os.utime(log, (killed_at, killed_at))
    assert P._earlier_segments(log) == [100.0, 250.0]
    assert "after 250.0 s (interrupted: no exit written)" in log.read_text()
    assert P._earlier_segments(log) == [100.0, 250.0]  # closed once


def test_git_commit_of_a_tree_copy_comes_from_the_environment(monkeypatch):
    """scripts/device_paper.sh runs stages in a copy of the tree whose .git may be stale: FLATLAB_GIT_COMMIT wins."""
    monkeypatch.setenv("FLATLAB_GIT_COMMIT", "0123abc")
    assert P.git_commit() == {"commit": "0123abc", "dirty": False, "from": "FLATLAB_GIT_COMMIT"}
    monkeypatch.delenv("FLATLAB_GIT_COMMIT")
    assert P.git_commit()["commit"] != "0123abc"


def test_provenance_of_an_earlier_run_names_where_its_training_ran():
    rec = {"command": "flatlab strategy-eval --policy X", "wall_s": 30.0, "machine": "2 CPU cores",
           "training": {"command": "lerobot-train --policy.device=cuda", "train_wall_s": 740.0,
                        "device": "cuda (NVIDIA H100 80GB HBM3)"}}  # fmt: skip
    p = R.provenance(rec)
    assert p["wall_s"] == 770.0 and p["command"].startswith("lerobot-train")
    assert p["device"] == "cuda (NVIDIA H100 80GB HBM3) (training); cpu (evaluation)"
    del rec["training"]["device"]
    assert R.provenance(rec)["device"] == "cpu"

"""The evaluation protocol runner: resumable results.jsonl, summaries in the paper's format."""

import json

from flatlab_lerobot.bench.protocol import main

ARGS = ["--policy", "oracle", "--objects", "ref_box,ref_book", "--trials", "2", "--quiet", "--no-plot"]


def _keys(path):
    return [(r["object_id"], r["trial"]) for r in map(json.loads, path.read_text().splitlines())]


def test_resume_after_interruption(tmp_path):
    out = tmp_path / "eval"
    assert main([*ARGS, "--out", str(out), "--workers", "2", "--max-trials", "1"]) == 0
    jsonl = out / "results.jsonl"
    first = _keys(jsonl)
    assert len(first) == 1 and not (out / "results.json").exists()
    # simulate a kill in the middle of writing the next line
    with open(jsonl, "a") as f:
        f.write('{"policy": "oracle", "object_id": "ref_bo')
    assert main([*ARGS, "--out", str(out), "--workers", "2"]) == 0
    keys = _keys(jsonl)
    assert keys[0] == first[0]  # kept, not repeated
    assert sorted(keys) == sorted({(o, t) for o in ("ref_box", "ref_book") for t in range(2)})
    summary = json.loads((out / "results.json").read_text())
    assert summary["overall"]["trials"] == 4 and summary["overall"]["S"] == 1.0
    md = (out / "results.md").read_text()
    assert "| reference | Box | ref_box | B | 2/2 |" in md
    # a third run has nothing left to do and rewrites the same summary
    assert main([*ARGS, "--out", str(out), "--workers", "2"]) == 0
    assert _keys(jsonl) == keys


def test_baselines_choose_fixed_strategies(tmp_path):
    out = tmp_path / "lift"
    assert main(["--policy", "lift_only", "--objects", "ref_box,ref_book", "--trials", "1", "--quiet",
                 "--workers", "1", "--out", str(out)]) == 0
    recs = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert {r["strategy"] for r in recs} == {"B"}
    assert {r["object_id"]: r["S"] for r in recs} == {"ref_box": True, "ref_book": False}
    assert (out / "results.png").stat().st_size > 0

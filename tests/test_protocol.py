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


def test_kill_9_then_rerun_finishes_without_repeats(tmp_path):
    """A real ``kill -9`` of ``flatlab eval`` half-way, then a re-run: every trial exactly once."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "eval"
    args = ["--policy", "oracle", "--objects", "ref_box,ref_book", "--trials", "3", "--quiet", "--no-plot",
            "--workers", "1", "--out", str(out)]  # fmt: skip
    cmd = [sys.executable, "-m", "flatlab_lerobot.cli", "eval", *args]
    proc = subprocess.Popen(cmd, start_new_session=True, env={**os.environ, "MUJOCO_GL": "egl"})
    jsonl = out / "results.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and not (jsonl.exists() and len(jsonl.read_text().splitlines()) >= 2):
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = len(_keys(jsonl))
    assert 2 <= done_before < 6, done_before
    assert subprocess.run(cmd, env={**os.environ, "MUJOCO_GL": "egl"}, timeout=300).returncode == 0
    keys = _keys(jsonl)
    assert sorted(keys) == sorted({(o, t) for o in ("ref_box", "ref_book") for t in range(3)})
    assert json.loads((out / "results.json").read_text())["overall"]["trials"] == 6

"""scripts/desk_objects.py: what became of every object of a desk (the uncounted carries in docs/unified.md)."""

import json

import pytest


def test_desk_objects_reports_when_each_object_left_the_table_and_whether_it_counted(script, tmp_path, capsys):
    out = tmp_path / "desks.jsonl"
    assert script("desk_objects").main(["--policy", "oracle", "--desks", "24", "--out", str(out), "--hold-trace", "--",
                           "--env.task=clear_desk", "--env.episode_length=300", "--env.obs_pixels=false",
                           "--env.obs_pointcloud=false"]) == 0  # fmt: skip
    row = json.loads(out.read_text().splitlines()[0])
    assert row["desk"] == 24 and len(row["objects"]) == len(row["cleared"]) == 5
    first = row["objects"][0]
    assert row["longest_hold_s"][first] >= 2.0, row  # the oracle lifts the first object and holds it (no carry):
    assert row["off_table"] == {} and not any(row["cleared"]), row  # lifted, but still above the table
    assert f"desk 24: cleared {sum(row['cleared'])}/5" in capsys.readouterr().out
    # --hold-trace: the first object's hold timer, step by step, counts up to the 2 s while a hand holds it aloft
    held = [t for t in row["hold_trace"] if t["object"] == first]
    assert held and all(t["arms"] for t in held), row["hold_trace"][:3]
    assert max(t["held_s"] for t in held) >= 2.0 and all(t["clearance"] >= 0.05 for t in held if t["held_s"] > 0)


def test_desk_objects_needs_the_desk_task(script, tmp_path):
    with pytest.raises(SystemExit):
        script("desk_objects").main(["--policy", "oracle", "--desks", "24", "--out", str(tmp_path / "x.jsonl")])

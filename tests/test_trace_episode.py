"""scripts/trace_episode.py: one flatlab-eval trial traced stage by stage (the failure reasons in docs/unified.md)."""

import json

import pytest


def test_trace_prints_the_trial_outcome_and_one_line_per_stage(script, capsys):
    main = script("trace_episode").main
    assert main(["--policy", "oracle", "--object", "ref_box", "--trial", "0", "--",
                 "--env.episode_length=40", "--env.obs_pixels=false", "--env.obs_pointcloud=false"]) == 0  # fmt: skip
    out = capsys.readouterr().out.splitlines()
    head = json.loads(out[0])
    assert head["object_id"] == "ref_box" and head["seed"] == 1000 and head["steps"] == 40
    stages = [line.split()[2] for line in out[2:] if line[:4].strip().isdigit()]
    assert stages[0] == "move" and "touch" in stages, out  # the expert's first transit, then its touch
    assert out[2 + len(stages)].startswith("end:   40"), out


def test_trace_refuses_flags_it_would_not_pass_on(script):
    with pytest.raises(SystemExit):
        script("trace_episode").main(["--policy", "oracle", "--object", "ref_box", "--", "--trials=3"])

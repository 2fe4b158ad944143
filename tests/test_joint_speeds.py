"""scripts/joint_speeds.py: the arms' joint speeds in flatlab-eval trials against the Panda's ratings."""

import json

import numpy as np
import pytest


def test_joint_speeds_per_stage_of_an_expert_trial(script, tmp_path, capsys):
    mod = script("joint_speeds")
    out = tmp_path / "js.json"
    assert mod.main(["--policy", "oracle", "--objects", "ref_box", "--trials", "1", "--out", str(out), "--",
                     "--env.episode_length=40", "--env.obs_pixels=false", "--env.obs_pointcloud=false"]) == 0  # fmt: skip
    res = json.loads(out.read_text())
    assert res["steps"] == 39 and res["per_trial"][0]["steps"] == 40  # the first step has no change to measure
    stages = res["per_stage"]
    assert "move" in stages and "touch" in stages  # the expert's first transit, then its touch
    assert sum(v["steps"] for v in stages.values()) == 39
    for v in stages.values():
        assert 0.0 <= v["max_commanded_x_rated"] < 5.0 and 0.0 <= v["max_measured_x_rated"] < 5.0
        assert v["max_measured_joint"].split("/")[0] in ("left", "right")
    assert res["rated_rad_s"] == [2.175] * 4 + [2.61] * 3
    assert res["machine"]["cpu_count"] >= 1 and res["git"]["commit"] and "--objects ref_box" in res["command"]
    assert "move" in capsys.readouterr().out


def test_summarize_names_the_joint_and_counts_steps_over(script):
    mod = script("joint_speeds")
    rated = np.tile([2.175] * 4 + [2.61] * 3, 2)
    slow, fast = rated * 0.5, rated * 0.5
    fast[9] = rated[9] * 2.0  # right/joint3 at twice its rating
    s = mod.summarize([("move", slow, slow), ("move", fast, slow), ("touch", slow, fast)])
    assert s["move"]["steps"] == 2 and s["move"]["steps_commanded_over"] == 1 and s["move"]["steps_measured_over"] == 0
    assert s["move"]["max_commanded_x_rated"] == 2.0 and s["move"]["max_commanded_joint"] == "right/joint3"
    assert s["touch"]["steps_measured_over"] == 1 and s["touch"]["max_measured_joint"] == "right/joint3"


def test_joint_speeds_refuses_bad_arguments(script):
    with pytest.raises(SystemExit):
        script("joint_speeds").main(["--policy", "oracle", "--objects", "", "--out", "x.json"])
    with pytest.raises(SystemExit):
        script("joint_speeds").main(["--policy", "oracle", "--objects", "ref_box", "--trials", "0", "--out", "x.json"])

"""Tests parametrised over what is registered: every strategy on every reference object, every built-in
``flatlab eval`` policy, every ``flatlab`` subcommand.  (Recipes: tests/test_recipes.py; tasks:
tests/test_tasks.py and tests/test_env.py; assets and scenes: tests/test_assets.py, tests/test_scenes.py.)"""

import contextlib
import io
import json
import re

import numpy as np
import pytest

from flatlab_lerobot import cli
from flatlab_lerobot.catalog import REFERENCE_OBJECTS, get_object
from flatlab_lerobot.evaluation.protocol import BUILTIN
from flatlab_lerobot.evaluation.protocol import main as eval_main
from flatlab_lerobot.strategies import STRATEGIES


def _subcommands() -> list[str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        cli.main(["--help"])
    return sorted(re.search(r"\{([\w,-]+)\}", out.getvalue()).group(1).split(","))


SUBCOMMANDS = _subcommands()


def test_every_passthrough_subcommand_is_listed():
    assert set(cli.PASSTHROUGH) <= set(SUBCOMMANDS)


@pytest.mark.parametrize("cmd", SUBCOMMANDS)
def test_subcommand_help(cmd):
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as e:
        cli.main([cmd, "--help"])
    assert e.value.code == 0, out.getvalue()
    assert "usage:" in out.getvalue()


@pytest.fixture(scope="module")
def start_states():
    """Each reference object's observation right after a seeded reset (cloth settles: built once)."""
    from flatlab_lerobot.env import FlatLabEnv

    out = {}
    for oid in sorted(set(REFERENCE_OBJECTS.values())):
        env = FlatLabEnv(object_id=oid, obs_pixels=False, obs_pointcloud=False)
        obs, _ = env.reset(seed=0)
        out[oid] = (obs, env.cell, env.action_space)
        env.close()
    return out


@pytest.mark.parametrize("strategy", sorted(STRATEGIES))
@pytest.mark.parametrize("object_id", sorted(set(REFERENCE_OBJECTS.values())))
def test_every_strategy_poses_every_stage_on_every_reference_object(start_states, strategy, object_id):
    """Kinematic dry run (no physics: the arms are taken to reach each commanded posture, the object
    stays where it lay): every stage of the strategy is posed, every action finite and within the
    actuator ranges, and the expert ends holding."""
    from flatlab_lerobot.rollout import ExpertPolicy

    obs, cell, space = start_states[object_id]
    policy = ExpertPolicy(strategy, cell)
    obs = dict(obs)
    seen = []
    for _ in range(2000):
        action = policy(obs)
        assert action.shape == (16,) and np.all(np.isfinite(action))
        assert np.all(action >= space.low - 1e-6) and np.all(action <= space.high + 1e-6), (policy.stage, action)
        if not seen or seen[-1] != policy.primitive:
            seen.append(policy.primitive)
        obs["agent_pos"] = action.astype(np.float32)
        if policy.primitive == len(STRATEGIES[strategy]) - 1 and policy.stage == "hold" and len(seen) > 1:
            break
    assert seen == list(range(len(STRATEGIES[strategy]))), seen


@pytest.mark.parametrize("policy", sorted(BUILTIN))
def test_builtin_policy_runs_and_reports_its_strategy(tmp_path, policy):
    out = tmp_path / policy
    assert eval_main(["--policy", policy, "--objects", "ref_box", "--trials", "1", "--workers", "1", "--quiet",
                      "--no-plot", "--out", str(out), "--env.episode_length=3"]) == 0  # fmt: skip
    (rec,) = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    expected = BUILTIN[policy](get_object("ref_box"))
    assert rec["strategy"] == ("B" if expected == "auto" else expected)  # the box is thick: auto picks B
    assert rec["S"] == (rec["strategy"] == "B") and rec["steps"] == 3 and not rec["G"]
    assert rec["failure_reason"] == "not_aloft"  # FailureReason vocabulary

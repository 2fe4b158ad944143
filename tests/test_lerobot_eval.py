"""End to end: the real ``lerobot-eval`` CLI runs the scripted policy on the flatlab env, and its
per-episode successes agree with the env's own success rule for the same seeds (rerun in-process)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import flatlab_lerobot  # noqa: F401
from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.policies.scripted.modeling_flatlab_scripted import pick_strategy
from flatlab_lerobot.strategies import Expert

BIN = Path(sys.executable).parent
EPISODE_LENGTH = 100
SEED = 1000  # lerobot-eval's default --seed; episode i uses SEED + i


def run_expert(seed: int, object_id: str, strategy: str = "auto") -> tuple[bool, int]:
    """In-process: the env's own success for one seeded episode driven by the expert."""
    env = FlatLabEnv(object_id=object_id, obs_pixels=False, obs_pointcloud=False, episode_length=EPISODE_LENGTH)
    obs, info = env.reset(seed=seed)
    if strategy == "auto":
        strategy = pick_strategy(obs["environment_state"])
    last = {"obs": obs}
    # float32 observations, as the policy sees them through lerobot-eval
    gen = Expert(None, env.control_dt).episode(
        strategy,
        lambda: (last["obs"]["agent_pos"].astype(np.float64), last["obs"]["environment_state"].astype(np.float64)),
    )
    for t in range(EPISODE_LENGTH):
        _, _, action = next(gen)
        last["obs"], _, term, trunc, info = env.step(action.astype(np.float32))
        if term or trunc:
            break
    env.close()
    return bool(info["is_success"]), t + 1


def test_pick_strategy_rule():
    st = np.zeros(14)
    st[9] = 0.02
    assert pick_strategy(st) == "A"
    st[9] = 0.08
    assert pick_strategy(st) == "B"
    st[10] = 1.0
    assert pick_strategy(st) == "C"


@pytest.mark.slow
def test_lerobot_eval_cli_matches_env_success(tmp_path):
    out = tmp_path / "eval"
    cmd = [
        str(BIN / "lerobot-eval"),
        "--policy.type=flatlab_scripted",
        "--policy.device=cpu",
        "--env.type=flatlab",
        "--env.object_id=ref_box",
        "--env.image_size=32",
        "--env.render_size=64",
        "--env.n_points=128",
        "--env.n_object_points=32",
        f"--env.episode_length={EPISODE_LENGTH}",
        "--eval.n_episodes=2",
        "--eval.batch_size=1",
        f"--seed={SEED}",
        f"--output_dir={out}",
    ]
    env = {**os.environ, "MUJOCO_GL": "egl"}
    res = subprocess.run(cmd, check=False, capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    info = json.loads((out / "eval_info.json").read_text())
    metrics = info["per_task"][0]["metrics"]
    cli = [bool(s) for s in metrics["successes"]]
    assert len(cli) == 2
    ours = [run_expert(SEED + i, "ref_box")[0] for i in range(2)]
    assert cli == ours, (cli, ours)
    assert info["overall"]["pc_success"] == pytest.approx(100 * np.mean(ours))
    assert all(ours), "strategy B should lift the reference box"


@pytest.mark.slow
@pytest.mark.parametrize("task_id", ["touch_dual", "slide_to_edge"])
def test_lerobot_eval_runs_a_task(tmp_path, task_id):
    """``lerobot-eval --env.task=<id>``: the scripted expert completes the sub-task, judged by its predicate."""
    object_id = "ref_box" if task_id == "touch_dual" else "ref_book"
    out = tmp_path / "eval"
    cmd = [
        str(BIN / "lerobot-eval"), "--policy.type=flatlab_scripted", "--policy.device=cpu", "--env.type=flatlab",
        f"--env.task={task_id}", f"--env.object_id={object_id}", "--env.image_size=32", "--env.render_size=64",
        "--env.n_points=128", "--env.n_object_points=32", "--env.episode_length=150", "--eval.n_episodes=1",
        "--eval.batch_size=1", f"--output_dir={out}",
    ]  # fmt: skip
    res = subprocess.run(cmd, check=False, capture_output=True, text=True, env={**os.environ, "MUJOCO_GL": "egl"}, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["pc_success"] == 100.0

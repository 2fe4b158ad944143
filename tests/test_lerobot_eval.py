"""End to end: the real ``lerobot-eval`` CLI runs the scripted policy on the flatlab envs sub-tasks;
:func:`run_expert` replays an episode in-process (used by tests/test_protocol.py to check lerobot-eval's
per-episode successes against the env's own success rule)."""

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
from flatlab_lerobot.rollout import ExpertPolicy, rollout

BIN = Path(sys.executable).parent
EPISODE_LENGTH = 100
SEED = 1000  # lerobot-eval's default --seed; episode i uses SEED + i


def run_expert(seed: int, object_id: str, strategy: str = "auto", episode_length: int = EPISODE_LENGTH) -> tuple[bool, int]:
    """In-process, through the one episode loop: the env's own success and length for one seeded
    episode driven by the expert, with float32 observations and actions as lerobot-eval passes them."""
    env = FlatLabEnv(object_id=object_id, obs_pixels=False, obs_pointcloud=False, episode_length=episode_length)
    first = env.reset(seed=seed)[0]
    if strategy == "auto":
        strategy = pick_strategy(first["environment_state"])
    expert = ExpertPolicy(strategy, None, env.control_dt)

    def policy(obs):
        as64 = {k: np.asarray(v, np.float64) for k, v in obs.items()}
        return expert(as64).astype(np.float32)

    policy.reset = expert.reset
    ep = rollout(env, policy, seed=seed)
    env.close()
    return ep.success, ep.steps


def test_pick_strategy_rule():
    st = np.zeros(14)
    st[9] = 0.02
    assert pick_strategy(st) == "A"
    st[9] = 0.08
    assert pick_strategy(st) == "B"
    st[10] = 1.0
    assert pick_strategy(st) == "C"


# lerobot-eval vs the env's own success on the same seeds: tests/test_protocol.py (one lerobot-eval run
# checks flatlab eval and the in-process rollout together).


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

"""FlatLabEnv: spaces, shapes, is_success, gym registration, failure handling, ee actions."""

import gymnasium as gym
import numpy as np
import pytest

import flatlab_lerobot  # noqa: F401
from flatlab_lerobot.env import GYM_ID, FlatLabEnv
from flatlab_lerobot.sim.core import SimulationDiverged


@pytest.fixture(scope="module")
def env():
    e = FlatLabEnv(
        object_id="ref_box", image_size=48, n_points=256, n_object_points=64, episode_length=5, render_size=64
    )
    yield e
    e.close()


def test_reset_and_step_shapes(env):
    obs, info = env.reset(seed=0)
    assert "is_success" in info and info["is_success"] is False
    assert env.observation_space.contains(obs)
    assert obs["agent_pos"].shape == (16,) and obs["environment_state"].shape == (14,)
    assert set(obs["pixels"]) == {"front", "top"} and obs["pixels"]["front"].shape == (48, 48, 3)
    assert obs["pointcloud"].shape == (256, 3) and obs["object_pointcloud"].shape == (64, 3)
    # the scene cloud is cropped to the workspace, the object cloud lies around the object
    lo, hi = env.workspace
    assert np.all(obs["pointcloud"] >= lo - 1e-6) and np.all(obs["pointcloud"] <= hi + 1e-6)
    centre = obs["environment_state"][:3]
    assert np.max(np.linalg.norm(obs["object_pointcloud"][:, :2] - centre[:2], axis=1)) < 0.2
    a = obs["agent_pos"].copy()
    for t in range(5):
        obs, r, term, trunc, info = env.step(a)
        assert "is_success" in info and isinstance(r, float)
        assert env.observation_space.contains(obs)
    assert trunc and not term  # episode_length = 5
    frame = env.render()
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8


def test_seeded_reset_is_deterministic(env):
    o1, i1 = env.reset(seed=7)
    o2, i2 = env.reset(seed=7)
    assert np.array_equal(i1["placement"], i2["placement"])
    for k in ("agent_pos", "environment_state", "pointcloud", "object_pointcloud"):
        assert np.array_equal(o1[k], o2[k]), k
    _, i3 = env.reset(seed=8)
    assert not np.array_equal(i1["placement"], i3["placement"])
    x, y, yaw = i3["placement"]
    assert abs(x) <= 0.05 and abs(y) <= 0.05 and abs(yaw) <= np.deg2rad(30)


def test_skipped_clouds_repeat_the_last_and_change_no_later_step(monkeypatch):
    """``skip_clouds``: the next step renders no cloud and repeats the last ones; every later step's clouds
    (and everything else) are those of an env that rendered at every step -- each step samples its clouds
    with its own generator -- so ``flatlab eval`` may skip them where the policy will not read them."""
    from flatlab_lerobot.sim.cameras import CameraRig

    renders = []  # the current run's scene-cloud renders
    real = CameraRig.scene_points
    monkeypatch.setattr(CameraRig, "scene_points", lambda self, *a, **k: renders.append(1) or real(self, *a, **k))

    def run(skip_at: set[int]) -> tuple[list[dict], int]:
        e = FlatLabEnv(object_id="ref_box", obs_pixels=False, image_size=32, n_points=128, n_object_points=32,
                       episode_length=6)  # fmt: skip
        renders.clear()
        obs = [e.reset(seed=3)[0]]
        a = obs[0]["agent_pos"].copy()
        a[2] += 0.3  # the arm moves: every step's cloud differs
        for t in range(5):
            if t in skip_at:
                e.skip_clouds()
            obs.append(e.step(a)[0])
        e.close()
        return obs, len(renders)

    every, n_every = run(set())
    skipped, n_skipped = run({1, 2})
    assert n_every == 6 and n_skipped == 4
    for t, (o1, o2) in enumerate(zip(every, skipped)):
        for k in ("agent_pos", "environment_state", "pointcloud", "object_pointcloud"):
            if k.endswith("pointcloud") and t in (2, 3):  # stepped after a skip: the clouds of step 1
                assert np.array_equal(o2[k], every[1][k]) and not np.array_equal(o2[k], o1[k]), (t, k)
            else:
                assert np.array_equal(o1[k], o2[k]), (t, k)


def test_divergence_ends_episode_as_failure(env, monkeypatch):
    obs, _ = env.reset(seed=0)

    def boom(_):
        raise SimulationDiverged("test")

    monkeypatch.setattr(env.sim, "step", boom)
    obs2, _, term, trunc, info = env.step(obs["agent_pos"])
    assert term and not trunc and not info["is_success"] and "diverged" in info["failure_reason"]
    assert env.observation_space.contains(obs2)


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_gym_make_and_check_env():
    from gymnasium.utils.env_checker import check_env

    e = gym.make(
        GYM_ID,
        object_id="ref_book",
        image_size=32,
        n_points=64,
        n_object_points=16,
        render_size=32,
        max_episode_steps=3,
    )
    check_env(e.unwrapped, skip_render_check=False)
    obs, info = e.reset(seed=1)
    done = False
    while not done:
        obs, _, term, trunc, info = e.step(obs["agent_pos"])
        done = term or trunc
    assert trunc and "is_success" in info
    e.close()


def test_ee_mode_and_object_switch():
    e = FlatLabEnv(object_id="ref_book", action_mode="ee", obs_pixels=False, obs_pointcloud=False)
    obs, _ = e.reset(seed=0)
    assert e.action_space.shape == (14,) and "pixels" not in obs
    from scipy.spatial.transform import Rotation

    act = []
    for arm in ("left", "right"):
        p, R = e.sim.tcp_pose(arm)
        act.append(np.r_[p + [0, 0, 0.03], Rotation.from_matrix(R).as_rotvec(), 0.08])
    for _ in range(5):
        obs, *_ = e.step(np.concatenate(act))
    for arm, a in zip(("left", "right"), act):
        assert np.linalg.norm(e.sim.tcp_pose(arm)[0] - a[:3]) < 0.01
    obs, info = e.reset(seed=0, options={"object_id": "ref_box"})
    assert e.object_id == "ref_box" and info["object_id"] == "ref_box"
    assert obs["environment_state"][9] == pytest.approx(0.08)
    e.close()


@pytest.mark.parametrize("task_id", sorted(__import__("flatlab_lerobot.tasks", fromlist=["TASKS"]).TASKS))
def test_every_task_runs_in_the_env(task_id):
    """``--env.task=<id>`` selects the task's predicate; reset/step give is_success and the description."""
    from flatlab_lerobot.env import FlatLabEnv
    from flatlab_lerobot.tasks import TASKS

    obj = "ref_towel" if TASKS[task_id].material == "deformable" else "ref_box"
    env = FlatLabEnv(object_id=obj, task=task_id, image_size=32, n_points=64, n_object_points=16)
    obs, info = env.reset(seed=0)
    assert info["is_success"] is False and env.task == task_id and env.task_description
    obs, r, term, trunc, info = env.step(obs["agent_pos"])
    assert "is_success" in info and not info["is_success"]
    env.close()


@pytest.mark.parametrize("limit", [False, True])
def test_joint_speed_limit_reaches_a_far_target_over_several_steps(limit):
    """joint_speed_limit: a joint target commanded 1 rad away is approached at the Panda's rated speed (2.175 rad/s
    for joint 1: 0.2175 rad per 0.1-s step) and reached on the fifth step; the grippers are not limited.  Off: the
    target is taken at once (the benchmark's measurements so far)."""
    from flatlab_lerobot.sim.robot import PANDA_MAX_JOINT_SPEED

    e = FlatLabEnv(object_id="ref_box", obs_pixels=False, obs_pointcloud=False, episode_length=10, joint_speed_limit=limit)
    try:
        obs, _ = e.reset(seed=0)
        a = obs["agent_pos"].copy()
        q0 = e.sim._target.copy()
        a[0] = q0[0] + 1.0  # left joint 1, 1 rad away
        a[7] = 0.0  # left gripper closed at once
        targets = []
        for _ in range(5):
            e.step(a)
            targets.append(e.sim._target.copy())
        step = 2.175 * 0.1
        if limit:
            np.testing.assert_allclose([t[0] - q0[0] for t in targets], [step, 2 * step, 3 * step, 4 * step, 1.0])
            assert e.sim.max_joint_speed[0] == PANDA_MAX_JOINT_SPEED[0] and e.sim.max_joint_speed.shape == (14,)
        else:
            np.testing.assert_allclose([t[0] - q0[0] for t in targets], [1.0] * 5)
            assert e.sim.max_joint_speed is None
        assert targets[0][7] == 0.0  # the gripper's target at once either way
    finally:
        e.close()

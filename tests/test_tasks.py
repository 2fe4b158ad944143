"""Every task of the registry: a scripted case that succeeds and cases that fail.

The success case runs the task's expert strategy on its reference object until the predicate
holds; failures are "no action" (the arms stay home) and, where it tells something, the wrong
strategy / object (e.g. a two-arm lift is not a single-arm pick-up).  Cloth tasks are slow."""

import json

import numpy as np
import pytest

from flatlab_lerobot.rollout import Episode, run_task_episode
from flatlab_lerobot.tasks import TASKS, ResetDistribution, mean_squared_jerk

RIGID = [t for t, s in TASKS.items() if s.material != "deformable"]
CLOTH = [t for t, s in TASKS.items() if s.material == "deformable"]


# The scripted success cases use one fixed placement seed.  The A expert lifts the book in ~70 % of
# placements (README), so the seed is one where it does; the predicates themselves are what is tested.
EXPERT_SEED = 1


def _check_success(task_id, seed=EXPERT_SEED):
    traj = run_task_episode(task_id, strategy="expert", seed=seed)
    m = traj.metrics()
    assert m["success"], (task_id, m)
    spec = TASKS[task_id]
    # it completes during one of the stages the registry names
    assert traj.stages[m["steps_to_completion"] - 1] in spec.expert_stages, (task_id, traj.stages[-1])
    assert m["strategy"] == spec.expert_strategy and m["primitives_executed"] >= 1
    assert m["time_to_completion_s"] == pytest.approx(m["steps_to_completion"] * 0.1)
    assert np.isfinite(m["mean_squared_jerk"])
    json.dumps(m)  # metrics are plain JSON
    return m


@pytest.mark.parametrize("task_id", RIGID)
def test_expert_completes_task(task_id):
    _check_success(task_id)


@pytest.mark.parametrize("task_id", RIGID)
def test_no_action_fails(task_id):
    m = run_task_episode(task_id, strategy=None, seed=0).metrics()
    expected = "not_aloft" if task_id == "grasp" else f"timeout: {task_id}"  # the env's FailureReason
    assert not m["success"] and m["failure_reason"] == expected
    assert m["steps"] == TASKS[task_id].episode_length and m["primitives_executed"] == 0
    assert m["mean_squared_jerk"] == pytest.approx(0.0, abs=1e-6)  # the arms did not move


@pytest.mark.parametrize(
    "task_id,object_id,strategy",
    [
        ("pick_up", "ref_box", "B"),  # lifted, but by two arms
        ("lift_coop", "ref_book", "A"),  # single-arm pick-up is not cooperative
        ("touch_dual", "ref_book", "A"),  # only one arm ever touches
        ("press", "ref_box", "B"),  # sideways squeeze, no downward press
        ("grasp_single", "ref_box", "B"),  # open fingers on one face each, no pinch
        ("slide_to_edge", "ref_box", "B"),  # lifted in place, never pushed to the edge
        ("grasp", "ref_box", "A"),  # wrong strategy for a thick box
    ],
)
def test_wrong_strategy_fails(task_id, object_id, strategy):
    m = run_task_episode(task_id, object_id, strategy, seed=0).metrics()
    assert not m["success"], m


def test_press_and_slide_predicates_need_their_stage():
    # stopping the expert before it reaches the object: no touch, no press, no slide
    for task_id in ("touch", "press", "slide", "slide_to_edge"):
        assert not run_task_episode(task_id, strategy="expert", seed=0, max_steps=15).metrics()["success"]


@pytest.mark.slow
@pytest.mark.parametrize("task_id", CLOTH)
def test_cloth_task_expert_succeeds(task_id):
    _check_success(task_id)


@pytest.mark.parametrize("task_id", CLOTH)
def test_cloth_task_no_action_fails(task_id):
    m = run_task_episode(task_id, strategy=None, seed=0, max_steps=10).metrics()
    assert not m["success"]


def test_cloth_predicates_fail_on_rigid_objects():
    # a flat book never raises a fold, and the box's two-arm squeeze pinches nothing
    assert not run_task_episode("squeeze_edge", "ref_book", "A", seed=0, max_steps=60).metrics()["success"]
    assert not run_task_episode("grasp_edge", "ref_box", "B", seed=0).metrics()["success"]


def test_reset_distribution_matches_the_benchmark_default():
    from flatlab_lerobot.env import FlatLabEnv

    env = FlatLabEnv(object_id="ref_box", obs_pixels=False, obs_pointcloud=False)
    env.reset(seed=3)
    assert ResetDistribution().sample(3) == env.placement  # what the env samples
    env.close()
    x, y, yaw = ResetDistribution(planar=0.0, yaw_deg=0.0).sample(3)
    assert x == y == yaw == 0.0


def test_jerk_metric():
    dt = 0.1
    t = np.arange(20) * dt
    line = np.stack([np.stack([t, 0 * t, 0 * t], -1)] * 2, axis=1)  # constant velocity
    assert mean_squared_jerk(line, dt) == pytest.approx(0.0, abs=1e-9)
    cubic = line.copy()
    cubic[:, 0, 0] = t**3  # d3/dt3 = 6 on one arm of two
    assert mean_squared_jerk(cubic, dt) == pytest.approx(36.0 / 2, rel=1e-6)
    assert np.isnan(mean_squared_jerk(line[:3], dt))


def test_metrics_from_a_recorded_trajectory():
    traj = Episode("ref_book", 0, "A", "touch", dt=0.1, success=True, steps=4)
    for k in range(4):  # the episode ends on the step its predicate first holds
        traj.tcp.append(np.zeros((2, 3)))
        traj.stages.append("touch")
        traj.primitives.append(k // 2)
    m = traj.metrics()
    assert m["success"] and m["steps_to_completion"] == 4 and m["time_to_completion_s"] == pytest.approx(0.4)
    assert m["primitives_executed"] == 2 and m["strategy"] == "A"


# The clear_desk scenario (five objects in one cell) is tested in test_clear_desk.py.

"""The one episode loop: a policy (or the scripted expert) acting in a :class:`~flatlab_lerobot.env.FlatLabEnv`.

:func:`rollout` resets the env, asks the policy for an action at every control step, steps the env
until it terminates or truncates, and returns an :class:`Episode`: success, failure reason (the
env's :class:`~flatlab_lerobot.sim.core.FailureReason` vocabulary), steps, simulated and wall time,
per-step stages / primitive indices / TCP positions, the per-episode metrics and whatever the
``before_step`` / ``after_step`` callbacks returned (frames, samples).

A *policy* here is any callable ``policy(obs) -> action`` with an optional ``reset()``; one that
also sets ``.stage`` / ``.primitive`` (like :class:`ExpertPolicy`) gets them recorded per step, and
one with a ``.strategy`` gets it recorded in the episode.

Users: ``flatlab demo``, the task episodes (:func:`run_task_episode`),
dataset collection (:mod:`flatlab_lerobot.collect.runner`) and the primitive set
(:mod:`flatlab_lerobot.learning.primitive_set`).  Loops that do not use it, and why:
``flatlab eval`` runs lerobot's own ``eval_policy`` (so a trial is exactly a ``lerobot-eval``
episode) and reads the same outcome from the env (``env.failure_reason``, ``env.steps``); the
clear_desk expert (:mod:`flatlab_lerobot.tasks.clear_desk`) plans carries from the simulation itself across five
objects; the speed benchmark times bare physics steps.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from flatlab_lerobot.sim.core import FailureReason, SimulationDiverged
from flatlab_lerobot.sim.robot import ARMS
from flatlab_lerobot.tasks import get_task, mean_squared_jerk


class ExpertPolicy:
    """The scripted expert as a policy: strategy ``strategy`` ("A" | "B" | "C") posed from each
    observation's ``agent_pos`` and ``environment_state``; ``.stage`` / ``.primitive`` name the
    primitive the last action belongs to.  ``options``: :class:`~flatlab_lerobot.strategies.expert.ExpertOptions`
    (None: the default expert)."""

    def __init__(self, strategy: str, cell=None, control_dt: float = 0.1, expert=None, options=None):
        from flatlab_lerobot.strategies import Expert

        self.strategy = strategy
        self.expert = expert or Expert(cell, control_dt, options)
        self.stage, self.primitive = "", -1
        self._obs: dict | None = None
        self._gen = None

    def reset(self) -> None:
        self._gen, self.stage, self.primitive = None, "", -1

    def __call__(self, obs: dict) -> np.ndarray:
        self._obs = obs
        if self._gen is None:
            self._gen = self.expert.episode(
                self.strategy, lambda: (self._obs["agent_pos"], self._obs["environment_state"])
            )
        self.stage, self.primitive, action = next(self._gen)
        return action


class HoldPolicy:
    """No action: the arms hold the posture they had at the first step."""

    strategy = None
    stage, primitive = "none", -1

    def __init__(self):
        self._hold = None

    def reset(self) -> None:
        self._hold = None

    def __call__(self, obs: dict) -> np.ndarray:
        if self._hold is None:
            self._hold = np.asarray(obs["agent_pos"], dtype=float).copy()
        return self._hold


@dataclass
class Step:
    """What the callbacks see: the observation the action was chosen from, the action, the
    primitive it belongs to, and (``after_step`` only) the env's answer (``next_obs``, ``info``)."""

    env: Any
    index: int
    obs: dict
    action: np.ndarray
    stage: str
    primitive: int
    next_obs: dict | None = None
    info: dict = field(default_factory=dict)


@dataclass
class Episode:
    """One episode's record."""

    object_id: str
    seed: int | None
    strategy: str | None
    task: str = "grasp"
    scene: str | None = None  # scene id (None: the default cell)
    success: bool = False
    failure_reason: str = ""  # "" on success, else "<FailureReason>[: detail]"
    steps: int = 0
    sim_time_s: float = 0.0
    wall_s: float = 0.0
    dt: float = 0.1
    placement: tuple[float, float, float] = (0.0, 0.0, 0.0)
    stages: list[str] = field(default_factory=list)  # per step
    primitives: list[int] = field(default_factory=list)  # per step (-1: none)
    tcp: list = field(default_factory=list)  # per step: (2, 3) TCP positions after the step, arms in ARMS order
    frames: list = field(default_factory=list)  # what before_step / after_step returned (None dropped)
    info: dict = field(default_factory=dict)  # the last step's info

    @property
    def failure(self) -> FailureReason | None:
        return FailureReason(self.failure_reason.split(":", 1)[0]) if self.failure_reason else None

    @property
    def stage_sequence(self) -> list[str]:
        """The stages in order, consecutive repeats merged."""
        return [s for i, s in enumerate(self.stages) if i == 0 or self.stages[i - 1] != s]

    def metrics(self) -> dict:
        """Per-episode metrics: success, steps and time to completion (None when it failed), TCP
        smoothness (mean squared jerk up to the end), primitives executed."""
        n = self.steps
        return {
            "task": self.task,
            "object_id": self.object_id,
            "seed": self.seed,
            "strategy": self.strategy,
            "success": self.success,
            "steps_to_completion": n if self.success else None,
            "time_to_completion_s": round(n * self.dt, 3) if self.success else None,
            "steps": n,
            "mean_squared_jerk": mean_squared_jerk(self.tcp[:n], self.dt),
            "primitives_executed": len({p for p in self.primitives[:n] if p >= 0}),
            "failure_reason": self.failure_reason,
            "wall_s": round(self.wall_s, 3),
            "scene": self.scene,
        }


def rollout(
    env,
    policy: Callable[[dict], np.ndarray],
    *,
    seed: int | None = None,
    options: dict | None = None,
    max_steps: int | None = None,
    on_reset: Callable[[Any, dict, dict], None] | None = None,
    before_step: Callable[[Step], Any] | None = None,
    after_step: Callable[[Step], Any] | None = None,
    stop: Callable[[Step], bool] | None = None,
    catch_errors: bool = False,
) -> Episode:
    """Run one episode of ``policy`` in ``env`` (reset with ``seed`` / ``options``) and return its record.

    Ends when the env terminates or truncates, after ``max_steps`` steps (default: the env's
    ``episode_length``), or when ``stop(step)`` (after a step) says so.  ``on_reset(env, obs, info)``
    runs after the reset; ``before_step(step)`` once the action is chosen, before the env steps (the
    env still shows ``step.obs``); ``after_step(step)`` after the step.  Their non-None results are
    kept in ``Episode.frames``.
    ``catch_errors``: an exception of the policy or the env ends the episode as a failure
    (``error: ...``, or ``diverged: ...`` for a divergence while resetting) instead of propagating.
    """
    ep = Episode(env.object_id, seed, getattr(policy, "strategy", None), env.task, env.scene, dt=env.control_dt)
    t0 = time.perf_counter()
    info: dict = {}
    error = ""
    try:
        obs, info = env.reset(seed=seed, options=options)
        ep.placement = tuple(float(v) for v in env.placement)
        if hasattr(policy, "reset"):
            policy.reset()
        if on_reset is not None:
            on_reset(env, obs, info)
        for k in range(env.episode_length if max_steps is None else max_steps):
            action = policy(obs)
            step = Step(env, k, obs, action, getattr(policy, "stage", ""), int(getattr(policy, "primitive", -1)))
            if before_step is not None and (out := before_step(step)) is not None:
                ep.frames.append(out)
            obs, _, terminated, truncated, info = env.step(action)
            step.next_obs, step.info = obs, info
            ep.stages.append(step.stage)
            ep.primitives.append(step.primitive)
            ep.tcp.append(np.stack([env.sim.tcp_pose(a)[0] for a in ARMS]))
            if after_step is not None and (out := after_step(step)) is not None:
                ep.frames.append(out)
            if terminated or truncated or (stop is not None and stop(step)):
                break
    except SimulationDiverged as exc:  # while resetting (settling): the env's step reports its own
        if not catch_errors:
            raise
        error = FailureReason.DIVERGED.text(str(exc))
    except Exception as exc:
        if not catch_errors:
            raise
        error = FailureReason.ERROR.text(f"{type(exc).__name__}: {exc}")
    ep.steps = len(ep.stages)
    ep.success = bool(info.get("is_success", False)) and not error and not env.failure
    if error:
        ep.failure_reason = error
    elif not ep.success:
        ep.failure_reason = env.failure_reason or _shortfall(env)
    if env.sim is not None:
        ep.sim_time_s = float(env.sim.data.time)
    ep.info = info
    ep.wall_s = time.perf_counter() - t0
    return ep


def _shortfall(env) -> str:
    """The failure reason of an episode stopped before the env ended it (max_steps or stop)."""
    if env.task == "grasp":
        return env.sim.grasp_status().shortfall.text()
    return FailureReason.TIMEOUT.text(env.task)


def run_task_episode(
    task_id: str,
    object_id: str | None = None,
    strategy: str | None = "expert",
    seed: int = 0,
    max_steps: int | None = None,
    scene: str | None = None,
) -> Episode:
    """One episode of task ``task_id`` (:data:`flatlab_lerobot.tasks.TASKS`) on ``object_id`` (default:
    the task's reference object), in an env without pixels or clouds.  ``strategy``: "expert" (the
    task's expert strategy), "A"/"B"/"C", or None (no action).  ``scene``: a scene id of
    ``envs/scenes`` (default: the task's reset distribution decides).  Ends at the first step where
    the task's predicate holds, or after ``max_steps`` (default: the task's episode length)."""
    from flatlab_lerobot.env import FlatLabEnv

    task = get_task(task_id)
    object_id = object_id or task.reference_object
    if strategy == "expert":
        strategy = task.expert_strategy
    env = FlatLabEnv(
        object_id=object_id, task=task_id, scene=scene or task.reset.scene(seed), xy_range=task.reset.planar,
        yaw_range_deg=task.reset.yaw_deg, episode_length=max_steps or task.episode_length,
        obs_pixels=False, obs_pointcloud=False,
    )  # fmt: skip
    try:
        policy = HoldPolicy() if strategy is None else ExpertPolicy(strategy, env.cell, env.control_dt)
        return rollout(env, policy, seed=seed)
    finally:
        env.close()

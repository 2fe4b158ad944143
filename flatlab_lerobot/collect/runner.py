"""One expert episode -> a list of LeRobot frames plus an episode record.

Frame ``t`` pairs the observation *before* step ``t`` with the expert's action at step ``t``
(the LeRobot convention).  The episode's outcome (success / failure reason) is only known at
the end, so frames are buffered and labelled afterwards: ``success`` is constant over the
episode, and a failed demo keeps its frames with ``failure_reason`` set.

Determinism: a fresh env and expert are built for every episode, the placement comes from
``numpy.random.default_rng(episode_seed)`` and the env (point-cloud sampling) is reset with the
same seed, so an episode's non-video data depends only on (recipe, episode index) -- not on
which episodes ran before it in the same process (required for crash/resume).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import numpy as np

from flatlab_lerobot.catalog import get_object
from flatlab_lerobot.collect.recipe import Recipe
from flatlab_lerobot.sim.core import FailureReason

STAGE_HOLD = "hold"


@dataclass
class EpisodeResult:
    episode_index: int  # index in the recipe's sequence (seed = recipe.seed + episode_index)
    seed: int
    object_id: str
    strategy: str
    task: str
    placement: tuple[float, float, float]
    success: bool
    failure_reason: str
    frames: list[dict] = field(default_factory=list)
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    stages: list[str] = field(default_factory=list)
    # feature -> (MP4 path, stats) once a worker has encoded the camera streams (video.encode_videos);
    # the frames then no longer hold those arrays.
    videos: dict | None = None
    timing: dict = field(default_factory=dict)  # seconds: build, reset, loop (expert + step + frames), encode
    domain: dict = field(default_factory=dict)  # the episode's Domain.to_json (+ jittered cameras' cam_to_world)

    def record(self) -> dict:
        return {
            "episode_index": self.episode_index,
            "seed": self.seed,
            "object_id": self.object_id,
            "strategy": self.strategy,
            "task": self.task,
            "placement": {"x": self.placement[0], "y": self.placement[1], "yaw_rad": self.placement[2]},
            "success": self.success,
            "failure_reason": self.failure_reason,
            "num_frames": len(self.frames),
            "sim_time_s": round(self.sim_time_s, 3),
            "wall_time_s": round(self.wall_time_s, 3),
            "stages": self.stages,
            "domain": self.domain,
        }


def _cam_to_world(env, cam: str) -> list:
    pos, R = env.rig.extrinsics(env.sim.data, cam)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, pos
    return T.tolist()


def sample_placement(recipe: Recipe, seed: int) -> tuple[float, float, float]:
    from flatlab_lerobot.tasks import ResetDistribution

    r = recipe.randomization
    return ResetDistribution(r.xy_range, r.yaw_range_deg).sample(seed)


@functools.cache
def _catalog_strategy(object_id: str) -> str:
    return get_object(object_id).strategy  # parses the whole catalog: once per process


def strategy_for(recipe: Recipe, object_id: str) -> str:
    return _catalog_strategy(object_id) if recipe.strategy == "auto" else recipe.strategy


def make_env(recipe: Recipe, object_id: str):
    from flatlab_lerobot.env import FlatLabEnv

    need_pc = recipe.has("pointcloud") or recipe.has("object_pointcloud")
    cams = recipe.cameras or (recipe.pointcloud_cameras or ())
    return FlatLabEnv(
        object_id=object_id,
        cameras=cams,
        image_size=recipe.image_size,
        n_points=recipe.n_points,
        n_object_points=recipe.n_object_points,
        pointcloud_cameras=recipe.pointcloud_cameras,
        xy_range=recipe.randomization.xy_range,
        yaw_range_deg=recipe.randomization.yaw_range_deg,
        episode_length=recipe.max_steps,
        control_dt=recipe.control_dt,
        render_size=max(16, recipe.image_size),
        obs_pixels=recipe.has("rgb"),
        obs_pointcloud=need_pc,
    )


def _frame(recipe: Recipe, env, obs: dict, action: np.ndarray, stage: str, stage_index: int) -> dict:
    f: dict = {
        "observation.state": np.asarray(obs["agent_pos"], np.float32),
        "action": np.asarray(action, np.float32),
        "stage_index": np.array([stage_index], np.int64),
        "stage": stage,
    }
    if recipe.has("rgb"):
        for cam in recipe.cameras:
            f[f"observation.images.{cam}"] = obs["pixels"][cam]
    if recipe.has("depth"):
        for cam in recipe.cameras:
            f[f"observation.depth.{cam}"] = env.rig.depth(env.sim.data, cam)[..., None].astype(np.float32)
    if recipe.has("pointcloud"):
        f["observation.pointcloud"] = np.asarray(obs["pointcloud"], np.float32)
    if recipe.has("object_pointcloud"):
        f["observation.object_pointcloud"] = np.asarray(obs["object_pointcloud"], np.float32)
    if recipe.has("ee_pose"):
        f["observation.ee_pose"] = env.sim.ee_pose().astype(np.float32)
    if recipe.has("environment_state"):
        f["observation.environment_state"] = np.asarray(obs["environment_state"], np.float32)
    return f


class EnvCache:
    """The last few envs a process built, by object and the recipe fields ``make_env`` reads.

    Building an env compiles the model and opens a GL context for its renderers (~0.12 s + the
    first render's ~0.15 s at 224 px, about a tenth of a rigid episode's cost).  ``reset`` puts
    everything that varies back (state, seeds, the domain from the nominal model), so an episode
    is the same in a reused env as in a fresh one (tests/test_collect.py compares 1 and 2 workers)."""

    def __init__(self, size: int = 2):
        self.size = size
        self._envs: dict = {}

    @staticmethod
    def _key(recipe: Recipe, object_id: str) -> tuple:
        r = recipe
        return (object_id, r.cameras, r.pointcloud_cameras, r.image_size, r.n_points, r.n_object_points,
                r.randomization.xy_range, r.randomization.yaw_range_deg, r.max_steps, r.control_dt,
                r.has("rgb"), r.has("pointcloud") or r.has("object_pointcloud"))  # fmt: skip

    def get(self, recipe: Recipe, object_id: str):
        key = self._key(recipe, object_id)
        env = self._envs.pop(key, None)
        if env is None:
            env = make_env(recipe, object_id)
        self._envs[key] = env  # most recently used last
        while len(self._envs) > self.size:
            self._envs.pop(next(iter(self._envs))).close()
        return env

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()


def run_episode(recipe: Recipe, episode_index: int, env=None, cache: EnvCache | None = None) -> EpisodeResult:
    """Run the scripted expert for episode ``episode_index`` of ``recipe`` and return its frames.

    Never raises for a failed demo: physics divergence, expert errors and timeouts all end the
    episode with ``success=False`` and a ``failure_reason``.  (An error *before the first frame*
    -- e.g. divergence while settling -- gives an episode with no frames, which the collector
    records as skipped.)  ``env``: an env to reuse (tests); ``cache``: an :class:`EnvCache` to take
    it from (collection workers); by default a fresh one."""
    from flatlab_lerobot.env import TASK_DESCRIPTIONS
    from flatlab_lerobot.rollout import ExpertPolicy, rollout

    seed = recipe.episode_seed(episode_index)
    object_id = recipe.object_for(episode_index)
    strategy = strategy_for(recipe, object_id)
    task = recipe.task or TASK_DESCRIPTIONS.get(strategy, "Lift the flat object off the table.")
    placement = sample_placement(recipe, seed)
    res = EpisodeResult(episode_index, seed, object_id, strategy, task, placement, False, "")
    t0 = time.perf_counter()
    own_env = env is None and cache is None
    t_reset = t_loop = t0
    try:
        if own_env:
            env = make_env(recipe, object_id)
        elif env is None:
            env = cache.get(recipe, object_id)
    except Exception as exc:  # noqa: BLE001 -- a bad env build: an episode with no frames, labelled
        res.failure_reason = FailureReason.ERROR.text(f"{type(exc).__name__}: {exc}")
        res.wall_time_s = time.perf_counter() - t0
        return res
    t_reset = time.perf_counter()
    domain = recipe.randomization.domain(seed, sorted(env.rig.camera_names) if env.rig is not None else ())
    res.domain = domain.to_json()

    def on_reset(env, obs, info):
        nonlocal t_loop
        if env.rig is not None and domain.camera_offsets:  # where the jittered cameras were
            res.domain["cam_to_world"] = {c: _cam_to_world(env, c) for c in sorted(domain.camera_offsets)}
        t_loop = time.perf_counter()

    ep = rollout(
        env, ExpertPolicy(strategy, env.cell, recipe.control_dt, options=recipe.expert), seed=seed,
        options={"placement": placement, "domain": domain}, max_steps=recipe.max_steps, on_reset=on_reset,
        before_step=lambda st: _frame(recipe, st.env, st.obs, st.action, st.stage, st.primitive), catch_errors=True,
    )  # fmt: skip
    t_end = time.perf_counter()
    res.timing = {"build": t_reset - t0, "reset": max(0.0, t_loop - t_reset), "loop": max(0.0, t_end - t_loop)}
    frames = ep.frames
    res.stages = ep.stage_sequence
    res.success, res.failure_reason = ep.success, ep.failure_reason
    res.sim_time_s = ep.sim_time_s
    if own_env:
        env.close()
    for f in frames:
        f["strategy"] = strategy
        f["object_id"] = object_id
        f["success"] = np.array([ep.success], bool)
        f["failure_reason"] = ep.failure_reason
        f["episode_seed"] = np.array([seed], np.int64)
        f["task"] = task
    res.frames = frames
    res.wall_time_s = time.perf_counter() - t0
    return res

"""The ``flatlab`` LeRobot EnvConfig (``--env.type=flatlab``).

Env keys -> policy keys: ``agent_pos`` -> ``observation.state``, ``pixels[cam]`` ->
``observation.images.<cam>``, ``environment_state`` -> ``observation.environment_state``,
``pointcloud`` -> ``observation.pointcloud``, ``object_pointcloud`` -> ``observation.object_pointcloud``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE

from flatlab_lerobot.env import GYM_ID


@EnvConfig.register_subclass("flatlab")
@dataclass
class FlatLabEnvConfig(EnvConfig):
    """FlatLab cell with one object.  ``object_id`` picks the object (catalog id, e.g. ref_book,
    ref_box, ref_towel); ``task`` picks the success predicate: one of ``flatlab_lerobot.tasks.TASKS``
    (``grasp`` = the benchmark's full 2-s hold rule; ``touch``, ``slide``, ``slide_to_edge``, ``press``,
    ``grasp_single``, ``pick_up``, ``touch_dual``, ``lift_coop``, ``squeeze_edge``, ``grasp_edge``), or the
    scenario ``clear_desk`` (five objects in one cell; use ``episode_length=1450``)).
    ``scene``: an ``envs/scenes`` id (room, table size/height/edge/material); None = the default cell."""

    task: str | None = "grasp"
    object_id: str = "ref_book"
    scene: str | None = None
    fps: int = 10
    episode_length: int = 300
    image_size: int = 96
    render_size: int = 256
    cameras: list[str] = field(default_factory=lambda: ["front", "top"])
    pointcloud_cameras: list[str] | None = None
    n_points: int = 1024
    n_object_points: int = 256
    action_mode: str = "joint"  # "joint" (16,) | "ee" (14,)
    xy_range: float = 0.05
    yaw_range_deg: float = 30.0
    obs_pixels: bool = True
    obs_pointcloud: bool = True
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        action_dim = 16 if self.action_mode == "joint" else 14
        s = self.image_size
        feats = {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(action_dim,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(16,)),
            "environment_state": PolicyFeature(type=FeatureType.ENV, shape=(14,)),
        }
        fmap = {ACTION: ACTION, "agent_pos": OBS_STATE, "environment_state": OBS_ENV_STATE}
        if self.obs_pixels:
            for cam in self.cameras:
                key = f"{OBS_IMAGES}.{cam}"
                feats[key] = PolicyFeature(type=FeatureType.VISUAL, shape=(s, s, 3))
                fmap[key] = key
        if self.obs_pointcloud:
            feats["pointcloud"] = PolicyFeature(type=FeatureType.STATE, shape=(self.n_points, 3))
            feats["object_pointcloud"] = PolicyFeature(type=FeatureType.STATE, shape=(self.n_object_points, 3))
            fmap["pointcloud"] = "observation.pointcloud"
            fmap["object_pointcloud"] = "observation.object_pointcloud"
        self.features = feats
        self.features_map = fmap

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        """As the default, but each sub-env is wrapped in lerobot's ``FreezeAfterEpisodeEnd``: a
        sub-env whose episode ended (e.g. on success) stops simulating instead of being auto-reset
        into a discarded extra episode while the rest of the batch finishes."""
        from lerobot.envs.utils import freeze_after_episode_end

        import flatlab_lerobot.env  # noqa: F401  registers the gym id

        gym_id, kwargs, checker = self.gym_id, self.gym_kwargs, self.disable_env_checker

        def _make_one():

            return gym.make(gym_id, disable_env_checker=checker, **kwargs)

        fns = [freeze_after_episode_end(_make_one) for _ in range(n_envs)]
        if use_async_envs and n_envs > 1:
            vec = gym.vector.AsyncVectorEnv(
                fns, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP, context="forkserver"
            )
        else:
            vec = gym.vector.SyncVectorEnv(fns, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
        return {self.type: {0: vec}}

    @property
    def package_name(self) -> str:
        return "lerobot_env_flatlab"

    @property
    def gym_id(self) -> str:
        return GYM_ID

    @property
    def gym_kwargs(self) -> dict:
        return {
            "object_id": self.object_id,
            "task": self.task,
            "scene": self.scene,
            "cameras": tuple(self.cameras),
            "pointcloud_cameras": tuple(self.pointcloud_cameras) if self.pointcloud_cameras else None,
            "image_size": self.image_size,
            "render_size": self.render_size,
            "n_points": self.n_points,
            "n_object_points": self.n_object_points,
            "action_mode": self.action_mode,
            "xy_range": self.xy_range,
            "yaw_range_deg": self.yaw_range_deg,
            "episode_length": self.episode_length,
            "control_dt": 1.0 / self.fps,
            "obs_pixels": self.obs_pixels,
            "obs_pointcloud": self.obs_pointcloud,
            "max_episode_steps": self.episode_length,
        }

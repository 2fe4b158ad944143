"""The ``flatlab`` LeRobot EnvConfig (``--env.type=flatlab``) and the policy/env feature check.

Env keys -> policy keys: ``agent_pos`` -> ``observation.state``, ``pixels[cam]`` ->
``observation.images.<cam>``, ``ee_pose`` -> ``observation.ee_pose``, ``cell`` -> ``observation.cell``,
``environment_state`` -> ``observation.environment_state``, ``pointcloud`` -> ``observation.pointcloud``,
``object_pointcloud`` -> ``observation.object_pointcloud``.

A trained checkpoint's input features must be among the env's, name and shape:
:func:`check_policy_features` says which ``--env.*`` flag fixes a mismatch.  ``flatlab eval`` calls it
before its first trial, and ``lerobot-eval --policy.path=...`` reaches it through
:meth:`FlatLabEnvConfig.create_envs` before any env is built.
"""

from __future__ import annotations

import difflib
import functools
from dataclasses import dataclass, field

import gymnasium as gym
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE

from flatlab_lerobot.catalog import BENCHMARK_SPLITS
from flatlab_lerobot.env import GYM_ID, make_flatlab_env
from flatlab_lerobot.sim.core import EE_POSE_NAMES, ENV_STATE_DIM, STATE_NAMES
from flatlab_lerobot.sim.scene import CALIBRATION_NAMES, default_cameras
from flatlab_lerobot.tasks import DEFAULT_PLANAR, DEFAULT_YAW_DEG

CAMERA_NAMES = tuple(c.name for c in default_cameras(0.0))
ACTION_DIMS = {"joint": 16, "ee": 14}
OBS_EE_POSE, OBS_CELL = "observation.ee_pose", "observation.cell"
OBS_POINTCLOUD, OBS_OBJECT_POINTCLOUD = "observation.pointcloud", "observation.object_pointcloud"


class EnvConfigError(ValueError):
    """A bad ``--env.*`` value: the message names the flag and the valid choices."""


class PolicyEnvMismatch(ValueError):
    """A policy's input/output features that the env does not give; the message names the fix."""


@EnvConfig.register_subclass("flatlab")
@dataclass
class FlatLabEnvConfig(EnvConfig):
    """FlatLab: two Franka Pandas at a table with one flat object (or the clear_desk scenario's five).

    Observations: ``observation.state`` (16: 7 joints + gripper width per arm), ``observation.ee_pose``
    (14: TCP position + quaternion wxyz per arm), ``observation.cell`` (7: table and arm-base
    calibration), ``observation.images.<cam>``, ``observation.pointcloud`` / ``observation.object_pointcloud``
    (world frame) and the privileged ``observation.environment_state`` (14: object pose and size, for
    scripted experts only).  Every field is validated at once: a bad value names its flag."""

    # Success predicate: grasp (the benchmark's 2-s hold rule), touch, slide, slide_to_edge, press,
    # grasp_single, pick_up, touch_dual, lift_coop, squeeze_edge, grasp_edge, or the scenario clear_desk
    # (five objects in one cell; use --env.episode_length=1450).
    task: str | None = "grasp"
    # Catalog object id (envs/objects; `flatlab assets list`), e.g. ref_book, ref_box, ref_towel, book_hardcover.
    object_id: str = "ref_book"
    # Scene id (envs/scenes: table size, height, edge, material, room), e.g. kitchen_counter; unset = the plain cell.
    scene: str | None = None
    # Control rate (Hz): one env step = 1/fps s of simulated time.
    fps: int = 10
    # Steps per episode before truncation (300 = 30 s at 10 Hz).
    episode_length: int = 300
    # Side of the square camera images (px) given as observation.images.<cam>.
    image_size: int = 96
    # Side of the frames rendered for lerobot-eval's videos (px).
    render_size: int = 256
    # Camera of the frames rendered for lerobot-eval's videos: any of front, top, left, right.
    render_camera: str = "front"
    # Cameras given as observation.images.<cam>: any of front, top, left, right.
    cameras: list[str] = field(default_factory=lambda: ["front", "top"])
    # Cameras whose depth makes the point clouds (unset = --env.cameras).
    pointcloud_cameras: list[str] | None = None
    # Points in observation.pointcloud (world frame, cropped to the workspace above the table).
    n_points: int = 1024
    # Points in observation.object_pointcloud (the object's pixels by segmentation).
    n_object_points: int = 256
    # Action space: joint (16: 7 joint targets + gripper width per arm) or ee (14: TCP xyz + rotvec + gripper per arm).
    action_mode: str = "joint"
    # Object placement: uniform offset in [-xy_range, xy_range] m along x and y around the table centre.
    xy_range: float = DEFAULT_PLANAR
    # Object placement: uniform yaw in [-yaw_range_deg, yaw_range_deg] degrees.
    yaw_range_deg: float = DEFAULT_YAW_DEG
    # clear_desk: the catalog split of the desk's five objects: test_beta (the benchmark's desk) or train (a
    # development desk, to choose a policy's switches on without looking at test objects), or test_alpha.
    desk_split: str = "test_beta"
    # Rate-limit the arms' joint targets to the Panda's rated joint speeds (2.175 rad/s joints 1-4, 2.61 joints 5-7):
    # a commanded step beyond them is reached over several steps.  Off: targets are taken as commanded (the benchmark's
    # measurements so far).
    joint_speed_limit: bool = False
    # Render the camera images (false: no observation.images.*; faster for policies that do not look).
    obs_pixels: bool = True
    # Compute the point clouds (false: no observation.pointcloud / observation.object_pointcloud).
    obs_pointcloud: bool = True
    # Env batches evaluated at once (lerobot's multi-task suites; FlatLab has one task per env: keep 1).
    max_parallel_tasks: int = 1
    # Skip gymnasium's env checker when building each env (it runs one extra reset/step).
    disable_env_checker: bool = True
    # (derived from the fields above; not a flag to set)
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    # (derived: env observation key -> policy feature key)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        self.validate()
        s = self.image_size
        feats = {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIMS[self.action_mode],)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(len(STATE_NAMES),)),
            "ee_pose": PolicyFeature(type=FeatureType.STATE, shape=(len(EE_POSE_NAMES),)),
            "cell": PolicyFeature(type=FeatureType.STATE, shape=(len(CALIBRATION_NAMES),)),
            "environment_state": PolicyFeature(type=FeatureType.ENV, shape=(ENV_STATE_DIM,)),
        }
        fmap = {
            ACTION: ACTION, "agent_pos": OBS_STATE, "ee_pose": OBS_EE_POSE, "cell": OBS_CELL,
            "environment_state": OBS_ENV_STATE,
        }  # fmt: skip
        if self.obs_pixels:
            for cam in self.cameras:
                key = f"{OBS_IMAGES}.{cam}"
                feats[key] = PolicyFeature(type=FeatureType.VISUAL, shape=(s, s, 3))
                fmap[key] = key
        if self.obs_pointcloud:
            feats["pointcloud"] = PolicyFeature(type=FeatureType.STATE, shape=(self.n_points, 3))
            feats["object_pointcloud"] = PolicyFeature(type=FeatureType.STATE, shape=(self.n_object_points, 3))
            fmap["pointcloud"] = OBS_POINTCLOUD
            fmap["object_pointcloud"] = OBS_OBJECT_POINTCLOUD
        self.features = feats
        self.features_map = fmap

    def validate(self) -> None:
        """Every field against its valid values (the catalog, the scenes, the task registry): a bad
        value raises :class:`EnvConfigError` naming ``--env.<field>`` at once, not ~9 s later in gym.make."""
        from flatlab_lerobot.catalog import load_objects, load_scenes
        from flatlab_lerobot.tasks import SCENARIOS, TASKS

        _choice("object_id", self.object_id, load_objects())
        _choice("task", self.task or "grasp", [*TASKS, *SCENARIOS])
        if self.scene:
            _choice("scene", self.scene, load_scenes())
        _choice("action_mode", self.action_mode, ACTION_DIMS)
        _choice("render_camera", self.render_camera, CAMERA_NAMES)
        for name in ("cameras", "pointcloud_cameras"):
            cams = getattr(self, name)
            if cams is None:
                continue
            if isinstance(cams, str) or not cams:
                raise EnvConfigError(f"--env.{name}={cams!r}: give a non-empty list, e.g. [front,top]")
            for cam in cams:
                _choice(name, cam, CAMERA_NAMES)
        for name in ("fps", "episode_length", "image_size", "render_size", "n_points", "n_object_points"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise EnvConfigError(f"--env.{name}={v!r}: must be a positive integer")
        if self.image_size < 8 or self.render_size < 8:
            raise EnvConfigError(f"--env.image_size / --env.render_size: at least 8 px (got {self.image_size}, "
                                 f"{self.render_size})")  # fmt: skip
        if not 0.0 <= self.xy_range <= 0.2:
            raise EnvConfigError(f"--env.xy_range={self.xy_range!r}: must be in [0, 0.2] m")
        if not 0.0 <= self.yaw_range_deg <= 180.0:
            raise EnvConfigError(f"--env.yaw_range_deg={self.yaw_range_deg!r}: must be in [0, 180]")
        _choice("desk_split", self.desk_split, BENCHMARK_SPLITS)

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        """As lerobot's default, with two differences.  Each sub-env is wrapped in lerobot's
        ``FreezeAfterEpisodeEnd``: a sub-env whose episode ended (e.g. on success) stops simulating
        instead of being auto-reset into a discarded extra episode while the rest of the batch
        finishes.  The factory is a module-level function (``env.make_flatlab_env``), so
        ``AsyncVectorEnv``'s forkserver workers import the module that registers the gym id.
        Before any env is built, a ``--policy.path`` checkpoint's features are checked against
        the env's (:func:`check_policy_features`)."""
        from lerobot.envs.utils import freeze_after_episode_end

        _check_cli_policy(self)
        make_one = functools.partial(
            make_flatlab_env, disable_env_checker=self.disable_env_checker, **self.gym_kwargs
        )
        fns = [freeze_after_episode_end(make_one) for _ in range(n_envs)]
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
            "render_camera": self.render_camera,
            "n_points": self.n_points,
            "n_object_points": self.n_object_points,
            "action_mode": self.action_mode,
            "xy_range": self.xy_range,
            "yaw_range_deg": self.yaw_range_deg,
            "desk_split": self.desk_split,
            "joint_speed_limit": self.joint_speed_limit,
            "episode_length": self.episode_length,
            "control_dt": 1.0 / self.fps,
            "obs_pixels": self.obs_pixels,
            "obs_pointcloud": self.obs_pointcloud,
            "max_episode_steps": self.episode_length,
        }


def _choice(name: str, value, valid) -> None:
    valid = list(valid)
    if value in valid:
        return
    near = difflib.get_close_matches(str(value), [str(v) for v in valid], n=3)
    hint = f" (did you mean {', '.join(near)}?)" if near else ""
    shown = ", ".join(map(str, valid[:30])) + (f", ... ({len(valid)} in all)" if len(valid) > 30 else "")
    raise EnvConfigError(f"--env.{name}={value!r} is not valid{hint}; valid: {shown}")


# ------------------------------------------------------------------------ policy <-> env features
def _fix(key: str, want: tuple, env_cfg: FlatLabEnvConfig, missing: bool) -> str:
    """The ``--env.*`` flag that makes the env give feature ``key`` with shape ``want`` (or why none can)."""
    none = "no --env flag can fix this"
    if key == ACTION:
        modes = [m for m, d in ACTION_DIMS.items() if (d,) == tuple(want)]
        return f"use --env.action_mode={modes[0]}" if modes else f"{none} (actions are (16,) joint or (14,) ee)"
    if key.startswith(f"{OBS_IMAGES}."):
        cam = key.removeprefix(f"{OBS_IMAGES}.")
        if cam not in CAMERA_NAMES:
            return f"{none}: the env has no camera {cam!r} (cameras: {', '.join(CAMERA_NAMES)})"
        flags = []
        if not env_cfg.obs_pixels:
            flags.append("--env.obs_pixels=true")
        if missing and cam not in env_cfg.cameras:
            flags.append(f"--env.cameras=[{','.join([*env_cfg.cameras, cam])}]")
        if len(want) == 3 and want[1] != want[2]:
            return f"{none}: the env's images are square, the checkpoint's are {want[1]}x{want[2]}"
        if len(want) == 3 and want[1] != env_cfg.image_size:
            flags.append(f"--env.image_size={want[1]}")
        return "use " + " ".join(flags) if flags else none
    if key in (OBS_POINTCLOUD, OBS_OBJECT_POINTCLOUD):
        size_flag = "n_points" if key == OBS_POINTCLOUD else "n_object_points"
        flags = [] if env_cfg.obs_pointcloud else ["--env.obs_pointcloud=true"]
        if len(want) == 2 and want[0] != getattr(env_cfg, size_flag):
            flags.append(f"--env.{size_flag}={want[0]}")
        return "use " + " ".join(flags) if flags else none
    if key.startswith("observation.depth."):
        return f"{none}: the env gives no depth images (train the policy without {key})"
    return f"{none}: the env's {key} has a fixed layout" if not missing else f"{none}: the env never gives {key}"


def policy_feature_problems(
    input_features: dict, output_features: dict, env_cfg: FlatLabEnvConfig, rename_map: dict | None = None
) -> list[str]:
    """One line per policy feature the env does not give with the same shape, each naming the fix.
    ``rename_map``: observation renames applied before the policy (lerobot-eval's ``--rename_map``)."""
    from lerobot.envs.utils import env_to_policy_features

    have = {(rename_map or {}).get(k, k): ft for k, ft in env_to_policy_features(env_cfg).items()}
    out = []
    for key, ft in {**(input_features or {}), **(output_features or {})}.items():
        want = tuple(ft.shape)
        if key not in have:
            out.append(f"{key}: the checkpoint has shape {want}, the env does not give it; {_fix(key, want, env_cfg, True)}")
        elif tuple(have[key].shape) != want:
            out.append(
                f"{key}: the checkpoint has shape {want}, the env gives {tuple(have[key].shape)}; "
                f"{_fix(key, want, env_cfg, False)}"
            )
    return out


def check_policy_features(
    policy_cfg, env_cfg: FlatLabEnvConfig, where: str = "the policy", rename_map: dict | None = None
) -> None:
    """Raise :class:`PolicyEnvMismatch` when ``policy_cfg``'s features are not the env's (name and shape)."""
    problems = policy_feature_problems(policy_cfg.input_features, policy_cfg.output_features, env_cfg, rename_map)
    if problems:
        raise PolicyEnvMismatch(
            f"{where} was trained on features that this --env.type=flatlab configuration does not give:\n  - "
            + "\n  - ".join(problems)
        )


def _check_cli_policy(env_cfg: FlatLabEnvConfig) -> None:
    """Under lerobot-eval / lerobot-train: check the ``--policy.path`` checkpoint (read from the command
    line as lerobot's own EvalPipelineConfig does) before any env is built.  No path: nothing to check
    (a policy made from scratch takes the env's features)."""
    import json
    import sys

    from lerobot.configs import parser
    from lerobot.configs.policies import PreTrainedConfig

    path = parser.get_path_arg("policy")
    if not path:
        return
    cfg = PreTrainedConfig.from_pretrained(
        path, cli_overrides=parser.get_yaml_overrides("policy") + (parser.get_cli_overrides("policy") or [])
    )
    renames = [a.split("=", 1)[1] for a in sys.argv[1:] if a.startswith("--rename_map=")]
    check_policy_features(cfg, env_cfg, where=f"--policy.path={path}", rename_map=json.loads(renames[-1]) if renames else None)

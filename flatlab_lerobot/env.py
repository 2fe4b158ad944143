"""FlatLab as a Gymnasium env: one cell, one flat object, two Pandas, cameras and point clouds.

Observation (a ``Dict``):

* ``agent_pos`` (16,) float32: per arm 7 joint angles (rad) + gripper width (m), left then right.
* ``pixels``: ``Dict`` camera name -> (H, W, 3) uint8 (only when ``obs_pixels``).
* ``pointcloud`` (n_points, 3) float32: world-frame scene cloud from the depth of
  ``pointcloud_cameras``, cropped to the workspace box above the table, sampled to a fixed size.
* ``object_pointcloud`` (n_object_points, 3) float32: the pixels the segmentation assigns to the
  object (rigid geoms / the cloth flex), sampled to a fixed size (zeros when the object is not seen).
  Both clouds are sampled with a generator of their own per step (seeded from the reset's ``np_random``
  and the step index), so the clouds of step k do not depend on which earlier steps rendered theirs:
  :meth:`FlatLabEnv.skip_clouds` lets the next step repeat the last clouds without rendering
  (``flatlab eval`` does, for a policy that says it will not read them) and changes nothing else.
* ``ee_pose`` (14,) float32: per arm the TCP position + quaternion wxyz, world frame (what the
  robot's forward kinematics reports; names ``sim.core.EE_POSE_NAMES``, as the datasets record it).
* ``cell`` (7,) float32: the cell's calibration, constant per scene: table top height, depth, width,
  thickness and the arm bases (``sim.scene.CALIBRATION_NAMES``).  Policies that plan with a
  kinematic model build it from this (``CellConfig.from_calibration``).
* ``environment_state`` (14,) float32: privileged state, names in ``sim.core.ENV_STATE_NAMES``.

Action: ``action_mode="joint"`` (default): (16,) joint targets + gripper width per arm.
``action_mode="ee"``: (14,) per arm [x, y, z, rotvec(3), gripper width] of the TCP in the world
frame, turned into joint targets by the sim's IK.

Reward is sparse (1.0 on the step the success rule is met).  The episode terminates on success
(object lifted >= 5 cm off the table, held >= 2 s with < 1 cm slip) or when the physics diverges;
it is truncated after ``episode_length`` steps.  ``info["is_success"]`` and ``info["steps"]`` (control
steps since the reset) are set on every reset and step; on every terminal step (terminated or
truncated) ``info["failure_reason"]`` says why it failed, in the vocabulary of
:class:`~flatlab_lerobot.sim.core.FailureReason` (``""`` on success).  The same outcome stays readable
after the episode as ``env.steps``, ``env.failure`` and ``env.failure_reason``.

The cell: ``scene`` (an ``envs/scenes`` id, e.g. ``kitchen_counter``: table size, height, edge,
material, room dressing) or ``cell`` (a ``CellConfig``); neither = the plain default cell.

``task="clear_desk"`` (a scenario, ``tasks.SCENARIOS``): every reset draws a desk layout of five
objects in one cell (``options["desk_seed"]`` picks one, else the reset's seed: ``tasks.clear_desk.sample_desk(seed)``,
the layout ``flatlab desk --seeds`` runs); the privileged state and the object cloud
refer to the first object still on the table; set ``episode_length`` to the scenario's (1450).

Domain randomization: ``reset(options={"domain": Domain(...)})`` (or its ``to_json`` dict) sets the
arms' start posture, the object's mass and friction and the camera poses for that episode
(:mod:`flatlab_lerobot.sim.domain`); a reset without one restores the nominal cell.
"""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from flatlab_lerobot.catalog import REFERENCE_OBJECTS, load_objects
from flatlab_lerobot.sim.cameras import CameraRig, crop, sample
from flatlab_lerobot.sim.core import EE_POSE_NAMES, ENV_STATE_DIM, STATE_NAMES, FailureReason, FlatLabSim, SimulationDiverged
from flatlab_lerobot.sim.domain import Domain, apply_domain
from flatlab_lerobot.sim.robot import ARMS, GRIPPER_MAX_WIDTH, PANDA_MAX_JOINT_SPEED
from flatlab_lerobot.sim.scene import CALIBRATION_NAMES, CellConfig
from flatlab_lerobot.tasks import DEFAULT_PLANAR, DEFAULT_YAW_DEG, SCENARIOS, TASKS, ResetDistribution, task_context

GYM_ID = "lerobot_env_flatlab/FlatLab-v0"
TASK_DESCRIPTIONS = {
    "A": "Slide the flat object over the table edge, then pinch the overhang and lift it.",
    "B": "Squeeze the box between both grippers and lift it off the table.",
    "C": "Push the cloth into a fold, pinch the fold and lift the cloth.",
}


class FlatLabEnv(gym.Env):
    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        object_id: str | None = None,
        strategy: str | None = None,
        cameras: tuple[str, ...] | list[str] | str = ("front", "top"),
        image_size: int = 96,
        n_points: int = 1024,
        n_object_points: int = 256,
        pointcloud_cameras: tuple[str, ...] | list[str] | str | None = None,
        action_mode: str = "joint",
        xy_range: float = DEFAULT_PLANAR,
        yaw_range_deg: float = DEFAULT_YAW_DEG,
        episode_length: int = 300,
        control_dt: float = 0.1,
        render_mode: str | None = "rgb_array",
        render_size: int = 256,
        render_camera: str = "front",
        obs_pixels: bool = True,
        obs_pointcloud: bool = True,
        cell: CellConfig | None = None,
        scene: str | None = None,
        task: str | None = None,
        desk_split: str | None = None,
        joint_speed_limit: bool = False,
    ):
        super().__init__()
        if object_id is None:
            if strategy in (None, "", "auto"):
                strategy = "A"
            object_id = REFERENCE_OBJECTS[strategy]
        if action_mode not in ("joint", "ee"):
            raise ValueError(f"action_mode must be 'joint' or 'ee', got {action_mode!r}")
        self.cameras = tuple(cameras.split(",")) if isinstance(cameras, str) else tuple(cameras)
        if pointcloud_cameras is None:
            pointcloud_cameras = self.cameras
        elif isinstance(pointcloud_cameras, str):
            pointcloud_cameras = tuple(pointcloud_cameras.split(","))
        self.pointcloud_cameras = tuple(pointcloud_cameras)
        self.image_size = int(image_size)
        self.n_points, self.n_object_points = int(n_points), int(n_object_points)
        self.action_mode = action_mode
        self.reset_distribution = ResetDistribution(float(xy_range), float(yaw_range_deg))
        self.episode_length = int(episode_length)
        self.control_dt = float(control_dt)
        self.render_mode = render_mode
        self.render_size, self.render_camera = int(render_size), render_camera
        self.obs_pixels, self.obs_pointcloud = bool(obs_pixels), bool(obs_pointcloud)
        self.metadata = {**self.metadata, "render_fps": round(1 / self.control_dt)}
        if scene and cell is not None:
            raise ValueError("give either scene (an envs/scenes id) or cell (a CellConfig), not both")
        self.scene = scene or None  # None: the default cell
        self._cell = CellConfig.from_scene(scene) if scene else cell
        self._objects = load_objects()
        self.sim: FlatLabSim | None = None
        self.rig: CameraRig | None = None
        self._task_override = task
        self.desk_split = desk_split or None  # a scenario's objects: this catalog split (None: the scenario's own)
        self.joint_speed_limit = bool(joint_speed_limit)  # arm joint targets move at most the Panda's rated speeds
        self._build(object_id)
        self._make_spaces()
        self.steps = 0  # control steps since the last reset
        self.failure: FailureReason | None = None  # why the episode failed, once it has ended
        self.failure_detail = ""
        self._last_obs = None
        self._cloud_seed = 0  # drawn per reset: the clouds of step k are sampled with (seed, k)
        self._skip_clouds = False

    # ------------------------------------------------------------------ construction
    def _build(self, object_id: str, layout=None) -> None:
        scenario = SCENARIOS.get(self._task_override or "")
        if scenario is not None:  # several objects in one cell (a desk layout; reset draws one per seed)
            self.layout = layout or scenario.layout(0, self.desk_split)
            object_id = self.layout.items[0].obj.id
        if object_id not in self._objects:
            raise ValueError(f"unknown object {object_id!r}; known: {sorted(self._objects)}")
        if self.rig is not None:
            self.rig.close()
        self.object_id = object_id
        self.obj = self._objects[object_id]
        if scenario is not None:
            from flatlab_lerobot.tasks.clear_desk import make_desk_sim

            self.sim = make_desk_sim(self.layout, self._cell, self.control_dt)
        else:
            self.sim = FlatLabSim(self.obj, self._cell, control_dt=self.control_dt)
        if self.joint_speed_limit:
            self.sim.max_joint_speed = np.tile(PANDA_MAX_JOINT_SPEED, 2)
        self.cell = self.sim.cell
        needed = set(self.cameras) | set(self.pointcloud_cameras) | {self.render_camera}
        self.rig = CameraRig(self.sim.model, self.image_size, self.image_size, sorted(needed))
        task_id = self._task_override or "grasp"
        if task_id not in TASKS and scenario is None:
            raise ValueError(f"unknown task {task_id!r}; known: {sorted(TASKS) + sorted(SCENARIOS)}")
        self.task_spec = scenario or TASKS[task_id]
        self.task = task_id
        self.task_description = (
            TASK_DESCRIPTIONS.get(self.obj.strategy, "Lift the flat object off the table.")
            if task_id == "grasp"
            else self.task_spec.description
        )
        tx, ty = self.cell.table_size
        h = self.cell.table_height
        # Workspace: the table top (plus a margin beyond the usable edge) up to 0.6 m above it.
        self.workspace = (np.array([-tx / 2, -ty / 2, h - 0.005]), np.array([tx / 2 + 0.15, ty / 2, h + 0.6]))

    def _make_spaces(self) -> None:
        s = self.image_size
        obs = {
            "agent_pos": spaces.Box(-np.inf, np.inf, (len(STATE_NAMES),), np.float32),
            "ee_pose": spaces.Box(-np.inf, np.inf, (len(EE_POSE_NAMES),), np.float32),
            "cell": spaces.Box(-np.inf, np.inf, (len(CALIBRATION_NAMES),), np.float32),
            "environment_state": spaces.Box(-np.inf, np.inf, (ENV_STATE_DIM,), np.float32),
        }
        if self.obs_pixels:
            obs["pixels"] = spaces.Dict({c: spaces.Box(0, 255, (s, s, 3), np.uint8) for c in self.cameras})
        if self.obs_pointcloud:
            obs["pointcloud"] = spaces.Box(-np.inf, np.inf, (self.n_points, 3), np.float32)
            obs["object_pointcloud"] = spaces.Box(-np.inf, np.inf, (self.n_object_points, 3), np.float32)
        self.observation_space = spaces.Dict(obs)
        m, ids = self.sim.model, self.sim.ctrl_ids()
        lo, hi = m.actuator_ctrlrange[ids, 0].astype(np.float32), m.actuator_ctrlrange[ids, 1].astype(np.float32)
        if self.action_mode == "joint":
            self.action_space = spaces.Box(lo, hi, (16,), np.float32)
        else:
            arm_lo = np.r_[-1.5, -1.5, 0.0, -np.pi, -np.pi, -np.pi, 0.0].astype(np.float32)
            arm_hi = np.r_[1.5, 1.5, 2.0, np.pi, np.pi, np.pi, GRIPPER_MAX_WIDTH].astype(np.float32)
            self.action_space = spaces.Box(np.r_[arm_lo, arm_lo], np.r_[arm_hi, arm_hi], (14,), np.float32)

    # ------------------------------------------------------------------ observation
    def _observe(self) -> dict:
        sim, rig = self.sim, self.rig
        rig.invalidate()
        obs = {
            "agent_pos": sim.joint_positions().astype(np.float32),
            "ee_pose": sim.ee_pose().astype(np.float32),
            "cell": self.cell.calibration().astype(np.float32),
            "environment_state": sim.environment_state().astype(np.float32),
        }
        if self.obs_pixels:
            obs["pixels"] = {c: rig.rgb(sim.data, c) for c in self.cameras}
        if self.obs_pointcloud and self._skip_clouds and self._last_obs is not None:
            obs["pointcloud"] = self._last_obs["pointcloud"]
            obs["object_pointcloud"] = self._last_obs["object_pointcloud"]
        elif self.obs_pointcloud:
            rng = np.random.default_rng((self._cloud_seed, self.steps))
            pts = crop(rig.scene_points(sim.data, self.pointcloud_cameras), *self.workspace)
            obs["pointcloud"] = sample(pts, self.n_points, rng)
            opts = rig.object_points(sim.data, sim.obj_geoms, sim.flex_id, self.pointcloud_cameras)
            obs["object_pointcloud"] = sample(opts, self.n_object_points, rng)
        self._skip_clouds = False
        return obs

    def skip_clouds(self) -> None:
        """The next step's observation repeats the last ``pointcloud`` / ``object_pointcloud`` instead of
        rendering new ones (one step only; a reset always renders).  For a caller that knows its policy
        will not read them: the clouds of every later step are the same as without the skip (each step
        samples with its own generator), so the episode is unchanged, only faster -- the four 128 px
        depth + segmentation renders of the benchmark's clouds are ~45 ms of a step on 2 CPU cores."""
        self._skip_clouds = True


    def _task_success(self) -> bool:
        """The selected task's predicate (``grasp``: the benchmark's 2-s hold rule).  Once met, the
        episode counts as a success (it terminates on that step)."""
        if self.task in SCENARIOS:  # the privileged state follows the next object still on the table
            from flatlab_lerobot.tasks.clear_desk import advance_target

            advance_target(self.sim)
        self._task_done = self._task_done or bool(self.task_spec.success(self.sim, self._task_ctx))
        return self._task_done

    def _info(self) -> dict:
        st = self.sim.grasp_status()
        info = {
            "is_success": self._task_success(),
            "object_id": self.object_id,
            "clearance": float(st.clearance),
            "held_for": float(st.held_for),
            "holding_arms": ",".join(st.holding_arms),
            "steps": self.steps,
        }
        return info

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        if options.get("object_id") and options["object_id"] != self.object_id:
            self._build(options["object_id"])
            self._make_spaces()
        rng = self.np_random
        x, y, yaw = self.reset_distribution.sample(rng)
        if "placement" in options:  # explicit (x, y, yaw)
            x, y, yaw = (float(v) for v in options["placement"])
        if self.task in SCENARIOS:  # a new desk layout (objects, poses) per reset: options["desk_seed"]'s, else
            # the episode seed's (so `flatlab eval --seed S` trial t runs `flatlab desk`'s desk S + t), else a random one
            desk_seed = options.get("desk_seed", seed if seed is not None else rng.integers(2**31))
            self._build(self.object_id, SCENARIOS[self.task].layout(int(desk_seed), self.desk_split))
            first = self.layout.items[0]
            x, y, yaw = first.x, first.y, first.yaw
        self.placement = (float(x), float(y), float(yaw))
        domain = options.get("domain")
        if isinstance(domain, dict):
            domain = Domain.from_json(domain)
        apply_domain(self.sim, domain)  # None: back to the nominal cell
        self.sim.reset(*self.placement, home_offsets=domain.home_offsets if domain else ())
        self._task_ctx = task_context(self.task_spec, self.sim)
        self._task_done = False
        self.steps = 0
        self.failure, self.failure_detail = None, ""
        self._cloud_seed = int(rng.integers(2**63))  # after the placement's draws: placements stay as they were
        self._skip_clouds = False
        obs = self._observe()
        self._last_obs = obs
        info = self._info()
        info["placement"] = np.array(self.placement)
        return obs, info

    def ee_to_joint(self, action: np.ndarray) -> np.ndarray:
        """(14,) per-arm [pos, rotvec, gripper] -> (16,) joint targets via IK."""
        from scipy.spatial.transform import Rotation

        a = np.asarray(action, dtype=float).reshape(2, 7)
        targets = {arm: (a[i, :3], Rotation.from_rotvec(a[i, 3:6]).as_matrix()) for i, arm in enumerate(ARMS)}
        q = self.sim.solve_ik(targets)
        return np.r_[q[:7], a[0, 6], q[7:], a[1, 6]]

    @property
    def failure_reason(self) -> str:
        """``"<reason>"`` / ``"<reason>: <detail>"`` once the episode failed; ``""`` otherwise."""
        return self.failure.text(self.failure_detail) if self.failure else ""

    def _end(self, failure: FailureReason | None, detail: str = "") -> None:
        self.failure, self.failure_detail = failure, detail

    def step(self, action):
        action = np.asarray(action, dtype=float)
        try:
            target = self.ee_to_joint(action) if self.action_mode == "ee" else action
            self.sim.step(target)
        except SimulationDiverged as e:
            self.steps += 1
            self._end(FailureReason.DIVERGED, str(e))
            info = {"is_success": False, "object_id": self.object_id, "steps": self.steps,
                    "failure_reason": self.failure_reason}  # fmt: skip
            return self._last_obs, 0.0, True, False, info
        self.steps += 1
        obs = self._observe()
        self._last_obs = obs
        info = self._info()
        success = info["is_success"]
        truncated = (not success) and self.steps >= self.episode_length
        if success:
            self._end(None)
        elif truncated:  # which part of the task's rule it missed
            if self.task == "grasp":
                self._end(self.sim.grasp_status().shortfall)
            else:
                self._end(FailureReason.TIMEOUT, self.task)
        if success or truncated:
            info["failure_reason"] = self.failure_reason
        return obs, float(success), bool(success), bool(truncated), info

    def render(self):
        return self.rig.render_rgb(self.sim.data, self.render_camera, self.render_size, self.render_size)

    def close(self):
        if self.rig is not None:
            self.rig.close()
            self.rig = None


def register_gym() -> None:
    if GYM_ID not in gym.registry:
        gym.register(id=GYM_ID, entry_point="flatlab_lerobot.env:FlatLabEnv")


def make_flatlab_env(**kwargs) -> gym.Env:
    """``gym.make(GYM_ID, **kwargs)``, importable by name: a vector env's worker process that
    unpickles it imports this module, which registers the gym id."""
    register_gym()
    return gym.make(GYM_ID, **kwargs)


register_gym()

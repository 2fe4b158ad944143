"""The dual Panda: loading the arm model, attaching two arms to a cell, and differential IK.

The arm itself is data (``envs/robot/panda.xml``, derived from Franka's published DH and
inertial parameters; see that file's header).  This module knows the arm's names, attaches
two copies (``left/`` and ``right/``) to a scene spec, and solves end-effector targets with
mink (differential IK as a QP).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from flatlab_lerobot.constants import BIT_LEFT, BIT_OBJECT, BIT_RIGHT, BIT_TABLE
from flatlab_lerobot.paths import ENVS_DIR

PANDA_XML: Path = ENVS_DIR / "robot" / "panda.xml"
ARMS: tuple[str, str] = ("left", "right")
ARM_JOINTS: tuple[str, ...] = tuple(f"joint{i}" for i in range(1, 8))
FINGER_JOINTS: tuple[str, str] = ("finger_joint1", "finger_joint2")
GRIPPER_MAX_WIDTH = 0.08  # metres between the finger pads, fully open
# A comfortable "ready" pose: elbow up, hand pointing down.
HOME_Q = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785398])
# Rated joint speeds, rad/s (Franka Control Interface, "Robot and interface specifications": joints 1-4 2.175, 5-7
# 2.61).  The model does not enforce them: --env.joint_speed_limit rate-limits the joint targets to them, and
# scripts/joint_speeds.py measures motions against them.
PANDA_MAX_JOINT_SPEED = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])

ARM_BITS = {"left": BIT_LEFT, "right": BIT_RIGHT}


def arm_collision_masks(arm: str) -> tuple[int, int]:
    """(contype, conaffinity) for every geom of ``arm``."""
    other = BIT_RIGHT if arm == "left" else BIT_LEFT
    return ARM_BITS[arm], BIT_TABLE | BIT_OBJECT | other


def attach_arm(spec: mujoco.MjSpec, arm: str, pos, yaw: float) -> None:
    """Attach one Panda (named ``<arm>/...``) to ``spec`` at base position ``pos``, turned by ``yaw``."""
    arm_spec = mujoco.MjSpec.from_file(str(PANDA_XML))
    contype, conaffinity = arm_collision_masks(arm)
    for geom in arm_spec.geoms:
        geom.contype = contype
        geom.conaffinity = conaffinity
    frame = spec.worldbody.add_frame(pos=list(pos), quat=[np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])
    frame.attach_body(arm_spec.body("link0"), f"{arm}/", "")


@dataclass
class ArmIndex:
    """Address book of one arm inside a compiled model."""

    qpos: np.ndarray  # 7 arm joint qpos addresses
    dof: np.ndarray  # 7 arm joint dof addresses
    finger_qpos: np.ndarray  # 2 finger qpos addresses
    ctrl: np.ndarray  # 8 actuator ids (7 joints + gripper)
    tcp_site: int
    geoms: np.ndarray  # every geom of the arm

    @classmethod
    def build(cls, model: mujoco.MjModel, arm: str) -> "ArmIndex":
        def jid(name):
            return model.joint(f"{arm}/{name}").id

        joints = [jid(j) for j in ARM_JOINTS]
        fingers = [jid(j) for j in FINGER_JOINTS]
        ctrl = [model.actuator(f"{arm}/actuator{i}").id for i in range(1, 8)]
        ctrl.append(model.actuator(f"{arm}/gripper").id)
        bodies = [b for b in range(model.nbody) if model.body(b).name.startswith(f"{arm}/")]
        geoms = np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies])
        return cls(
            qpos=np.array([model.jnt_qposadr[j] for j in joints]),
            dof=np.array([model.jnt_dofadr[j] for j in joints]),
            finger_qpos=np.array([model.jnt_qposadr[j] for j in fingers]),
            ctrl=np.array(ctrl),
            tcp_site=model.site(f"{arm}/tcp").id,
            geoms=geoms,
        )


class DualArmIK:
    """Differential IK for both arms on a kinematic copy of the model (mink + daqp).

    ``solve`` returns the 14 arm joint positions that bring each TCP site to its target
    pose, starting from the given joint positions.  Arms without a target hold their posture.
    """

    def __init__(self, model: mujoco.MjModel, arms: dict[str, ArmIndex]):
        import mink

        self._mink = mink
        self.model = model
        self.arms = arms
        self.configuration = mink.Configuration(model)
        self.tasks = {
            arm: mink.FrameTask(f"{arm}/tcp", "site", position_cost=1.0, orientation_cost=0.5, lm_damping=1e-3)
            for arm in arms
        }
        self.posture = mink.PostureTask(model, cost=1e-3)
        self.limits = [mink.ConfigurationLimit(model)]

    def solve(
        self,
        qpos: np.ndarray,
        targets: dict[str, tuple[np.ndarray, np.ndarray]],
        iterations: int = 20,
        tol: float = 1e-4,
    ) -> tuple[np.ndarray, float]:
        """``targets``: arm -> (position (3,), rotation matrix (3,3)).  Returns (new full qpos,
        the largest remaining task error)."""
        mink = self._mink
        q = qpos.copy()
        self.configuration.update(q)
        self.posture.set_target(q)
        tasks = [self.posture]
        for arm, (pos, rot) in targets.items():
            task = self.tasks[arm]
            task.set_target(mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(rot), pos))
            tasks.append(task)
        dt = 0.05
        err = 0.0
        for _ in range(iterations):
            vel = mink.solve_ik(self.configuration, tasks, dt, solver="daqp", damping=1e-4, limits=self.limits)
            self.configuration.integrate_inplace(vel, dt)
            err = max(
                (np.linalg.norm(self.tasks[a].compute_error(self.configuration)) for a in targets),
                default=0.0,
            )
            if err < tol:
                break
        return self.configuration.q.copy(), float(err)


def tcp_rotation(approach, finger_axis) -> np.ndarray:
    """Rotation matrix of a TCP frame whose z points along ``approach`` and whose y (the
    finger slide axis) lies along ``finger_axis`` (made orthogonal to ``approach``)."""
    z = np.asarray(approach, float)
    z = z / np.linalg.norm(z)
    y = np.asarray(finger_axis, float)
    y = y - z * (y @ z)
    y = y / np.linalg.norm(y)
    return np.stack([np.cross(y, z), y, z], axis=1)

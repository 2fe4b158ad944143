"""Reusable action primitives: each is a start -> end gripper pose per arm (+ gripper command).

A primitive is pure data (:class:`Primitive`); :class:`PrimitiveRunner` turns it into a stream
of 16-number joint-target actions: first a joint-space *transit* to the start pose (only when
an arm is not already there), then the primitive itself as a straight Cartesian line with
slerped orientation, IK at every control step.  The gripper width is interpolated over the
primitive.  The same runner serves the scripted expert in-process and the LeRobot scripted
policy (which only sees observations).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


PRIMITIVE_NAMES = ("move", "touch", "press", "slide", "squeeze", "grasp", "lift", "hold", "release")


@dataclass
class ArmMotion:
    """One arm's part of a primitive: TCP start/end poses (pos (3,), rotation (3,3)) and the
    gripper width (m) at the start and the end of the primitive."""

    start: tuple[np.ndarray, np.ndarray]
    end: tuple[np.ndarray, np.ndarray]
    gripper: tuple[float, float]

    @classmethod
    def still(cls, pose, gripper: float) -> "ArmMotion":
        return cls(pose, pose, (gripper, gripper))


@dataclass
class Primitive:
    """A named primitive: per-arm motions executed together over ``duration`` seconds."""

    name: str
    motions: dict[str, ArmMotion]
    duration: float
    transit: float = 1.0  # seconds allowed for the joint-space move to the start pose
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.name not in PRIMITIVE_NAMES:
            raise ValueError(f"unknown primitive {self.name!r}; known: {PRIMITIVE_NAMES}")


def _interp_pose(motion: ArmMotion, s: float):
    p = (1 - s) * motion.start[0] + s * motion.end[0]
    rots = Rotation.from_matrix(np.stack([motion.start[1], motion.end[1]]))
    R = Slerp([0.0, 1.0], rots)([s]).as_matrix()[0]
    return p, R


def joint_action(q14: np.ndarray, grip: dict[str, float]) -> np.ndarray:
    """The (16,) action of 14 arm joints and per-arm gripper widths: left 7 + gripper, right 7 + gripper."""
    return np.r_[q14[:7], grip["left"], q14[7:], grip["right"]]


class Unreachable(RuntimeError):
    """A primitive's start pose that the arm's IK misses by more than the ``reach_tol`` asked of
    :meth:`PrimitiveRunner.actions` (raised before the first action): ``miss`` is the distance per arm (m)."""

    def __init__(self, name: str, miss: dict[str, float]):
        super().__init__(f"{name}: start missed by " + ", ".join(f"{a} {m * 100:.1f} cm" for a, m in miss.items()))
        self.name, self.miss = name, miss


class PrimitiveRunner:
    """Executes primitives as joint targets.  ``ik(targets, seed14) -> q14`` and ``fk(q14) ->
    {arm: (pos, rot)}`` come from a kinematic model of the robot (see ``sim.core``)."""

    def __init__(self, ik, fk, control_dt: float):
        self.ik, self.fk, self.dt = ik, fk, control_dt

    def actions(self, prim: Primitive, q_now: np.ndarray, grip_now: dict[str, float], reach_tol: float | None = None):
        """Yield (stage, action (16,)) until ``prim`` is done.  ``q_now`` is the 14 commanded
        arm joints; ``grip_now`` the commanded gripper width per arm.  ``reach_tol`` (m): raise
        :class:`Unreachable`, before any action, when the transit's IK misses a start pose by more."""
        q = q_now.copy()
        grip = dict(grip_now)
        # 1. joint-space transit to the start pose of every moving arm that is not there yet
        cur = self.fk(q)
        need = {
            a: m.start
            for a, m in prim.motions.items()
            if np.linalg.norm(cur[a][0] - m.start[0]) > 2e-3 or np.linalg.norm(cur[a][1] - m.start[1]) > 1e-2
        }
        if need:
            q_goal = self.ik(need, q, far=True)
            if reach_tol is not None:
                got = self.fk(q_goal)
                miss = {a: float(np.linalg.norm(got[a][0] - p[0])) for a, p in need.items()}
                if max(miss.values()) > reach_tol:
                    raise Unreachable(prim.name, miss)
            n = max(1, int(round(prim.transit / self.dt)))
            for k in range(1, n + 1):
                s = 0.5 - 0.5 * np.cos(np.pi * k / n)  # smooth start and stop
                qk = q + (q_goal - q) * s
                yield "move", joint_action(qk, grip)
            q = q_goal
        # 2. the primitive: Cartesian line, gripper ramp
        n = max(1, int(round(prim.duration / self.dt)))
        for k in range(1, n + 1):
            s = k / n
            targets = {a: _interp_pose(m, s) for a, m in prim.motions.items() if m.start is not m.end}
            if targets:
                q = self.ik(targets, q)
            for a, m in prim.motions.items():
                grip[a] = (1 - s) * m.gripper[0] + s * m.gripper[1]
            yield prim.name, joint_action(q, grip)
        self.q, self.grip = q, grip

"""The scripted expert: its own kinematic model of the two arms (no object), IK with far-goal seeds
and link clearance, and the episode generator that runs a strategy's stages (:data:`STRATEGIES`)."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from flatlab_lerobot.primitives import PrimitiveRunner, joint_action
from flatlab_lerobot.sim.robot import ARMS, ArmIndex, DualArmIK
from flatlab_lerobot.sim.scene import CellConfig, build_model
from flatlab_lerobot.strategies.registry import STRATEGIES
from flatlab_lerobot.strategies.world import World

IK_SEEDS = [
    np.array([0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785398]),  # home: hand down
    np.array([0.0, 0.4, 0.0, -2.0, 0.0, 2.4, 0.785398]),  # reaching low and far, hand down
    np.array([0.8, 0.8, 0.0, -1.6, -1.5, 1.6, 0.0]),  # hand sideways, low
    np.array([-0.8, 0.8, 0.0, -1.6, 1.5, 1.6, 0.0]),
    np.array([0.0, 1.0, 0.0, -1.0, 0.0, 2.0, 0.0]),
]
IK_SEEDS += [s * np.array([-1, 1, -1, 1, -1, 1, -1]) for s in IK_SEEDS]  # mirror images
"""Seed postures for IK of far-away goals (differential IK is local)."""
LINK_CLEARANCE = 0.07  # an arm link's frame must stay this far above the table top (capsule radius + margin, m)
TRANSIT_SWEEP = 0.05  # a transit whose hand strays further than this sideways or below the straight line loses to one that does not (m)


@dataclass(frozen=True)
class ExpertOptions:
    """Choices of the scripted expert that change its demos.  All off is the expert that every committed
    result so far used (oracle G, learning sets, baseline demos).

    ``b_right_half_turn``: strategy B's right hand is posed a half turn about its approach axis (its
    finger axis reversed).  The parallel gripper grips the same either way, but the right wrist (joint 7)
    then stays inside its range: with it off, the right wrist ends at -1.7..-2.7 rad up to an object yaw
    of 10-30 deg and at its +2.897 rad limit beyond, a jump of ~5 rad that joint-space imitation learners
    see as two modes (docs/baselines.md, "the expert's right-wrist branch jump")."""

    b_right_half_turn: bool = False


class Expert:
    """Scripted expert with its own kinematic model of the two arms (no object)."""

    def __init__(self, cell: CellConfig | None = None, control_dt: float = 0.1, options: ExpertOptions | None = None):
        self.cell = cell or CellConfig()
        self.options = options or ExpertOptions()
        self.model = build_model(self.cell, None)
        self.data = mujoco.MjData(self.model)
        self.arms = {a: ArmIndex.build(self.model, a) for a in ARMS}
        self._ik = DualArmIK(self.model, self.arms)
        self.runner = PrimitiveRunner(self.ik, self.fk, control_dt)
        self.control_dt = control_dt

    # kinematics on the 14 arm joints ------------------------------------------------------
    def _set(self, q14):
        for i, a in enumerate(ARMS):
            self.data.qpos[self.arms[a].qpos] = q14[7 * i : 7 * i + 7]

    def fk(self, q14) -> dict:
        self._set(q14)
        mujoco.mj_kinematics(self.model, self.data)
        return {
            a: (self.data.site_xpos[i.tcp_site].copy(), self.data.site_xmat[i.tcp_site].reshape(3, 3).copy())
            for a, i in self.arms.items()
        }

    def ik(self, targets, q14, far: bool = False) -> np.ndarray:
        """Joint targets reaching ``targets``.  ``far``: the goal may be far from ``q14`` (a transit),
        so canned seed postures are tried too.  A reaching solution is *clear* when the moving
        arms' elbow/forearm/wrist stay above the table as far as the goal allows (a goal near the
        table top necessarily brings the wrist down to it).  Among clear solutions whose transit
        keeps the hands within TRANSIT_SWEEP of the straight line, the one nearest to ``q14`` in
        joint space wins (the current posture first: a joint-space transit between far-apart
        branches sweeps the arm through the workspace and knocks objects over); if every clear
        transit strays, the current posture's own solution, else the nearest clear one; else the
        reaching solution whose links stay highest."""
        seeds = [q14]
        if far:
            seeds += [np.r_[s if "left" in targets else q14[:7], s if "right" in targets else q14[7:]] for s in IK_SEEDS]
            lowest_goal = min(float(t[0][2]) for t in targets.values()) - self.cell.table_height
            need = min(0.0, lowest_goal - LINK_CLEARANCE) - 0.01
        best, best_key = None, (3, 0, np.inf)
        for seed in seeds:
            self._set(seed)
            q, err = self._ik.solve(self.data.qpos, targets, iterations=20 if not far else 150)
            if err >= 5e-3:
                key = (2, 0, err)
            elif not far:
                key = (0, 0, 0.0)
            else:
                clear = self._link_clearance(q, targets)
                q_new = np.concatenate([q[self.arms[a].qpos] for a in ARMS])
                if clear < need:
                    key = (1, 0, -clear)
                else:
                    moved = float(np.abs(q_new - q14).max())
                    if self._transit_sweep(q14, q_new, targets) <= TRANSIT_SWEEP:
                        key = (0, 0, moved)
                    else:  # sweeping: the current posture's own solution first, then the nearest
                        key = (0, 1, 0.0) if seed is q14 else (0, 2, moved)
            if key < best_key:
                best, best_key = q, key
            if key[:2] == (0, 0) and seed is q14:
                break
        return np.concatenate([best[self.arms[a].qpos] for a in ARMS])

    def _transit_sweep(self, q_from: np.ndarray, q_to: np.ndarray, targets) -> float:
        """How far the moving hands stray sideways or downward from the straight line between their
        start and goal (m) along the joint-space transit ``q_from`` -> ``q_to`` (the runner's smooth
        profile).  Rising above the line does not count: arching over the table is the safe way round
        (a branch that dipped 17 cm instead of arching 48 cm up knocked a saucer off the table)."""
        start, goal = self.fk(q_from), self.fk(q_to)
        worst = 0.0
        for s in np.linspace(0.0, 1.0, 11)[1:-1]:
            now = self.fk(q_from + (q_to - q_from) * (0.5 - 0.5 * np.cos(np.pi * s)))
            for a in targets:
                a0, d = start[a][0], goal[a][0] - start[a][0]
                t = float(np.clip(np.dot(now[a][0] - a0, d) / max(float(np.dot(d, d)), 1e-12), 0.0, 1.0))
                off = now[a][0] - (a0 + t * d)
                off[2] = min(float(off[2]), 0.0)
                worst = max(worst, float(np.linalg.norm(off)))
        return worst

    def _link_clearance(self, qpos: np.ndarray, targets) -> float:
        """Lowest height of the moving arms' elbow/forearm/wrist bodies above the table top, less a
        capsule radius (m); negative: that link would hit the table."""
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        z = min(
            self.data.xpos[self.model.body(f"{a}/{link}").id][2] for a in targets for link in ("link4", "link5", "link6")
        )
        return float(z - self.cell.table_height - LINK_CLEARANCE)

    # the episode --------------------------------------------------------------------------
    def episode(self, strategy: str, observe):
        """Generator of (stage name, primitive index, action (16,)) for a whole strategy.

        ``observe()`` returns (agent_pos (16,), environment_state (14,)) of the *current* step;
        it is called at the start of every primitive.  After the last primitive the final
        action is repeated forever (the arm holds)."""
        if strategy not in STRATEGIES:
            raise ValueError(f"unknown strategy {strategy!r}; choose from {sorted(STRATEGIES)}")
        agent_pos, _ = observe()
        q = np.r_[agent_pos[0:7], agent_pos[8:15]]
        grip = {"left": float(agent_pos[7]), "right": float(agent_pos[15])}
        action = joint_action(q, grip)
        ctx: dict = {}  # choices that hold for the whole episode (e.g. which arm pushes in A)
        for i, stage in enumerate(STRATEGIES[strategy]):
            _, env_state = observe()
            world = World.from_vector(env_state)
            poses = self.fk(q)
            prim = stage(self, world, poses, grip, ctx)
            for name, action in self.runner.actions(prim, q, grip):
                yield name, i, action
            q, grip = self.runner.q, self.runner.grip
        while True:
            yield "hold", len(STRATEGIES[strategy]) - 1, action




class ExpertCache:
    """One :class:`Expert` per (batch element, cell calibration), for the policies that run the expert's
    kinematics inside ``select_action``: an expert holds IK state, so batch elements never share one,
    and each is built once (building compiles a MuJoCo model) and reused by later episodes of that
    element in the same cell.  ``cell``: ``observation.cell`` (None: the default cell)."""

    def __init__(self, control_dt: float, options: ExpertOptions | None = None):
        self.control_dt = control_dt
        self.options = options
        self._experts: dict = {}

    def get(self, i: int, cell=None) -> Expert:
        key = (i, None if cell is None else tuple(np.round(np.asarray(cell, np.float64), 6)))
        if key not in self._experts:
            cfg = None if key[1] is None else CellConfig.from_calibration(key[1])
            self._experts[key] = Expert(cfg, self.control_dt, self.options)
        return self._experts[key]

"""The simulation core: one cell (two arms + one object), stepping, control, contacts, success.

Control is joint-position targets (7 joints + gripper width per arm, 16 numbers).  Within one
control step the actuator targets move linearly from the previous to the new target, so a
10 Hz policy still produces smooth motion.  End-effector targets are turned into joint targets
by differential IK (:class:`~flatlab_lerobot.sim.robot.DualArmIK`) on a robot-only copy.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from flatlab_lerobot.catalog import ObjectSpec
from flatlab_lerobot.sim.robot import ARMS, GRIPPER_MAX_WIDTH, HOME_Q, ArmIndex, DualArmIK
from flatlab_lerobot.assets import OBJECT_BODY
from flatlab_lerobot.sim.scene import CellConfig, build_model

ACTION_DIM = 16  # per arm: 7 joint targets (rad) + gripper width (m)
LIFT_HEIGHT = 0.05  # success: lowest object point at least this far above the table (m)
HOLD_TIME = 2.0  # success: ... for this long (s)
MAX_SLIP = 0.01  # success: ... moving less than this relative to the holding gripper(s) (m)


class SimulationDiverged(RuntimeError):
    """NaN/Inf state or a MuJoCo warning: the episode's physics cannot be trusted."""


@dataclass
class GraspStatus:
    """What the success rule sees at one instant."""

    clearance: float  # lowest object point above the table top (m)
    table_contact: bool
    holding_arms: tuple[str, ...]  # arms whose fingers touch the object
    slip: float  # object motion relative to the holding hands since the hold began (m)
    held_for: float  # seconds the hold has satisfied every condition
    success: bool


class FlatLabSim:
    """A compiled cell with one object, and everything needed to drive and judge it."""

    def __init__(self, obj: ObjectSpec, cell: CellConfig | None = None, control_dt: float = 0.1):
        self.obj = obj
        self.cell = cell or CellConfig()
        self.model = build_model(self.cell, obj)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.control_dt = control_dt
        self.n_substeps = max(1, int(round(control_dt / m.opt.timestep)))
        self.arms = {arm: ArmIndex.build(m, arm) for arm in ARMS}
        self.table_geom = m.geom("table_top").id
        self.obj_body = m.body(OBJECT_BODY).id
        if obj.deformable:
            self.flex_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_FLEX, "cloth")
            adr, num = m.flex_vertadr[self.flex_id], m.flex_vertnum[self.flex_id]
            self._vert_slice = slice(adr, adr + num)
            d0 = mujoco.MjData(m)
            mujoco.mj_forward(m, d0)  # flex vertex positions need the full position stage
            rest = d0.flexvert_xpos[self._vert_slice][:, :2]
            self._rest_xy = rest - rest.mean(axis=0)  # sheet-frame layout, for the yaw fit
            self.obj_geoms = np.zeros(0, dtype=int)
            self._free_qadr = None
        else:
            self.flex_id = -1
            self.obj_geoms = np.array([g for g in range(m.ngeom) if m.geom_bodyid[g] == self.obj_body])
            self._free_qadr = m.jnt_qposadr[m.joint("object_free").id]
        self.finger_geoms = {
            arm: np.array([g for g in idx.geoms if m.body(m.geom_bodyid[g]).name.endswith("finger")])
            for arm, idx in self.arms.items()
        }
        # Robot-only kinematic model for IK (cloth vertices would make the QP huge).
        self.ik_model = build_model(self.cell, None)
        self.ik_arms = {arm: ArmIndex.build(self.ik_model, arm) for arm in ARMS}
        self.ik = DualArmIK(self.ik_model, self.ik_arms)
        self._ik_q = np.zeros(self.ik_model.nq)
        self._target = np.zeros(ACTION_DIM)
        self._hold_ref: dict | None = None
        self.time_held = 0.0

    # ------------------------------------------------------------------ reset
    def reset(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0, settle: float = 0.3) -> None:
        """Home both arms (grippers open), place the object at (x, y, yaw) on the table, settle."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        for idx in self.arms.values():
            d.qpos[idx.qpos] = HOME_Q
            d.qpos[idx.finger_qpos] = GRIPPER_MAX_WIDTH / 2
        self._target = np.concatenate([np.r_[HOME_Q, GRIPPER_MAX_WIDTH]] * 2)
        d.ctrl[self._ctrl_ids()] = self._target
        c, s = np.cos(yaw / 2), np.sin(yaw / 2)
        if self._free_qadr is not None:
            a = self._free_qadr
            d.qpos[a : a + 3] = [x, y, m.body_pos[self.obj_body][2]]
            d.qpos[a + 3 : a + 7] = [c, 0, 0, s]
        else:
            # Cloth vertices are slide-jointed to the object body: move the body itself.
            m.body_pos[self.obj_body][:2] = [x, y]
            m.body_quat[self.obj_body] = [c, 0, 0, s]
        # Sleeping islands (cloth scenes) would keep the old kinematics of bodies that start asleep:
        # compute the new placement with sleep off, then let things fall asleep again while settling.
        sleep = m.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        m.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        mujoco.mj_forward(m, d)
        m.opt.enableflags |= sleep
        self._hold_ref = None
        self.time_held = 0.0
        self.warning_counts = self._warning_counts()
        for _ in range(int(round(settle / self.control_dt))):
            self.step(self._target)
        self._hold_ref = None
        self.time_held = 0.0

    def _ctrl_ids(self) -> np.ndarray:
        return np.concatenate([self.arms[a].ctrl for a in ARMS])

    # ------------------------------------------------------------------ control
    def step(self, target: np.ndarray) -> None:
        """Advance one control step towards joint/gripper ``target`` (16,)."""
        target = np.asarray(target, dtype=float)
        if target.shape != (ACTION_DIM,):
            raise ValueError(f"action must have shape ({ACTION_DIM},), got {target.shape}")
        if not np.all(np.isfinite(target)):
            raise ValueError("action contains NaN/Inf")
        m, d = self.model, self.data
        ids = self._ctrl_ids()
        lo, hi = m.actuator_ctrlrange[ids, 0], m.actuator_ctrlrange[ids, 1]
        target = np.clip(target, lo, hi)
        start = self._target
        for k in range(1, self.n_substeps + 1):
            d.ctrl[ids] = start + (target - start) * (k / self.n_substeps)
            mujoco.mj_step(m, d)
        self._target = target
        self._check_health()
        self._update_hold()

    def _warning_counts(self) -> np.ndarray:
        return np.array([w.number for w in self.data.warning])

    def _check_health(self) -> None:
        d = self.data
        if not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))):
            raise SimulationDiverged(f"NaN/Inf in the state at t={d.time:.3f}s")
        counts = self._warning_counts()
        new = np.nonzero(counts > self.warning_counts)[0]
        if len(new):
            names = [mujoco.mjtWarning(i).name for i in new]
            raise SimulationDiverged(f"MuJoCo warning(s) {names} at t={d.time:.3f}s")

    # ------------------------------------------------------------------ state
    def joint_positions(self) -> np.ndarray:
        """(16,) measured arm joints + gripper width per arm (the LeRobot ``agent_pos``)."""
        d = self.data
        out = []
        for a in ARMS:
            idx = self.arms[a]
            out.append(np.r_[d.qpos[idx.qpos], d.qpos[idx.finger_qpos].sum()])
        return np.concatenate(out)

    def tcp_pose(self, arm: str) -> tuple[np.ndarray, np.ndarray]:
        s = self.arms[arm].tcp_site
        return self.data.site_xpos[s].copy(), self.data.site_xmat[s].reshape(3, 3).copy()

    def object_points(self) -> np.ndarray:
        """World positions of the object's corners (rigid) or vertices (cloth), (K, 3)."""
        d = self.data
        if self.flex_id >= 0:
            return d.flexvert_xpos[self._vert_slice].copy()
        half = np.array(self.obj.size) / 2
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
        R = d.xmat[self.obj_body].reshape(3, 3)
        return d.xpos[self.obj_body] + corners @ R.T

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(position (3,), quaternion wxyz (4,)).  For cloth: centroid and yaw of the principal axis."""
        d = self.data
        if self.flex_id < 0:
            return d.xpos[self.obj_body].copy(), d.xquat[self.obj_body].copy()
        pts = self.object_points()
        c = pts.mean(axis=0)
        # yaw: best 2-D rotation of the rest layout onto the current vertices (Procrustes)
        H = self._rest_xy.T @ (pts[:, :2] - c[:2])
        yaw = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
        return c, np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])

    def object_extent(self) -> np.ndarray:
        """Current size of the object along its own axes (rigid: the spec; cloth: measured)."""
        if self.flex_id < 0:
            return np.array(self.obj.size, dtype=float)
        pts = self.object_points()
        pos, quat = self.object_pose()
        yaw = 2 * np.arctan2(quat[3], quat[0])
        R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        local = (pts[:, :2] - pos[:2]) @ R
        return np.r_[local.max(0) - local.min(0), pts[:, 2].max() - pts[:, 2].min()]

    def _contact_pairs(self):
        d = self.data
        n = d.ncon
        if n == 0:
            return np.zeros((0, 2), int), np.zeros((0, 2), int)
        return d.contact.geom[:n], d.contact.flex[:n]

    def _is_object(self, geom: np.ndarray, flex: np.ndarray) -> np.ndarray:
        if self.flex_id >= 0:
            return flex == self.flex_id
        return np.isin(geom, self.obj_geoms)

    def object_contacts(self, geoms: np.ndarray) -> bool:
        """Does the object touch any of ``geoms``?"""
        g, f = self._contact_pairs()
        if len(g) == 0:
            return False
        obj = self._is_object(g, f)
        other = np.isin(g, geoms)
        return bool(np.any(obj[:, 0] & other[:, 1]) or np.any(obj[:, 1] & other[:, 0]))

    def holding_arms(self) -> tuple[str, ...]:
        return tuple(a for a in ARMS if self.object_contacts(self.finger_geoms[a]))

    def _object_in_hand(self, arm: str, ref_vertex: int | None) -> np.ndarray:
        hp, hR = self.tcp_pose(arm)
        if self.flex_id >= 0:
            p = self.data.flexvert_xpos[self._vert_slice][ref_vertex]
            return hR.T @ (p - hp)
        # Rigid: object origin and one corner, in the hand frame (catches rotation too).
        pts = np.vstack([self.data.xpos[self.obj_body], self.object_points()[7]])
        return (pts - hp) @ hR

    # ------------------------------------------------------------------ success
    def _update_hold(self) -> None:
        st = self.grasp_status()
        ok = st.clearance >= LIFT_HEIGHT and not st.table_contact and st.holding_arms
        if not ok:
            self._hold_ref, self.time_held = None, 0.0
            return
        if self._hold_ref is None or set(self._hold_ref) != set(st.holding_arms):
            ref = {}
            for a in st.holding_arms:
                vert = None
                if self.flex_id >= 0:
                    hp, _ = self.tcp_pose(a)
                    vert = int(np.argmin(np.linalg.norm(self.object_points() - hp, axis=1)))
                ref[a] = (vert, self._object_in_hand(a, vert))
            self._hold_ref, self.time_held = ref, 0.0
            return
        if st.slip >= MAX_SLIP:
            self._hold_ref, self.time_held = None, 0.0
            return
        self.time_held += self.control_dt

    def _slip(self) -> float:
        if not self._hold_ref:
            return 0.0
        return max(
            float(np.max(np.linalg.norm(self._object_in_hand(a, v) - p0, axis=-1)))
            for a, (v, p0) in self._hold_ref.items()
        )

    def grasp_status(self) -> GraspStatus:
        clearance = float(self.object_points()[:, 2].min() - self.cell.table_height)
        held = self.time_held
        return GraspStatus(
            clearance=clearance,
            table_contact=self.object_contacts(np.array([self.table_geom])),
            holding_arms=self.holding_arms(),
            slip=self._slip(),
            held_for=held,
            success=held >= HOLD_TIME - 1e-9,
        )

    def is_success(self) -> bool:
        return self.time_held >= HOLD_TIME - 1e-9

    def environment_state(self) -> np.ndarray:
        """Privileged state (14,): object pose (pos, quat wxyz), size, deformable flag, table
        height, usable-edge x, object mass.  Names: ``strategies.ENV_STATE_NAMES``."""
        pos, quat = self.object_pose()
        return np.r_[
            pos, quat, self.object_extent(), float(self.obj.deformable),
            self.cell.table_height, self.cell.edge_x, self.obj.mass,
        ].astype(np.float32)  # fmt: skip

    # ------------------------------------------------------------------ IK
    def solve_ik(self, targets: dict[str, tuple[np.ndarray, np.ndarray]], seed: np.ndarray | None = None) -> np.ndarray:
        """Joint targets (14,) = IK of TCP ``targets`` (arm -> (pos, rot)), seeded from the current
        arm joints (or ``seed``, (14,)).  Arms without a target keep the seed."""
        q = self._ik_q
        cur = seed if seed is not None else np.r_[self.joint_positions()[:7], self.joint_positions()[8:15]]
        for i, a in enumerate(ARMS):
            q[self.ik_arms[a].qpos] = cur[7 * i : 7 * i + 7]
        qn, _ = self.ik.solve(q, targets)
        return np.concatenate([qn[self.ik_arms[a].qpos] for a in ARMS])

"""The simulation core: one cell (two arms + one object), stepping, control, contacts, success.

A cell may also hold rigid *clutter* objects (a cluttered desk, :mod:`flatlab_lerobot.tasks.clear_desk`).
Then one of the objects is the *target* (:meth:`FlatLabSim.set_target`): the privileged state,
the object-only point cloud and the success rule's status refer to it, while the 2-s hold rule
is tracked for every object (``FlatLabSim.lifted`` latches per object when it was met).

Control is joint-position targets (7 joints + gripper width per arm, 16 numbers).  Within one
control step the actuator targets move linearly from the previous to the new target, so a
10 Hz policy still produces smooth motion.  End-effector targets are turned into joint targets
by differential IK (:class:`~flatlab_lerobot.sim.robot.DualArmIK`) on a robot-only copy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import mujoco
import numpy as np

from flatlab_lerobot.catalog import ObjectSpec
from flatlab_lerobot.constants import OBJECT_BODY
from flatlab_lerobot.sim.robot import ARM_JOINTS, ARMS, GRIPPER_MAX_WIDTH, HOME_Q, ArmIndex, DualArmIK
from flatlab_lerobot.sim.scene import CellConfig, build_model, clutter_name

ACTION_DIM = 16  # per arm: 7 joint targets (rad) + gripper width (m)

# The observation layout, defined here, where it is produced -------------------------------------
STATE_NAMES: tuple[str, ...] = tuple(f"{arm}_{j}" for arm in ARMS for j in (*ARM_JOINTS, "gripper_width"))
"""Names of the (16,) joint vector: ``joint_positions()`` (env ``agent_pos``, ``observation.state``) and the joint action."""
ENV_STATE_NAMES: tuple[str, ...] = (
    "obj_x", "obj_y", "obj_z", "obj_qw", "obj_qx", "obj_qy", "obj_qz",
    "obj_size_x", "obj_size_y", "obj_size_z", "deformable", "table_height", "table_edge_x", "obj_mass",
)  # fmt: skip
"""Names of the (14,) privileged state, :meth:`FlatLabSim.environment_state` (``observation.environment_state``)."""
ENV_STATE_DIM = len(ENV_STATE_NAMES)
ENV_STATE_INDEX: dict[str, int] = {n: i for i, n in enumerate(ENV_STATE_NAMES)}
"""Index of each name in the privileged state (read it by name, never by a bare number)."""
LIFT_HEIGHT = 0.05  # success: lowest object point at least this far above the table (m)
HOLD_TIME = 2.0  # success: ... for this long (s)
MAX_SLIP = 0.01  # success: ... moving less than this relative to the holding gripper(s) (m)
EE_POSE_NAMES = tuple(f"{arm}_{k}" for arm in ARMS for k in ("x", "y", "z", "qw", "qx", "qy", "qz"))
OFF_TABLE_DROP = 0.10  # an object is off the table once its centre is this far below the table top (m)


class SimulationDiverged(RuntimeError):
    """NaN/Inf state or a MuJoCo warning: the episode's physics cannot be trusted."""


class FailureReason(StrEnum):
    """Why an episode failed: the one vocabulary of every ``failure_reason`` (env ``info``, episode
    records, eval results, datasets).  A failure reason is written ``"<reason>"`` or
    ``"<reason>: <detail>"`` (:meth:`text`); ``""`` means success."""

    DIVERGED = "diverged"  # the physics diverged (NaN/Inf state or a MuJoCo warning); detail: which
    FELL_OFF_TABLE = "fell_off_table"  # out of steps; the object is off the table (floor, bin, falling)
    NOT_ALOFT = "not_aloft"  # out of steps; the object is not >= LIFT_HEIGHT above the table, off it
    NOT_HELD = "not_held"  # out of steps; aloft, but held < HOLD_TIME or it slipped >= MAX_SLIP
    TIMEOUT = "timeout"  # out of steps; a task predicate other than the grasp rule was not met; detail: the task
    ERROR = "error"  # the expert or policy raised (collection keeps the demo); detail: the exception

    def text(self, detail: str = "") -> str:
        return f"{self.value}: {detail}" if detail else self.value


@dataclass
class GraspStatus:
    """What the success rule sees at one instant."""

    clearance: float  # lowest object point above the table top (m)
    table_contact: bool
    holding_arms: tuple[str, ...]  # arms whose fingers touch the object
    slip: float  # object motion relative to the holding hands since the hold began (m)
    held_for: float  # seconds the hold has satisfied every condition
    success: bool
    fallen: bool = False  # the object is off the table (FlatLabSim.off_table)

    @property
    def shortfall(self) -> FailureReason:
        """Which part of the success rule an unsuccessful episode missed."""
        if self.fallen:
            return FailureReason.FELL_OFF_TABLE
        return FailureReason.NOT_ALOFT if self.clearance < LIFT_HEIGHT else FailureReason.NOT_HELD


@dataclass
class SimObject:
    """One object of the cell and where it lives in the compiled model."""

    obj: ObjectSpec
    body: int
    geoms: np.ndarray  # collision + visual geoms of a rigid object (empty for cloth)
    free_qadr: int | None  # qpos address of a rigid object's free joint
    flex_id: int = -1
    vert_slice: slice | None = None  # cloth vertices in ``flexvert_xpos``
    rest_xy: np.ndarray | None = None  # cloth: centred rest layout, for the yaw fit


class FlatLabSim:
    """A compiled cell with one object (plus optional rigid clutter), and everything needed to
    drive and judge it.

    ``clutter``: (ObjectSpec, (x, y, yaw)) pairs: further rigid objects (bodies
    ``clutter<i>/object``, i = 1, 2, ...) placed at those poses by every :meth:`reset` (change
    ``clutter_poses`` to move them); ``objects[0]`` is ``obj``, ``objects[i]`` clutter object i.
    ``drop_bin``: add the bin in front of the usable edge that cleared objects fall into
    (default: when there is clutter)."""

    def __init__(
        self,
        obj: ObjectSpec,
        cell: CellConfig | None = None,
        control_dt: float = 0.1,
        clutter: Sequence[tuple[ObjectSpec, Sequence[float]]] = (),
        drop_bin: bool | None = None,
    ):
        self.cell = cell or CellConfig()
        clutter = [(o, tuple(float(v) for v in pose)) for o, pose in clutter]
        if clutter and obj.deformable:
            raise ValueError(f"object {obj.id!r} is deformable: a cell with clutter holds rigid objects only")
        if any(len(pose) != 3 for _, pose in clutter):
            raise ValueError("every clutter pose must be (x, y, yaw)")
        drop_bin = bool(clutter) if drop_bin is None else drop_bin
        self.model = build_model(self.cell, obj, [o for o, _ in clutter], drop_bin)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.control_dt = control_dt
        self.n_substeps = max(1, int(round(control_dt / m.opt.timestep)))
        # (14,) rad/s per arm joint (left then right), or None: each control step's arm joint targets move at most
        # this far from the last step's (joint_speed_limit; the model itself has no speed limit)
        self.max_joint_speed: np.ndarray | None = None
        self.arms = {arm: ArmIndex.build(m, arm) for arm in ARMS}
        self.table_geom = m.geom("table_top").id
        self.objects = [self._index_object(obj, OBJECT_BODY, "object_free")] + [
            self._index_object(o, clutter_name(i), clutter_name(i, "object_free")) for i, (o, _) in enumerate(clutter, 1)
        ]
        self.clutter_poses = [pose for _, pose in clutter]
        n = len(self.objects)
        self._hold_refs: list[dict | None] = [None] * n  # per object: hold reference (see _update_hold)
        self._time_held = np.zeros(n)
        self.lifted = np.zeros(n, dtype=bool)  # per object: the hold rule was met since the last reset
        self.set_target(0)
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
        # written by sim.domain.apply_domain: the model's nominal values and the mass scale applied now
        self.domain_nominal = None
        self.domain_mass_scale = 1.0

    def _index_object(self, obj: ObjectSpec, body_name: str, joint_name: str) -> SimObject:
        m = self.model
        body = m.body(body_name).id
        if not obj.deformable:
            geoms = np.array([g for g in range(m.ngeom) if m.geom_bodyid[g] == body])
            return SimObject(obj, body, geoms, int(m.jnt_qposadr[m.joint(joint_name).id]))
        flex_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_FLEX, "cloth")
        adr, num = m.flex_vertadr[flex_id], m.flex_vertnum[flex_id]
        vs = slice(adr, adr + num)
        d0 = mujoco.MjData(m)
        mujoco.mj_forward(m, d0)  # flex vertex positions need the full position stage
        rest = d0.flexvert_xpos[vs][:, :2]
        # sheet-frame layout, for the yaw fit
        return SimObject(obj, body, np.zeros(0, dtype=int), None, flex_id, vs, rest - rest.mean(axis=0))

    def set_target(self, index: int) -> None:
        """Make ``objects[index]`` the target: the object that ``obj``, ``object_pose``,
        ``environment_state``, ``grasp_status``, ``is_success`` ... refer to."""
        if not 0 <= index < len(self.objects):
            raise IndexError(f"object index {index} out of range: the cell holds {len(self.objects)} objects")
        o = self.objects[index]
        self.target_index = index
        self.obj, self.obj_body, self.obj_geoms, self._free_qadr = o.obj, o.body, o.geoms, o.free_qadr
        self.flex_id, self._vert_slice, self._rest_xy = o.flex_id, o.vert_slice, o.rest_xy

    def _obj(self, index: int | None) -> SimObject:
        return self.objects[self.target_index if index is None else index]

    @property
    def time_held(self) -> float:
        """Seconds the target has satisfied the hold rule without interruption."""
        return float(self._time_held[self.target_index])

    def _clear_holds(self) -> None:
        self._hold_refs = [None] * len(self.objects)
        self._time_held[:] = 0.0

    # ------------------------------------------------------------------ reset
    def reset(
        self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0, settle: float = 0.3, home_offsets: Sequence[float] = ()
    ) -> None:
        """Home both arms (grippers open), place the object at (x, y, yaw) on the table and the
        clutter at ``clutter_poses``, settle.  The target becomes ``objects[0]``.  ``home_offsets``
        (14,) rad: the arms start (and hold) that far from home, within their joint limits."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        offsets = np.zeros(14) if len(home_offsets) == 0 else np.asarray(home_offsets, float).reshape(14)
        homes = []
        for i, idx in enumerate(self.arms.values()):
            lo, hi = m.actuator_ctrlrange[idx.ctrl[:7], 0], m.actuator_ctrlrange[idx.ctrl[:7], 1]
            homes.append(np.clip(HOME_Q + offsets[7 * i : 7 * i + 7], lo, hi))
            d.qpos[idx.qpos] = homes[-1]
            d.qpos[idx.finger_qpos] = GRIPPER_MAX_WIDTH / 2
        self._target = np.concatenate([np.r_[q, GRIPPER_MAX_WIDTH] for q in homes])
        d.ctrl[self.ctrl_ids()] = self._target
        self.set_target(0)
        for o, (px, py, pyaw) in zip(self.objects, [(x, y, yaw), *self.clutter_poses]):
            c, s = np.cos(pyaw / 2), np.sin(pyaw / 2)
            if o.free_qadr is not None:
                a = o.free_qadr
                d.qpos[a : a + 3] = [px, py, m.body_pos[o.body][2]]
                d.qpos[a + 3 : a + 7] = [c, 0, 0, s]
            else:
                # Cloth vertices are slide-jointed to the object body: move the body itself.
                m.body_pos[o.body][:2] = [px, py]
                m.body_quat[o.body] = [c, 0, 0, s]
        # Sleeping islands (cloth scenes) would keep the old kinematics of bodies that start asleep:
        # compute the new placement with sleep off, then let things fall asleep again while settling.
        sleep = m.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        m.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        mujoco.mj_forward(m, d)
        m.opt.enableflags |= sleep
        self._clear_holds()
        self.warning_counts = self._warning_counts()
        for _ in range(int(round(settle / self.control_dt))):
            self.step(self._target)
        self._clear_holds()
        self.lifted[:] = False

    def ctrl_ids(self) -> np.ndarray:
        """Actuator ids of the 16 controls, in action order (left arm + gripper, right arm + gripper)."""
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
        ids = self.ctrl_ids()
        lo, hi = m.actuator_ctrlrange[ids, 0], m.actuator_ctrlrange[ids, 1]
        target = np.clip(target, lo, hi)
        start = self._target
        if self.max_joint_speed is not None:  # the arms' joint targets rate-limited, the grippers not
            arm = np.r_[0:7, 8:15]
            reach = self.max_joint_speed * self.control_dt
            target[arm] = start[arm] + np.clip(target[arm] - start[arm], -reach, reach)
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

    def ee_pose(self) -> np.ndarray:
        """(14,) per arm (left, right): TCP position (3) + unit quaternion wxyz (4), world frame,
        w >= 0 (one hemisphere, so a stream of poses has no sign flips).  Names: ``EE_POSE_NAMES``."""
        out = []
        for arm in ARMS:
            pos, R = self.tcp_pose(arm)
            q = np.zeros(4)
            mujoco.mju_mat2Quat(q, R.reshape(-1))
            out.append(np.r_[pos, -q if q[0] < 0 else q])
        return np.concatenate(out)

    def object_points(self, index: int | None = None) -> np.ndarray:
        """World positions of the object's corners (rigid) or vertices (cloth), (K, 3).
        ``index``: which of ``objects`` (default: the target); so for the other methods."""
        d, o = self.data, self._obj(index)
        if o.flex_id >= 0:
            return d.flexvert_xpos[o.vert_slice].copy()
        half = np.array(o.obj.size) / 2
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
        R = d.xmat[o.body].reshape(3, 3)
        return d.xpos[o.body] + corners @ R.T

    def object_pose(self, index: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(position (3,), quaternion wxyz (4,)).  For cloth: centroid and yaw of the principal axis."""
        d, o = self.data, self._obj(index)
        if o.flex_id < 0:
            return d.xpos[o.body].copy(), d.xquat[o.body].copy()
        pts = self.object_points(index)
        c = pts.mean(axis=0)
        # yaw: best 2-D rotation of the rest layout onto the current vertices (Procrustes)
        H = o.rest_xy.T @ (pts[:, :2] - c[:2])
        yaw = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
        return c, np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])

    def object_extent(self, index: int | None = None) -> np.ndarray:
        """Current size of the object along its own axes (rigid: the spec; cloth: measured)."""
        o = self._obj(index)
        if o.flex_id < 0:
            return np.array(o.obj.size, dtype=float)
        pts = self.object_points(index)
        pos, quat = self.object_pose(index)
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

    def is_object(self, geom: np.ndarray, flex: np.ndarray, index: int | None = None) -> np.ndarray:
        """Per (geom id, flex id) pair of a contact side: is it the target (or ``objects[index]``)?"""
        o = self._obj(index)
        if o.flex_id >= 0:
            return flex == o.flex_id
        return np.isin(geom, o.geoms)

    def object_contacts(self, geoms: np.ndarray, index: int | None = None) -> bool:
        """Does the object touch any of ``geoms``?"""
        g, f = self._contact_pairs()
        if len(g) == 0:
            return False
        obj = self.is_object(g, f, index)
        other = np.isin(g, geoms)
        return bool(np.any(obj[:, 0] & other[:, 1]) or np.any(obj[:, 1] & other[:, 0]))

    def holding_arms(self, index: int | None = None) -> tuple[str, ...]:
        return tuple(a for a in ARMS if self.object_contacts(self.finger_geoms[a], index))

    def _object_in_hand(self, arm: str, ref_vertex: int | None, index: int | None = None) -> np.ndarray:
        hp, hR = self.tcp_pose(arm)
        o = self._obj(index)
        if o.flex_id >= 0:
            p = self.data.flexvert_xpos[o.vert_slice][ref_vertex]
            return hR.T @ (p - hp)
        # Rigid: object origin and one corner, in the hand frame (catches rotation too).
        pts = np.vstack([self.data.xpos[o.body], self.object_points(index)[7]])
        return (pts - hp) @ hR

    # ------------------------------------------------------------------ success
    def _update_hold(self) -> None:
        for i in range(len(self.objects)):
            self._update_hold_of(i)

    def _update_hold_of(self, i: int) -> None:
        """Advance object ``i``'s hold timer (the success rule) by one control step."""
        holding = self.holding_arms(i)
        if not holding:  # cheapest test first: most objects are not in a hand
            self._hold_refs[i], self._time_held[i] = None, 0.0
            return
        clearance = float(self.object_points(i)[:, 2].min() - self.cell.table_height)
        if clearance < LIFT_HEIGHT or self.object_contacts(np.array([self.table_geom]), i):
            self._hold_refs[i], self._time_held[i] = None, 0.0
            return
        ref0 = self._hold_refs[i]
        if ref0 is None or set(ref0) != set(holding):
            ref = {}
            for a in holding:
                vert = None
                if self._obj(i).flex_id >= 0:
                    hp, _ = self.tcp_pose(a)
                    vert = int(np.argmin(np.linalg.norm(self.object_points(i) - hp, axis=1)))
                ref[a] = (vert, self._object_in_hand(a, vert, i))
            self._hold_refs[i], self._time_held[i] = ref, 0.0
            return
        if self._slip(i) >= MAX_SLIP:
            self._hold_refs[i], self._time_held[i] = None, 0.0
            return
        self._time_held[i] += self.control_dt
        if self._time_held[i] >= HOLD_TIME - 1e-9:
            self.lifted[i] = True

    def _slip(self, index: int | None = None) -> float:
        i = self.target_index if index is None else index
        if not self._hold_refs[i]:
            return 0.0
        return max(
            float(np.max(np.linalg.norm(self._object_in_hand(a, v, i) - p0, axis=-1)))
            for a, (v, p0) in self._hold_refs[i].items()
        )

    def grasp_status(self, index: int | None = None) -> GraspStatus:
        i = self.target_index if index is None else index
        clearance = float(self.object_points(i)[:, 2].min() - self.cell.table_height)
        held = float(self._time_held[i])
        return GraspStatus(
            clearance=clearance,
            table_contact=self.object_contacts(np.array([self.table_geom]), i),
            holding_arms=self.holding_arms(i),
            slip=self._slip(i),
            held_for=held,
            success=held >= HOLD_TIME - 1e-9,
            fallen=self.off_table(i),
        )

    def off_table(self, index: int | None = None) -> bool:
        """The object (or ``objects[index]``) no longer lies on or above the table: its centre is
        OFF_TABLE_DROP below the top (on the floor, in the drop bin, or falling)."""
        return bool(self.object_pose(index)[0][2] < self.cell.table_height - OFF_TABLE_DROP)

    def is_success(self, index: int | None = None) -> bool:
        """The success rule holds now for the target (or ``objects[index]``)."""
        i = self.target_index if index is None else index
        return bool(self._time_held[i] >= HOLD_TIME - 1e-9)

    def environment_state(self) -> np.ndarray:
        """Privileged state (14,): object pose (pos, quat wxyz), size, deformable flag, table
        height, usable-edge x, object mass, in the order of :data:`ENV_STATE_NAMES`."""
        pos, quat = self.object_pose()
        return np.r_[  # ENV_STATE_NAMES order
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

"""Strategies A / B / C as sequences of primitives, and the scripted expert that poses them.

The expert only reads *privileged state* (``environment_state``: object pose, size, material,
table height and edge) plus the robot's joints, so the same code runs in-process
(``flatlab demo``) and as a LeRobot policy (``flatlab_scripted``).  Each stage is a function
``stage(expert, world) -> Primitive`` evaluated when the stage starts, on the state at that
moment: after the slide of strategy A, the grasp is aimed at where the book really ended up.

A: press the object and slide it until it overhangs the usable edge; grasp the overhang from
   the side (fingers above and below it); lift.
B: two arms touch opposite sides, squeeze, lift together.
C: two open grippers, leaning outward, press the sheet and slide towards each other to raise a
   fold; both let go (the left one steps off the fold, rises, then moves away), the right one straddles
   the fold at the sheet's current centre, pinches it and lifts.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from flatlab_lerobot.primitives import ArmMotion, Primitive, PrimitiveRunner, joint_action
from flatlab_lerobot.sim.robot import ARMS, GRIPPER_MAX_WIDTH, ArmIndex, DualArmIK, tcp_rotation
from flatlab_lerobot.sim.core import ENV_STATE_INDEX
from flatlab_lerobot.sim.scene import CellConfig, build_model

DOWN = np.array([0.0, 0.0, -1.0])
FINGER_TIP_BELOW_TCP = 0.007  # finger tips sit this far beyond the TCP along the approach (m)
FINGER_HALF_WIDTH = 0.01  # half thickness of a finger along the hand x axis (m)


@dataclass
class World:
    """The expert's view of the scene, parsed from ``environment_state``."""

    pos: np.ndarray
    yaw: float
    size: np.ndarray
    deformable: bool
    table_height: float
    edge_x: float

    @classmethod
    def from_vector(cls, v) -> "World":
        """From the privileged state (:data:`~flatlab_lerobot.sim.core.ENV_STATE_NAMES`)."""
        v = np.asarray(v, dtype=float)
        i = ENV_STATE_INDEX
        return cls(
            v[[i["obj_x"], i["obj_y"], i["obj_z"]]], float(2 * np.arctan2(v[i["obj_qz"]], v[i["obj_qw"]])),
            v[[i["obj_size_x"], i["obj_size_y"], i["obj_size_z"]]], bool(v[i["deformable"]] > 0.5),
            float(v[i["table_height"]]), float(v[i["table_edge_x"]]),
        )  # fmt: skip

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([c, s, 0.0]), np.array([-s, c, 0.0])

    @property
    def round(self) -> bool:
        """A rigid object with a square footprint (disks, plates, round clocks -- or a square): its
        yaw says nothing useful, so footprint queries treat it as a disk of that diameter."""
        return not self.deformable and abs(self.size[0] - self.size[1]) < 1e-4

    def max_x(self) -> float:
        """Largest x of the footprint (m)."""
        if self.round:
            return float(self.pos[0] + self.size[0] / 2)
        return float(self.corners_xy()[:, 0].max())

    def length_x(self) -> float:
        """Extent of the footprint along world x (m)."""
        if self.round:
            return float(self.size[0])
        c = self.corners_xy()[:, 0]
        return float(c.max() - c.min())

    def front_at(self, y: float) -> float:
        """x where the footprint's front (+x) boundary crosses the line at ``y``."""
        if self.round:
            r = self.size[0] / 2
            return float(self.pos[0] + np.sqrt(max(r * r - (y - self.pos[1]) ** 2, 0.0)))
        hits = _polygon_hits(self.corners_xy(), 1, y)
        return max(hits) if hits else self.max_x()

    def corners_xy(self) -> np.ndarray:
        ex, ey = self.axes()
        hx, hy = self.size[0] / 2, self.size[1] / 2
        return np.array([self.pos + sx * hx * ex + sy * hy * ey for sx in (-1, 1) for sy in (-1, 1)])[:, :2]

    def squeeze_axis(self) -> tuple[np.ndarray, float]:
        """The object's horizontal axis closest to world y (pointing to +y), and the half extent along it."""
        ex, ey = self.axes()
        if abs(ex[1]) > abs(ey[1]):
            u, half = ex, self.size[0] / 2
        else:
            u, half = ey, self.size[1] / 2
        return (u if u[1] >= 0 else -u), float(half)


def _p(*xyz) -> np.ndarray:
    return np.array(xyz, dtype=float)


def _rel(pose, dp):
    return (pose[0] + np.asarray(dp, float), pose[1])


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


class Expert:
    """Scripted expert with its own kinematic model of the two arms (no object)."""

    def __init__(self, cell: CellConfig | None = None, control_dt: float = 0.1):
        self.cell = cell or CellConfig()
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


# ---------------------------------------------------------------------------- strategy A
A_OVERHANG = 0.085  # how far the object is pushed past the edge (m) ...
A_OVERHANG_FRAC = 0.4  # ... but at most this share of its length along x
A_APPROACH_YAW = 35.0  # the hand approaches the overhang from the front, turned this much to its side (deg)
A_INSET = 0.04  # the pinch point lies this far inside the object's front boundary (m) ...
A_MIN_BEYOND_EDGE = 0.02  # ... and at least this far beyond the table edge, so the fingers clear it (m)
A_OPEN = 0.06  # gripper opening while approaching the overhang (m)
A_APPROACH_LEN = 0.12  # the horizontal approach starts this far out, so the descent clears the object (m)
A_PRESS_DEPTH = 0.001  # press target below the object top (m): the arm is stiff
A_SLIDE_GAIN = 1.3  # the object lags the finger: slide this many times the missing distance ...
A_SLIDE_EXTRA = 0.05  # ... but at most this much further (m)
A_PASSES = 3  # push passes at most; a pass is skipped once the overhang is within 1 cm of the target
A_PRESS_OPEN = 0.0  # press with closed fingers (open ones were measured worse: 0/10)


def _a_arm(world: World, ctx: dict) -> str:
    """The arm that pushes: the one on the object's side, chosen once per episode."""
    return ctx.setdefault("arm", "right" if world.pos[1] <= 0 else "left")


def _a_grasp_arm(world: World, ctx: dict) -> str:
    """The arm that grasps: the one on the side where the pushes left the object (a push can
    drift it sideways by 10-20 cm), chosen once, when the grasp begins."""
    return ctx.setdefault("grasp_arm", "right" if world.pos[1] <= 0 else "left")


def _a_press_pose(world: World):
    top = world.table_height + world.size[2]
    p = world.pos.copy()
    p[0] -= 0.02
    p[2] = top + FINGER_TIP_BELOW_TCP - A_PRESS_DEPTH
    return p, tcp_rotation(DOWN, [0.0, 1.0, 0.0])


def _a_overhang_target(w: World) -> float:
    """How far the object should stick out past the edge (m): A_OVERHANG, but at most
    A_OVERHANG_FRAC of its length along x, so a small object keeps its centre of mass on the table."""
    return min(A_OVERHANG, A_OVERHANG_FRAC * w.length_x())


def _a_overhang_missing(w: World) -> float:
    """How much further the object must go past the edge (m); 0 when it overhangs enough."""
    return max(0.0, w.edge_x + _a_overhang_target(w) - w.max_x())


def _hold_all(poses, grip, duration: float) -> Primitive:
    """Both arms hold their pose and gripper for ``duration`` seconds."""
    return Primitive("hold", {a: ArmMotion.still(poses[a], grip[a]) for a in ARMS}, duration)


def a_touch(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_arm(w, ctx)
    # A later push pass is skipped (0.1 s holds) once an earlier one pushed far enough.
    ctx["skipping"] = ctx.get("pass", 0) >= 1 and _a_overhang_missing(w) < 0.01
    if ctx["skipping"]:
        return _hold_all(poses, grip, 0.1)
    p, R = _a_press_pose(w)
    above = (p + _p(0, 0, 0.06), R)
    return Primitive("touch", {arm: ArmMotion(above, (p + _p(0, 0, A_PRESS_DEPTH + 0.002), R), (A_PRESS_OPEN,) * 2)}, 0.6, transit=1.5)


def a_press(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_arm(w, ctx)
    if ctx["skipping"]:
        return _hold_all(poses, grip, 0.1)
    start = poses[arm]
    return Primitive("press", {arm: ArmMotion(start, _rel(start, (0, 0, -A_PRESS_DEPTH - 0.002)), (A_PRESS_OPEN,) * 2)}, 0.4)


def a_slide(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_arm(w, ctx)
    if ctx["skipping"]:
        return _hold_all(poses, grip, 0.1)
    missing = _a_overhang_missing(w)
    # Sliding further than missing makes up for the object lagging the finger, but a light object
    # follows the finger fully and a 5-cm overshoot pushed CDs, coasters and saucers off the table:
    # never overshoot by more than half of the margin left before the centre passes the edge.
    # A on all 36 A objects x 3 seeds: Disk 1/18 and Plate 5/18 without this cap, 16/18 with it.
    spare = 0.5 * w.length_x() - _a_overhang_target(w)
    dist = min(missing * A_SLIDE_GAIN, missing + min(A_SLIDE_EXTRA, 0.5 * spare))
    start = poses[arm]
    return Primitive("slide", {arm: ArmMotion(start, _rel(start, (dist, 0, 0)), (A_PRESS_OPEN,) * 2)}, max(0.5, dist / 0.08))


def a_release(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_arm(w, ctx)
    ctx["pass"] = ctx.get("pass", 0) + 1
    if ctx["skipping"]:
        return _hold_all(poses, grip, 0.1)
    start = poses[arm]
    return Primitive("release", {arm: ArmMotion(start, _rel(start, (0, 0, 0.12)), (A_PRESS_OPEN, A_OPEN))}, 0.8)


def _polygon_hits(corners: np.ndarray, axis: int, value: float) -> list[float]:
    """Other coordinate of the points where the footprint polygon crosses ``coord[axis] = value``."""
    order = [0, 1, 3, 2]
    hits = []
    for i in range(4):
        a, b = corners[order[i]], corners[order[(i + 1) % 4]]
        if (a[axis] - value) * (b[axis] - value) <= 0 and abs(b[axis] - a[axis]) > 1e-9:
            t = (value - a[axis]) / (b[axis] - a[axis])
            hits.append(a[1 - axis] + t * (b[1 - axis] - a[1 - axis]))
    return hits


def _a_grasp_geometry(w: World, ctx: dict):
    """Where the fingers pinch the overhang: the end point E of the approach and the approach
    direction.  The hand comes horizontally from the front, turned A_APPROACH_YAW towards the
    arm's side (reachable, and the wrist stays clear of the table), enters the overhang at the
    object's centre line and stops A_INSET inside its front boundary."""
    arm = _a_grasp_arm(w, ctx)
    dy = 1.0 if arm == "right" else -1.0
    yaw = np.radians(A_APPROACH_YAW)
    approach = _p(-np.cos(yaw), dy * np.sin(yaw), 0.0)
    yc = float(w.pos[1])
    front = w.front_at(yc)
    end = _p(front, yc, _a_pinch_height(w)) + A_INSET * approach
    end[0] = max(end[0], w.edge_x + A_MIN_BEYOND_EDGE)
    return arm, end, approach


A_SHEET_TOP = 0.005  # a sheet's top above the table where it still lies flat (m)


def _a_pinch_height(w: World) -> float:
    """Height of the overhang where the fingers pinch.  Rigid: mid-thickness.  A sheet's overhang
    droops over the edge, so its measured height extent is mostly that droop; the pinch point,
    about half-way out, sits about half of it below the table top (a large mouse pad drooped
    ~3 cm, and the fingers aimed at the old mid-extent height closed above it)."""
    if not w.deformable:
        return w.table_height + w.size[2] / 2
    return w.table_height + A_SHEET_TOP / 2 - 0.5 * max(0.0, float(w.size[2]) - A_SHEET_TOP)


def a_preapproach(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    arm, end, a = _a_grasp_geometry(w, ctx)
    R = tcp_rotation(a, [0.0, 0.0, 1.0])
    p = end - A_APPROACH_LEN * a + _p(0, 0, 0.12)  # straight above the approach start
    motions = {arm: ArmMotion((p, R), (p, R), (A_OPEN, A_OPEN))}
    pusher = _a_arm(w, ctx)
    if pusher != arm:  # the pushing hand backs off towards its own base, out of the grasping arm's way
        back = poses[pusher][0] + _p(-0.05, 0.15 if pusher == "left" else -0.15, 0.05)
        motions[pusher] = ArmMotion((back, poses[pusher][1]), (back, poses[pusher][1]), (grip[pusher],) * 2)
    return Primitive("move", motions, 0.2, transit=2.0)


def a_approach(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    arm, end, a = _a_grasp_geometry(w, ctx)
    R = tcp_rotation(a, [0.0, 0.0, 1.0])
    return Primitive("touch", {arm: ArmMotion((end - A_APPROACH_LEN * a, R), (end, R), (A_OPEN, A_OPEN))}, 1.2, transit=1.0)


def a_grasp(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_grasp_arm(w, ctx)
    return Primitive("grasp", {arm: ArmMotion(poses[arm], poses[arm], (A_OPEN, 0.0))}, 0.6)


A_LIFT = 0.16  # lift height of a rigid object (m)
A_SHEET_LIFT_MARGIN = 0.08  # a sheet held by its front edge hangs its full length: lift that much + this (m)


def a_lift(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_grasp_arm(w, ctx)
    start = poses[arm]
    dz = max(A_LIFT, float(max(w.size[0], w.size[1])) + A_SHEET_LIFT_MARGIN) if w.deformable else A_LIFT
    return Primitive("lift", {arm: ArmMotion(start, _rel(start, (0.06, 0, dz)), (0.0, 0.0))}, 1.6 * dz / A_LIFT)


def hold(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    return _hold_all(poses, grip, 2.6)


# ---------------------------------------------------------------------------- strategy B
B_OPEN = GRIPPER_MAX_WIDTH  # open fingers: two contact patches far apart resist tilting
B_SQUEEZE = 0.025  # how far each hand is commanded past the touched face (m)


def _b_targets(w: World, inset: float, dz: float = 0.0):
    u, half = w.squeeze_axis()
    z = w.table_height + max(0.014, w.size[2] - 0.04) + dz
    f = np.cross(_p(0, 0, 1), u)
    R = tcp_rotation(DOWN, f)
    out = {}
    for arm, s in (("left", 1.0), ("right", -1.0)):
        p = w.pos + s * (half + FINGER_HALF_WIDTH - inset) * u
        out[arm] = (_p(p[0], p[1], z), R)
    return out


B_ABOVE = 0.05  # the hands come down to the touch start from this far above the object's top (m)


def b_preapproach(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    """Both hands straight above their touch start.  A joint-space transit straight to a start
    beside a tall, large object swept the hand onto its top edge (a 6 cm album, seen from above):
    the hand then pressed on the top instead of squeezing the side."""
    top = w.table_height + w.size[2] + B_ABOVE
    motions = {}
    for a, (p, R) in _b_targets(w, -0.04).items():
        above = (_p(p[0], p[1], max(p[2], top)), R)
        motions[a] = ArmMotion(above, above, (B_OPEN, B_OPEN))
    return Primitive("move", motions, 0.2, transit=2.0)


def b_touch(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    far, near = _b_targets(w, -0.04), _b_targets(w, 0.0)
    return Primitive("touch", {a: ArmMotion(far[a], near[a], (B_OPEN, B_OPEN)) for a in ARMS}, 1.0, transit=0.8)


def b_squeeze(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    return Primitive(
        "squeeze", {a: ArmMotion(poses[a], _rel(poses[a], _b_inward(w, a) * B_SQUEEZE), (B_OPEN, B_OPEN)) for a in ARMS}, 0.6
    )


def _b_inward(w: World, arm: str) -> np.ndarray:
    u, _ = w.squeeze_axis()
    return -u if arm == "left" else u


def b_lift(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    return Primitive("lift", {a: ArmMotion(poses[a], _rel(poses[a], (0, 0, 0.16)), (B_OPEN, B_OPEN)) for a in ARMS}, 1.6)


# ---------------------------------------------------------------------------- strategy C
C_PRESS_TIP_Z = 0.001  # finger tips this far above the table while pressing cloth (m)
C_START_FRAC = 0.42  # press points at +-this fraction of the sheet's extent from its centre
C_END_HALF_GAP = 0.025  # the pressing hands stop this far from the centre (m)
C_PINCH_OPEN = 0.06  # gripper opening when straddling the fold (m)
C_PRESS_OPEN = GRIPPER_MAX_WIDTH  # pressing with open fingers: no cloth gets caught between them
C_TILT = 20.0  # pressing hands lean outward by this much (deg): upright, their wrists collide when 5 cm apart
C_TILT_LIFT = 0.01  # a leaning finger's lower edge is about this far (m) times sin(tilt) below its tip centre
C_LEFT_AWAY = 0.15  # after the squeeze the left hand backs off this far outward (m), clear of the pinching hand ...
C_LEFT_OFF, C_LEFT_OFF_UP = 0.05, 0.02  # ... first this far outward and up (m), off the ridge's wall, ...
C_LEFT_UP = 0.15  # ... then straight up to this height above the press (m), then outward


def _c_pose(w: World, s: float, dist: float, dz: float):
    """Pressing pose of the hand on side ``s`` (+1 left, -1 right) of the sheet centre, ``dist`` out
    along the squeeze axis, fingers across it, leaning C_TILT outward, tips ``dz`` above the press."""
    u, _ = w.squeeze_axis()
    p = w.pos + s * dist * u
    f = np.cross(_p(0, 0, 1), u)
    th = np.radians(C_TILT)
    approach = DOWN * np.cos(th) - s * np.sin(th) * u
    tip = _p(p[0], p[1], w.table_height + C_PRESS_TIP_Z + C_TILT_LIFT * np.sin(th) + dz)
    return tip - approach * FINGER_TIP_BELOW_TCP, tcp_rotation(approach, f)


def c_touch(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    _, half = w.squeeze_axis()
    d = C_START_FRAC * 2 * half
    return Primitive(
        "touch",
        {a: ArmMotion(_c_pose(w, s, d, 0.05), _c_pose(w, s, d, 0.0), (C_PRESS_OPEN,) * 2) for a, s in (("left", 1), ("right", -1))},
        0.8,
        transit=2.0,
    )


def c_squeeze(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    motions = {}
    for a, s in (("left", 1.0), ("right", -1.0)):
        u, _ = w.squeeze_axis()
        start = poses[a]
        end_xy = w.pos + s * C_END_HALF_GAP * u
        motions[a] = ArmMotion(start, (_p(end_xy[0], end_xy[1], start[0][2]), start[1]), (C_PRESS_OPEN,) * 2)
    return Primitive("squeeze", motions, 1.6)


def c_release_both(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    """Both hands let go of the squeezed sheet (the ridge stays, held by table friction).  The left
    hand first moves its leaning finger tips 5 cm outward and 2 cm up, off the ridge's wall (then
    :func:`c_left_away`, :func:`c_left_out`): backing away 15 cm up and out in one move, the tips
    dragged a heavy towel's wall up with them and flattened the fold (seen in frames)."""
    u, _ = w.squeeze_axis()
    return Primitive(
        "release",
        {
            "right": ArmMotion(poses["right"], _rel(poses["right"], (0, 0, 0.06)), (C_PRESS_OPEN, C_PINCH_OPEN)),
            "left": ArmMotion(poses["left"], _rel(poses["left"], C_LEFT_OFF * u + _p(0, 0, C_LEFT_OFF_UP)), (C_PRESS_OPEN,) * 2),
        },
        0.6,
    )


def c_left_away(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    """The left hand, off the ridge, rises straight up: moving outward while low, it carried a
    skirt's tall ridge away with it (seen in frames)."""
    rise = _p(0, 0, C_LEFT_UP - C_LEFT_OFF_UP)
    return Primitive("move", {"left": ArmMotion(poses["left"], _rel(poses["left"], rise), (C_PRESS_OPEN,) * 2)}, 0.6)


def c_left_out(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    """... then moves outward, clear of the pinching hand."""
    u, _ = w.squeeze_axis()
    out = (C_LEFT_AWAY - C_LEFT_OFF) * u
    return Primitive("move", {"left": ArmMotion(poses["left"], _rel(poses["left"], out), (C_PRESS_OPEN,) * 2)}, 0.5)


def c_straddle(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    """Right gripper, open, fingers either side of the fold, at the sheet's centre as it is now: a
    tall ridge (a skirt's) can topple sideways once the left hand leaves it and drag the sheet a
    few cm along; the fold goes with it (seen in frames)."""
    u, _ = w.squeeze_axis()
    centre = w.pos
    R = tcp_rotation(DOWN, u)
    z = w.table_height + C_PRESS_TIP_Z + FINGER_TIP_BELOW_TCP
    start = (_p(centre[0], centre[1], z + 0.06), R)
    end = (_p(centre[0], centre[1], z), R)
    return Primitive(
        "press", {"right": ArmMotion(start, end, (C_PINCH_OPEN, C_PINCH_OPEN)), "left": ArmMotion.still(poses["left"], C_PRESS_OPEN)}, 0.8, transit=1.5
    )


def c_pinch(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    return Primitive(
        "grasp",
        {"right": ArmMotion(poses["right"], poses["right"], (C_PINCH_OPEN, 0.0)), "left": ArmMotion.still(poses["left"], C_PRESS_OPEN)},
        0.8,
    )


C_LIFT = 0.32  # lift height of a pinched fold (m) ...
C_LIFT_MARGIN = 0.06  # ... at least the sheet's diagonal + this: a pinch near an edge lets it hang that long (m)


def c_lift(ex: Expert, w: World, poses, grip, ctx) -> Primitive:
    dz = max(C_LIFT, float(np.hypot(w.size[0], w.size[1])) + C_LIFT_MARGIN)
    return Primitive("lift", {"right": ArmMotion(poses["right"], _rel(poses["right"], (0, 0, dz)), (0.0, 0.0))}, 2.0 * dz / C_LIFT)


STRATEGIES = {
    "A": (a_touch, a_press, a_slide, a_release) * A_PASSES + (a_preapproach, a_approach, a_grasp, a_lift, hold),
    "B": (b_preapproach, b_touch, b_squeeze, b_lift, hold),
    "C": (c_touch, c_squeeze, c_release_both, c_left_away, c_left_out, c_straddle, c_pinch, c_lift, hold),
}
"""Each strategy as its sequence of stages (each stage poses one primitive)."""

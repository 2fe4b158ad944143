"""Strategy A, push to the edge: press the object and slide it until it overhangs the usable edge;
grasp the overhang from the side (fingers above and below it); lift."""

from __future__ import annotations

import numpy as np

from flatlab_lerobot.primitives import ArmMotion, Primitive
from flatlab_lerobot.sim.robot import tcp_rotation
from flatlab_lerobot.strategies.world import (
    DOWN, FINGER_TIP_BELOW_TCP, HOLD, StageSpec, World, hold, hold_all, shifted, vec,
)  # fmt: skip

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
A_PASSES = 3  # push passes at most; a pass is skipped once the overhang is within A_SKIP_MISSING of the target
A_SKIP_MISSING = 0.01  # m
A_SKIP_HOLD = 0.1  # a skipped pass's stages each hold this long (s)
A_PRESS_OPEN = 0.0  # press with closed fingers (open ones were measured worse: 0/10)
A_PRESS_BEHIND = 0.02  # the press point lies this far behind (-x) the object's centre (m)

# each stage's primitive and timing (duration of the Cartesian motion, transit to its start)
S_TOUCH = StageSpec("touch", 0.6, transit=1.5)
S_PRESS = StageSpec("press", 0.4, start="current")
S_SLIDE = StageSpec("slide", 0.5, speed=0.08, along="xy", start="current")  # max(0.5 s, distance / 8 cm/s)
S_RELEASE = StageSpec("release", 0.8, start="current")
S_PREAPPROACH = StageSpec("move", 0.2, transit=2.0)
S_APPROACH = StageSpec("touch", 1.2, transit=1.0)
S_GRASP = StageSpec("grasp", 0.6, start="current")
S_LIFT = StageSpec("lift", 1.6, speed=0.1, along="z", start="current")  # 1.6 s per A_LIFT (16 cm) of rise, at least 1.6 s


def arm_on_side(y: float) -> str:
    """The arm on the side of an object centred at ``y`` (the right arm at y <= 0).  The expert reads
    ``y`` from the privileged state; the learned policy's ``contact_a_grasp`` from the object cloud."""
    return "right" if y <= 0 else "left"


def pusher_backoff(arm: str, hand) -> np.ndarray:
    """Where the pushing ``arm``'s hand at ``hand`` backs off to before the other arm grasps: towards its
    own base (5 cm back, 15 cm to its side, 5 cm up), out of the grasping arm's and the lifted object's
    way.  The expert's pre-approach; the learned policy's with ``contact_a_backoff``."""
    return np.asarray(hand, float) + vec(-0.05, 0.15 if arm == "left" else -0.15, 0.05)


def _a_arm(world: World, ctx: dict) -> str:
    """The arm that pushes: the one on the object's side, chosen once per episode."""
    return ctx.setdefault("arm", arm_on_side(float(world.pos[1])))


def _a_grasp_arm(world: World, ctx: dict) -> str:
    """The arm that grasps: the one on the side where the pushes left the object (a push can
    drift it sideways by 10-20 cm), chosen once, when the grasp begins."""
    return ctx.setdefault("grasp_arm", arm_on_side(float(world.pos[1])))


def _a_press_pose(world: World):
    top = world.table_height + world.size[2]
    p = world.pos.copy()
    p[0] -= A_PRESS_BEHIND
    p[2] = top + FINGER_TIP_BELOW_TCP - A_PRESS_DEPTH
    return p, tcp_rotation(DOWN, [0.0, 1.0, 0.0])


def overhang_target(length_x: float) -> float:
    """How far an object ``length_x`` m long along x should stick out past the edge (m): A_OVERHANG,
    but at most A_OVERHANG_FRAC of its length, so a small object keeps its centre of mass on the table."""
    return min(A_OVERHANG, A_OVERHANG_FRAC * length_x)


def overhang_missing(max_x: float, length_x: float, edge_x: float) -> float:
    """How much further an object whose footprint reaches ``max_x`` and spans ``length_x`` along x
    must go past the edge at ``edge_x`` (m); 0 when it overhangs enough.  The expert measures the
    footprint from the privileged state; the learned policy from the object cloud."""
    return max(0.0, edge_x + overhang_target(length_x) - max_x)


def slide_distance(missing: float, length_x: float) -> float:
    """How far the finger slides (m) for an overhang ``missing`` m short, on an object ``length_x`` long.
    Sliding further than missing makes up for the object lagging the finger, but a light object
    follows the finger fully and a 5-cm overshoot pushed CDs, coasters and saucers off the table:
    never overshoot by more than half of the margin left before the centre passes the edge.
    A on all 36 A objects x 3 seeds: Disk 1/18 and Plate 5/18 without this cap, 16/18 with it."""
    spare = 0.5 * length_x - overhang_target(length_x)
    return min(missing * A_SLIDE_GAIN, missing + min(A_SLIDE_EXTRA, 0.5 * spare))


def pass_needed(missing: float) -> bool:
    """Whether a later push pass runs (it is skipped once the overhang is within A_SKIP_MISSING)."""
    return missing >= A_SKIP_MISSING


def _a_overhang_target(w: World) -> float:
    return overhang_target(w.length_x())


def _a_overhang_missing(w: World) -> float:
    return overhang_missing(w.max_x(), w.length_x(), w.edge_x)

def a_touch(ex, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_arm(w, ctx)
    # A later push pass is skipped (0.1 s holds) once an earlier one pushed far enough.
    ctx["skipping"] = ctx.get("pass", 0) >= 1 and not pass_needed(_a_overhang_missing(w))
    if ctx["skipping"]:
        return hold_all(poses, grip, A_SKIP_HOLD)
    p, R = _a_press_pose(w)
    above = (p + vec(0, 0, 0.06), R)
    motion = ArmMotion(above, (p + vec(0, 0, A_PRESS_DEPTH + 0.002), R), (A_PRESS_OPEN,) * 2)
    return S_TOUCH.make({arm: motion})


def a_press(ex, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_arm(w, ctx)
    if ctx["skipping"]:
        return hold_all(poses, grip, A_SKIP_HOLD)
    start = poses[arm]
    motion = ArmMotion(start, shifted(start, (0, 0, -A_PRESS_DEPTH - 0.002)), (A_PRESS_OPEN,) * 2)
    return S_PRESS.make({arm: motion})


def a_slide(ex, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_arm(w, ctx)
    if ctx["skipping"]:
        return hold_all(poses, grip, A_SKIP_HOLD)
    dist = slide_distance(_a_overhang_missing(w), w.length_x())
    start = poses[arm]
    motion = ArmMotion(start, shifted(start, (dist, 0, 0)), (A_PRESS_OPEN,) * 2)
    return S_SLIDE.make({arm: motion}, dist)


def a_release(ex, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_arm(w, ctx)
    ctx["pass"] = ctx.get("pass", 0) + 1
    if ctx["skipping"]:
        return hold_all(poses, grip, A_SKIP_HOLD)
    start = poses[arm]
    motion = ArmMotion(start, shifted(start, (0, 0, 0.12)), (A_PRESS_OPEN, A_OPEN))
    return S_RELEASE.make({arm: motion})


def _a_grasp_geometry(w: World, ctx: dict):
    """Where the fingers pinch the overhang: the end point E of the approach and the approach
    direction.  The hand comes horizontally from the front, turned A_APPROACH_YAW towards the
    arm's side (reachable, and the wrist stays clear of the table), enters the overhang at the
    object's centre line and stops A_INSET inside its front boundary."""
    arm = _a_grasp_arm(w, ctx)
    dy = 1.0 if arm == "right" else -1.0
    yaw = np.radians(A_APPROACH_YAW)
    approach = vec(-np.cos(yaw), dy * np.sin(yaw), 0.0)
    yc = float(w.pos[1])
    front = w.front_at(yc)
    end = vec(front, yc, _a_pinch_height(w)) + A_INSET * approach
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


def a_preapproach(ex, w: World, poses, grip, ctx) -> Primitive:
    arm, end, a = _a_grasp_geometry(w, ctx)
    R = tcp_rotation(a, [0.0, 0.0, 1.0])
    p = end - A_APPROACH_LEN * a + vec(0, 0, 0.12)  # straight above the approach start
    motions = {arm: ArmMotion((p, R), (p, R), (A_OPEN, A_OPEN))}
    pusher = _a_arm(w, ctx)
    if pusher != arm:
        back = pusher_backoff(pusher, poses[pusher][0])
        motions[pusher] = ArmMotion((back, poses[pusher][1]), (back, poses[pusher][1]), (grip[pusher],) * 2)
    return S_PREAPPROACH.make(motions)


def a_approach(ex, w: World, poses, grip, ctx) -> Primitive:
    arm, end, a = _a_grasp_geometry(w, ctx)
    R = tcp_rotation(a, [0.0, 0.0, 1.0])
    motion = ArmMotion((end - A_APPROACH_LEN * a, R), (end, R), (A_OPEN, A_OPEN))
    return S_APPROACH.make({arm: motion})


def a_grasp(ex, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_grasp_arm(w, ctx)
    return S_GRASP.make({arm: ArmMotion(poses[arm], poses[arm], (A_OPEN, 0.0))})


A_LIFT = 0.16  # lift height of a rigid object (m)
A_SHEET_LIFT_MARGIN = 0.08  # a sheet held by its front edge hangs its full length: lift that much + this (m)


def a_lift(ex, w: World, poses, grip, ctx) -> Primitive:
    arm = _a_grasp_arm(w, ctx)
    start = poses[arm]
    dz = max(A_LIFT, float(max(w.size[0], w.size[1])) + A_SHEET_LIFT_MARGIN) if w.deformable else A_LIFT
    return S_LIFT.make({arm: ArmMotion(start, shifted(start, (0.06, 0, dz)), (0.0, 0.0))}, dz)



STAGES = (a_touch, a_press, a_slide, a_release) * A_PASSES + (a_preapproach, a_approach, a_grasp, a_lift, hold)
"""Strategy A's stages: up to A_PASSES push passes, then the side grasp of the overhang."""
SPECS = (S_TOUCH, S_PRESS, S_SLIDE, S_RELEASE) * A_PASSES + (S_PREAPPROACH, S_APPROACH, S_GRASP, S_LIFT, HOLD)
"""Each stage's :class:`StageSpec`: primitive name and timing (a skipped pass holds A_SKIP_HOLD instead)."""
PASS_STAGES = 4  # stages per push pass: touch, press, slide, release
A_PREAPPROACH = A_PASSES * PASS_STAGES  # index of the pre-approach ("move"): the grasp's stages start there

"""Strategy C, cloth fold-and-pinch: two open grippers, leaning outward, press the sheet and slide
towards each other to raise a fold; both let go (the left one steps off the fold, rises, then moves
away), the right one straddles the fold at the sheet's current centre, pinches it and lifts."""

from __future__ import annotations

import numpy as np

from flatlab_lerobot.primitives import ArmMotion, Primitive
from flatlab_lerobot.sim.robot import GRIPPER_MAX_WIDTH, tcp_rotation
from flatlab_lerobot.strategies.world import DOWN, FINGER_TIP_BELOW_TCP, HOLD, StageSpec, World, hold, shifted, vec

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
S_TOUCH = StageSpec("touch", 0.8, transit=2.0)
S_SQUEEZE = StageSpec("squeeze", 1.6, start="current")
S_RELEASE = StageSpec("release", 0.6, start="current")
S_LEFT_AWAY = StageSpec("move", 0.6, start="current")
S_LEFT_OUT = StageSpec("move", 0.5, start="current")
S_STRADDLE = StageSpec("press", 0.8, transit=1.5)
S_PINCH = StageSpec("grasp", 0.8, start="current")
S_LIFT = StageSpec("lift", 2.0, speed=0.16, along="z", start="current")  # 2 s per C_LIFT (32 cm) of rise, at least 2 s


C_TOUCH_ABOVE = 0.05  # the pressing hands come down from this far above the press (m)
C_STRADDLE_ABOVE = 0.06  # the pinching hand comes down from this far above its pinch (m)


def press_tcp_z(table_height: float) -> float:
    """TCP height (m) of a pressing hand (leaning C_TILT, tips C_PRESS_TIP_Z above the table)."""
    th = np.radians(C_TILT)
    return table_height + C_PRESS_TIP_Z + C_TILT_LIFT * np.sin(th) + FINGER_TIP_BELOW_TCP * np.cos(th)


def pinch_tcp_z(table_height: float) -> float:
    """TCP height (m) of the upright pinching hand, its tips C_PRESS_TIP_Z above the table."""
    return table_height + C_PRESS_TIP_Z + FINGER_TIP_BELOW_TCP


def _c_pose(w: World, s: float, dist: float, dz: float):
    """Pressing pose of the hand on side ``s`` (+1 left, -1 right) of the sheet centre, ``dist`` out
    along the squeeze axis, fingers across it, leaning C_TILT outward, tips ``dz`` above the press."""
    u, _ = w.squeeze_axis()
    p = w.pos + s * dist * u
    f = np.cross(vec(0, 0, 1), u)
    th = np.radians(C_TILT)
    approach = DOWN * np.cos(th) - s * np.sin(th) * u
    tip = vec(p[0], p[1], w.table_height + C_PRESS_TIP_Z + C_TILT_LIFT * np.sin(th) + dz)
    return tip - approach * FINGER_TIP_BELOW_TCP, tcp_rotation(approach, f)


def c_touch(ex, w: World, poses, grip, ctx) -> Primitive:
    _, half = w.squeeze_axis()
    d = C_START_FRAC * 2 * half
    sides = (("left", 1), ("right", -1))
    return S_TOUCH.make(
        {a: ArmMotion(_c_pose(w, s, d, C_TOUCH_ABOVE), _c_pose(w, s, d, 0.0), (C_PRESS_OPEN,) * 2) for a, s in sides}
    )


def c_squeeze(ex, w: World, poses, grip, ctx) -> Primitive:
    motions = {}
    for a, s in (("left", 1.0), ("right", -1.0)):
        u, _ = w.squeeze_axis()
        start = poses[a]
        end_xy = w.pos + s * C_END_HALF_GAP * u
        motions[a] = ArmMotion(start, (vec(end_xy[0], end_xy[1], start[0][2]), start[1]), (C_PRESS_OPEN,) * 2)
    return S_SQUEEZE.make(motions)


def c_release_both(ex, w: World, poses, grip, ctx) -> Primitive:
    """Both hands let go of the squeezed sheet (the ridge stays, held by table friction).  The left
    hand first moves its leaning finger tips 5 cm outward and 2 cm up, off the ridge's wall (then
    :func:`c_left_away`, :func:`c_left_out`): backing away 15 cm up and out in one move, the tips
    dragged a heavy towel's wall up with them and flattened the fold (seen in frames)."""
    u, _ = w.squeeze_axis()
    off = C_LEFT_OFF * u + vec(0, 0, C_LEFT_OFF_UP)
    return S_RELEASE.make(
        {
            "right": ArmMotion(poses["right"], shifted(poses["right"], (0, 0, 0.06)), (C_PRESS_OPEN, C_PINCH_OPEN)),
            "left": ArmMotion(poses["left"], shifted(poses["left"], off), (C_PRESS_OPEN,) * 2),
        }
    )


def c_left_away(ex, w: World, poses, grip, ctx) -> Primitive:
    """The left hand, off the ridge, rises straight up: moving outward while low, it carried a
    skirt's tall ridge away with it (seen in frames)."""
    rise = vec(0, 0, C_LEFT_UP - C_LEFT_OFF_UP)
    motion = ArmMotion(poses["left"], shifted(poses["left"], rise), (C_PRESS_OPEN,) * 2)
    return S_LEFT_AWAY.make({"left": motion})


def c_left_out(ex, w: World, poses, grip, ctx) -> Primitive:
    """... then moves outward, clear of the pinching hand."""
    u, _ = w.squeeze_axis()
    out = (C_LEFT_AWAY - C_LEFT_OFF) * u
    motion = ArmMotion(poses["left"], shifted(poses["left"], out), (C_PRESS_OPEN,) * 2)
    return S_LEFT_OUT.make({"left": motion})


def c_straddle(ex, w: World, poses, grip, ctx) -> Primitive:
    """Right gripper, open, fingers either side of the fold, at the sheet's centre as it is now: a
    tall ridge (a skirt's) can topple sideways once the left hand leaves it and drag the sheet a
    few cm along; the fold goes with it (seen in frames)."""
    u, _ = w.squeeze_axis()
    centre = w.pos
    R = tcp_rotation(DOWN, u)
    z = pinch_tcp_z(w.table_height)
    start = (vec(centre[0], centre[1], z + C_STRADDLE_ABOVE), R)
    end = (vec(centre[0], centre[1], z), R)
    left = ArmMotion.still(poses["left"], C_PRESS_OPEN)
    return S_STRADDLE.make({"right": ArmMotion(start, end, (C_PINCH_OPEN, C_PINCH_OPEN)), "left": left})


def c_pinch(ex, w: World, poses, grip, ctx) -> Primitive:
    left = ArmMotion.still(poses["left"], C_PRESS_OPEN)
    return S_PINCH.make({"right": ArmMotion(poses["right"], poses["right"], (C_PINCH_OPEN, 0.0)), "left": left})


C_LIFT = 0.32  # lift height of a pinched fold (m) ...
C_LIFT_MARGIN = 0.06  # ... at least the sheet's diagonal + this: a pinch near an edge lets it hang that long (m)


def c_lift(ex, w: World, poses, grip, ctx) -> Primitive:
    dz = max(C_LIFT, float(np.hypot(w.size[0], w.size[1])) + C_LIFT_MARGIN)
    motion = ArmMotion(poses["right"], shifted(poses["right"], (0, 0, dz)), (0.0, 0.0))
    return S_LIFT.make({"right": motion}, dz)



STAGES = (c_touch, c_squeeze, c_release_both, c_left_away, c_left_out, c_straddle, c_pinch, c_lift, hold)
"""Strategy C's stages."""
SPECS = (S_TOUCH, S_SQUEEZE, S_RELEASE, S_LEFT_AWAY, S_LEFT_OUT, S_STRADDLE, S_PINCH, S_LIFT, HOLD)
"""Each stage's :class:`StageSpec`: primitive name and timing."""

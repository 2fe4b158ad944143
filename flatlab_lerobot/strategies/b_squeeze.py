"""Strategy B, dual-arm squeeze: two arms touch opposite sides, squeeze, lift together."""

from __future__ import annotations

import numpy as np

from flatlab_lerobot.primitives import ArmMotion, Primitive
from flatlab_lerobot.sim.robot import ARMS, GRIPPER_MAX_WIDTH, tcp_rotation
from flatlab_lerobot.strategies.world import DOWN, FINGER_HALF_WIDTH, HOLD, StageSpec, World, hold, shifted, vec

# ---------------------------------------------------------------------------- strategy B
B_OPEN = GRIPPER_MAX_WIDTH  # open fingers: two contact patches far apart resist tilting
B_SQUEEZE = 0.025  # how far each hand is commanded past the touched face (m)
S_PREAPPROACH = StageSpec("move", 0.2, transit=2.0)
S_TOUCH = StageSpec("touch", 1.0, transit=0.8)
S_SQUEEZE = StageSpec("squeeze", 0.6, start="current")
S_LIFT = StageSpec("lift", 1.6, start="current")


HALF_TURN = np.diag([-1.0, -1.0, 1.0])  # tcp_rotation(approach, -f) == tcp_rotation(approach, f) @ HALF_TURN


def _b_targets(w: World, inset: float, dz: float = 0.0, right_half_turn: bool = False):
    """Each hand's pose beside its end of the squeeze axis; ``right_half_turn``: the right hand turned a
    half turn about its approach axis (``ExpertOptions.b_right_half_turn``)."""
    u, half = w.squeeze_axis()
    z = w.table_height + max(0.014, w.size[2] - 0.04) + dz
    f = np.cross(vec(0, 0, 1), u)
    R = tcp_rotation(DOWN, f)
    out = {}
    for arm, s in (("left", 1.0), ("right", -1.0)):
        p = w.pos + s * (half + FINGER_HALF_WIDTH - inset) * u
        out[arm] = (vec(p[0], p[1], z), R @ HALF_TURN if arm == "right" and right_half_turn else R)
    return out


def _right_half_turn(ex) -> bool:
    """The expert's ``b_right_half_turn`` option; a stage posed without an expert (``ex`` None) poses as the default."""
    return ex is not None and ex.options.b_right_half_turn


B_ABOVE = 0.05  # the hands come down to the touch start from this far above the object's top (m)


def b_preapproach(ex, w: World, poses, grip, ctx) -> Primitive:
    """Both hands straight above their touch start.  A joint-space transit straight to a start
    beside a tall, large object swept the hand onto its top edge (a 6 cm album, seen from above):
    the hand then pressed on the top instead of squeezing the side."""
    top = w.table_height + w.size[2] + B_ABOVE
    motions = {}
    for a, (p, R) in _b_targets(w, -0.04, right_half_turn=_right_half_turn(ex)).items():
        above = (vec(p[0], p[1], max(p[2], top)), R)
        motions[a] = ArmMotion(above, above, (B_OPEN, B_OPEN))
    return S_PREAPPROACH.make(motions)


def b_touch(ex, w: World, poses, grip, ctx) -> Primitive:
    turn = _right_half_turn(ex)
    far, near = _b_targets(w, -0.04, right_half_turn=turn), _b_targets(w, 0.0, right_half_turn=turn)
    motions = {a: ArmMotion(far[a], near[a], (B_OPEN, B_OPEN)) for a in ARMS}
    return S_TOUCH.make(motions)


def b_squeeze(ex, w: World, poses, grip, ctx) -> Primitive:
    motions = {a: ArmMotion(poses[a], shifted(poses[a], _b_inward(w, a) * B_SQUEEZE), (B_OPEN, B_OPEN)) for a in ARMS}
    return S_SQUEEZE.make(motions)


def _b_inward(w: World, arm: str) -> np.ndarray:
    u, _ = w.squeeze_axis()
    return -u if arm == "left" else u


def b_lift(ex, w: World, poses, grip, ctx) -> Primitive:
    motions = {a: ArmMotion(poses[a], shifted(poses[a], (0, 0, 0.16)), (B_OPEN, B_OPEN)) for a in ARMS}
    return S_LIFT.make(motions)



STAGES = (b_preapproach, b_touch, b_squeeze, b_lift, hold)
"""Strategy B's stages."""
SPECS = (S_PREAPPROACH, S_TOUCH, S_SQUEEZE, S_LIFT, HOLD)
"""Each stage's :class:`StageSpec`: primitive name and timing."""

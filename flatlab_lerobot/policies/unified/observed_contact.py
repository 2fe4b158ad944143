"""``--policy.contact=observed``: the heights of the stages that touch the object, and the length of A's
slide, come from the observed clouds by the expert's own rules; every x, y, orientation, gripper width,
arm choice and strategy stays learned (but for C's pinch and squeeze below, and the switches at the end).
Not in the paper: a measured answer to "how much of the gap is the executor's upward height bias" (1-1.5
cm on Train frames too: the last constant-lr checkpoint's offset, docs/executor.md), which keeps strategy
A's press above 5-mm discs and B's squeeze above thin boards.

What is read: the seen object points (``observation.object_pointcloud``), the table top and the usable
edge from the calibration (``observation.cell``) -- never ``environment_state``.  The expert's rules, with
the observed quantities in place of the privileged ones:

* A, push passes (touch, press, slide, release): the fingertips at the object's top (the 95th percentile
  of the cloud's z within 4 cm of the contact point, else of the whole cloud) + 2 mm at the touch's end,
  - 1 mm while pressing and sliding (``a_push_to_edge``: ``A_PRESS_DEPTH``); the touch starts 6 cm above.
* A, the side grasp (approach, grasp, lift's start): the overhang's mid height (the points past the
  table edge: half-way between their lowest and highest), which is the expert's ``_a_pinch_height`` for
  a rigid object and close to it for a drooping sheet.
* B (touch, squeeze, lift's start): ``table + max(1.4 cm, thickness - 4 cm)`` (``b_squeeze._b_targets``),
  the thickness being the cloud's top above the table.
* A's slide: at most the expert's ``slide_distance`` for the overhang still missing, measured on the
  cloud at the slide's start (its largest x and extent along x against the usable edge, the rule that
  already decides another push pass): once the press holds the object, a learned slide that ran longer
  pushed it off the table.
* C (touch, squeeze; the pinching hand's press, grasp and lift's start -- the pinching hand being the
  commanded arm whose learned gripper closes most): the expert's heights, which
  depend on the table top only (``c_fold_pinch``: the leaning pressing hands' tips 1 mm above the table,
  the upright pinching hand's likewise; the touch and the straddle come down from 5 and 6 cm above).
* C's squeeze: its end moved along its own direction to stop ``C_END_HALF_GAP`` (2.5 cm) short of the
  seen cloth's centre (the mean of its cloud), as the expert's hands stop short of the sheet's centre:
  the learned squeezes stopped 5-8 cm short and raised no fold (towel, cotton sheet; seen in the stage
  log, the cloth's top stayed 3 mm above the table).
* C's pinch (the pinching hand's press, grasp, lift): at the seen cloth's centre, as the expert straddles
  the fold at the sheet's current centre (its press at the centre of the cloud seen then; grasp and lift
  from where the hand is): the learned straddle stood 2.7-3.5 cm beside a raised fold across the
  fingers' closing direction (``shorts_denim``, a Train object; the stage log) and closed beside it.
* The other stages: learned.

Where a stage sets only its start height (release, lift) the learned displacement is kept.

``--policy.contact_from_hand=true`` (with ``observed``): A's and B's stages that the expert starts where
the hand is (``StageSpec.start == "current"``: A's press, slide, release, grasp and lift, B's squeeze and
lift) start exactly at the commanded hand (position and orientation), with their learned displacement
and change of orientation, their end height by the rules above where they set one; B's squeeze at most
the expert's ``B_SQUEEZE`` long and its lift straight up (:func:`b_from_hand`).  A learned start
0.5-1.5 cm off the hand made the runner move the hand there first, a joint-space transit while it pressed
or held the object: on ``album_pocket`` (seed 1003) pass 2's capped 3.0-cm slide moved the album 4.0 cm,
1.1 cm of it while the release's start was reached, and the album went over the edge (the stage log
against the true pose).  C is left as it is: its pinch rules already place the pinching hand.

``--policy.contact_b_face=true`` (with ``observed``): B's touch moved along its own horizontal direction
so that it ends ``FINGER_HALF_WIDTH`` outside the face of the seen cloud it approaches, as the expert's
hands end at the object's side (``b_squeeze._b_targets``).  On the large unseen boards the learned touch
ended 3-4 cm inside the face (``painting_portrait`` 25 x 32 cm, ``chess_folding_wood`` 40 x 40 cm, seed
1000, against the true pose: the executor's hands land about where Train-sized boards have their sides)
and the squeeze that followed lifted nothing.  With ``contact_from_hand`` the squeeze then starts there.

``--policy.contact_a_grasp=true`` (with ``observed``): A's grasp stages (pre-approach, approach, grasp, lift)
are commanded to the arm on the side of the seen object's centre, decided once at the pre-approach, as
the expert's ``_a_grasp_arm`` decides from the true centre (:func:`a_side_arm`).  Where the executor
commands only the other arm, that arm's learned motion is mirrored across the seen centre line onto the
rule's arm (:func:`mirror_pose`: the expert's approach for the two arms are such mirror images); the
executor's pose of an arm it does not command is untrained.  The learned arm reached across for objects
on its far side: on ``magazine_fashion`` (seed 1004, the magazine 5.5 cm right of the centre) the left
arm's transit to the approach start swung the hand 60 cm up and back down onto the magazine, which
flipped off the table; on ``disk_flying_disc`` (seed 1001) the left hand stopped 2.6 cm above its
commanded approach height and closed on nothing (the stage log against the true pose).  And the
pre-approach (the expert's joint-space transit to a pose above the approach's start) runs as a Cartesian
line from where each commanded hand is to its learned pose, taking the transit's time
(:func:`observed_motion`'s ``a_grasp``): from the pusher's release pose 10 cm above a magazine, the
transit's joint-space path dipped the hand 9.5 cm onto it and dragged it off the table
(``magazine_fashion`` seed 1003; so fell 4 of the 6 trials of a 12-trial pilot that still failed with the
arm by side alone); the expert's transit from its own joints arches 50 cm up instead.  After the
pre-approach only the rule's arm moves (:func:`a_side_arms`), and the grasp closes where the hand is, as
the expert's does.  Measured: docs/unified.md (stop 39).

``--policy.contact_a_backoff=true`` (with ``contact_a_grasp``): at the pre-approach the arm off the seen
side (the pusher, where the two differ) backs off from its commanded hand as the expert's does
(``a_push_to_edge.pusher_backoff``: 5 cm back, 15 cm to its own side, 5 cm up; the policy's
``_pusher_backoff``), replacing any learned motion of it.  Left where its release put it, 13 cm above
the table, it was in the lift's way: thin rigid objects pinched at their overhang tilted on the way up
(``book_comic`` seed 1000: to 54 degrees, prising the pinching fingers from 1.0 to 1.9 cm apart) and slid
out during the hold; lifted only 16 cm they stayed wedged against its fingers (both arms touched the
object in 3 of 4 traced holds).  With the back-off the learned lift held in 11 of 15 such trials (3
before).  Measured: docs/unified.md (stop 40).

``--policy.contact_a_sheet_lift=true`` (with ``observed``): A's lift of an object whose seen overhang droops
(:func:`overhang_droop` at least A_SHEET_DROOP: a sheet) rises at least the seen sheet's length plus the
expert's ``A_SHEET_LIFT_MARGIN`` (:func:`sheet_lift_end`), as the expert lifts a sheet held by its front edge
(``a_push_to_edge.a_lift``: its length + 8 cm); a rigid object's lift (and an unseen overhang's) keeps its
learned rise.  The executor, which cannot tell a sheet from a rigid object of its outline, learned a rise
of about the length: sheets lifted by A still touched the table at the hold (``mousepad_small`` seed 1002
hung 4.3 cm clear with its front edge pinched, the rest of it on the table).  The droop threshold from a
42-trial pilot's lift stages (stop 40): rigid overhangs were seen within 2.5 mm of the table top (depth
noise on their sides), sheets' drooped 5.4-24.6 mm.  Measured (docs/unified.md, stop 41; paired on one build):
418 -> 426 of 520 trials lifted, 8 sheets won and none lost; it acted in 3 of 157 rigid A lifts (a CD and a
cork coaster, their small round overhangs seen drooping), which rose 2-4 cm higher and held as before.

``--policy.contact_b_steady=true`` (with ``contact_from_hand``): B's squeeze and lift keep the orientation the
hand has at their start (its commanded orientation: translations only), as the expert's ``b_squeeze`` and
``b_lift`` do; without it they end in the hand's orientation turned by the learned change (0.5-12 degrees).
A turn of hands that clamp a board shifts its finger pads on the faces: the boards B lifted slid down and
pivoted out during the hold (``laptop_15in`` seed 1000: lifted 11.5 cm clear, then tilted about the
squeeze axis, its lower edge on the table 2 s later and dropped; ``album_large_leather``, ``board_cork``,
``painting_seascape`` alike, against the true pose).  With the orientation kept all four held; the
gripper opened fully instead (the expert's ``B_OPEN``) held one of the four.

``--policy.contact_b_align=true`` (with ``observed``): B's touch turned about the vertical so that the finger axis
lies along the nearest side of the seen outline (:func:`b_align_turn`: the smallest rectangle around the seen
points from above), as the expert's fingers lie along the object's side; the touch's positions turn with it
about the seen centre (:func:`b_aligned`), so it approaches at right angles to that side and ``contact_b_face``
finds the side, not a corner: with the fingers turned alone, the touch of a square album turned 22 degrees
(``album_wedding`` seed 1004) stopped at its corner's reach and the squeeze closed 1-1.5 cm short of both
sides.  The learned fingers stood 4-7 degrees off the side of a board turned 18 degrees (``board_oak_shelf``,
``board_pine_plank`` seed 1001): with ``contact_b_steady`` alone the board pivoted out of the hands during the
hold; where the learned turn of the squeeze happened to align the hands, it held.  With the touch aligned, both
held.  Measured with ``contact_b_steady`` (docs/unified.md, stop 42; paired on one build): B's trials 193 -> 223
of 231 lifted, 35 won and 5 lost.

``--policy.contact_grip_closed=true`` (with ``observed``): in A's and C's grasp the pinching hand (the commanded
arm whose learned gripper closes most) closes to 0 and its lift keeps the gripper at 0, as the expert's
``a_grasp`` / ``c_pinch`` close to 0 and ``a_lift`` / ``c_lift`` hold at 0; the learned opening widths are
dropped there (the other arm's stay learned).  The learned C pinch closed to 2.7 cm and its lift opened from
0.1 to 1.1 cm on the way up: ``skirt_pencil`` (seed 1000) hung 23 cm from the pinch, then slid out of it and
fell back onto the table (the stage log against the true pose); closed, it held (so did ``skirt_a_line``
seed 1002; ``scarf_silk_blue`` and ``fabric_linen`` pinched no fold either way).  Measured (docs/unified.md,
stop 42; paired on one build): A 166 -> 168 of 185, C 67 -> 66 of 104 (7 won, 8 lost): no measurable effect.

``--policy.contact_a_slide_full=true`` (with ``observed``): A's slide goes the expert's whole ``slide_distance``
for the overhang still missing, as seen on the cloud at the slide's start, straight along +x as the expert's
slide (:func:`full_slide`), instead of the learned slide capped at it.  The learned first slide stopped short:
on desk 5 (``magazine_comics_digest``, stop 43) it went 30 cm where the rule asked 43 cm, so passes 2 and 3 ran
(3.8 and 7.2 cm) and the attempt took 317 steps against the expert's 180 for an A object: the time
the desks ran out of.  With it that desk was cleared.  Measured (docs/unified.md, stop 43; paired on one build):
the 30 desks 10 -> 14 cleared, but the 104 x 5 run 457 -> 446 lifted (A's trials 168 -> 157: 9 of the 16 lost
were pushed off the table, 7 sheets not aloft), so Table 1's row runs without it.

``--policy.contact_a_touch=true`` (with ``observed``): A's push-pass touch comes straight down at the expert's
press point, ``A_PRESS_BEHIND`` (2 cm) behind the seen object's centre (:func:`a_touch_xy`; the expert's
``_a_press_pose`` from the true centre), instead of at the learned point.  On a desk the executor, trained on
one object per scene, put the touch on a neighbour: desk 25 (stop 43, front camera) pressed the right hand
onto ``laptop_13in`` 20 cm from the target ``pad_memo``, at the pad's contact height, and the laptop and a
painting beside it were thrown off the table; the desk could not be cleared after that.
"""

from __future__ import annotations

import cv2
import numpy as np

from flatlab_lerobot.policies import seen_points
from flatlab_lerobot.strategies.a_push_to_edge import (
    A_PREAPPROACH,
    A_PRESS_BEHIND,
    A_PRESS_DEPTH,
    A_SHEET_LIFT_MARGIN,
    arm_on_side,
    overhang_missing,
    slide_distance,
)
from flatlab_lerobot.strategies.c_fold_pinch import (
    C_END_HALF_GAP,
    C_STRADDLE_ABOVE,
    C_TOUCH_ABOVE,
    pinch_tcp_z,
    press_tcp_z,
)
from flatlab_lerobot.strategies.b_squeeze import B_SQUEEZE
from flatlab_lerobot.strategies.registry import STAGE_SPECS
from flatlab_lerobot.strategies.world import FINGER_HALF_WIDTH, FINGER_TIP_BELOW_TCP

CONTACT_CHOICES = ("learned", "observed")
GRIP_CLOSED_STRATEGIES = ("A", "C")  # contact_grip_closed: the strategies whose grasp pinches (B squeezes open)
FROM_HAND_STRATEGIES = ("A", "B")  # contact_from_hand: their "current" stages start at the hand (C: see above)
B_FACE_QUANTILE = 0.5  # percentile of the seen points along the approach taken as the face (a few stray points)
TOP_QUANTILE = 95  # percentile of the cloud's z taken as the object's top (a few stray points above)
TOP_RADIUS = 0.04  # m: the top under the contact point, from the points this close in x, y
MIN_POINTS = 10  # fewer seen points than this: the learned height stays
A_TOUCH_ABOVE = 0.06  # the expert's touch starts this far above its press pose (a_touch)
B_MIN_HEIGHT, B_BELOW_TOP = 0.014, 0.04  # b_squeeze._b_targets: table + max(1.4 cm, thickness - 4 cm)


def object_top(points: np.ndarray, xy: np.ndarray | None = None) -> float | None:
    """The object's top (m) under ``xy`` (within TOP_RADIUS), or of the whole cloud; None if unseen."""
    if len(points) < MIN_POINTS:
        return None
    if xy is not None:
        near = points[np.linalg.norm(points[:, :2] - np.asarray(xy, float)[:2], axis=1) < TOP_RADIUS]
        if len(near) >= MIN_POINTS:
            points = near
    return float(np.percentile(points[:, 2], TOP_QUANTILE))


def press_floor(p1: np.ndarray, points: np.ndarray, depth: float) -> tuple[np.ndarray, float]:
    """A's press end ``p1`` (TCP) raised, if need be, so that the fingertips go at most ``depth`` below the seen
    object top under it (:func:`object_top`; the expert's press goes A_PRESS_DEPTH below it), and by how much (m);
    unchanged when the object is unseen there."""
    top = object_top(points, p1[:2])
    if top is None:
        return p1, 0.0
    floor = top + FINGER_TIP_BELOW_TCP - depth
    if p1[2] >= floor:
        return p1, 0.0
    out = np.array(p1, float)
    out[2] = floor
    return out, float(floor - p1[2])


def _overhang(points: np.ndarray, edge_x: float) -> np.ndarray | None:
    """The seen points past the table edge; None when fewer than MIN_POINTS overhang."""
    over = points[points[:, 0] > edge_x]
    return over if len(over) >= MIN_POINTS else None


def overhang_mid(points: np.ndarray, edge_x: float) -> float | None:
    """Mid height (m) of the seen points past the table edge; None when fewer than MIN_POINTS overhang."""
    over = _overhang(points, edge_x)
    return None if over is None else float(0.5 * (over[:, 2].min() + over[:, 2].max()))


A_SHEET_DROOP = 0.004  # m: an overhang seen this far below the table top droops (a sheet); less: rigid


def overhang_droop(points: np.ndarray, table: float, edge_x: float) -> float | None:
    """How far (m) the seen overhang (the points past the table edge) reaches below the table top: ~0 for a
    rigid object's overhang (its top face, some of its side), centimetres for a sheet's drooping one; None
    when fewer than MIN_POINTS overhang."""
    over = _overhang(points, edge_x)
    return None if over is None else float(table - over[:, 2].min())


def seen_sheet_length(points: np.ndarray, droop: float) -> float:
    """A drooping sheet's length (m) as seen: its extent along y, or along x plus the ``droop`` of the part
    that hangs past the edge (foreshortened in x), whichever is longer -- the expert's ``max(size x, y)``."""
    ext = points[:, :2].max(0) - points[:, :2].min(0)
    return float(max(ext[0] + droop, ext[1]))


def sheet_lift_end(p0: np.ndarray, p1: np.ndarray, points: np.ndarray, table: float, edge_x: float):
    """A's lift ``p0 -> p1`` (``contact_a_sheet_lift``): where the seen overhang droops (a sheet,
    ``droop >= A_SHEET_DROOP``) the lift rises at least the seen length + A_SHEET_LIFT_MARGIN, its learned
    horizontal drift kept; otherwise unchanged.  Returns (end, the stage log's entry)."""
    p1 = np.array(p1, float)
    droop = overhang_droop(points, table, edge_x)
    log = {"droop": droop}
    if droop is not None and droop >= A_SHEET_DROOP:
        log["rise"] = rise = seen_sheet_length(points, droop) + A_SHEET_LIFT_MARGIN
        p1[2] = max(p1[2], p0[2] + rise)
    return p1, log


def _a(index: int, primitive: str, points: np.ndarray, xy, table: float, edge_x: float):
    if index < A_PREAPPROACH:  # a push pass
        top = object_top(points, xy)
        if top is None:
            return None, None
        touch, press = top + FINGER_TIP_BELOW_TCP + 0.002, top + FINGER_TIP_BELOW_TCP - A_PRESS_DEPTH
        return {"touch": (press + A_TOUCH_ABOVE, touch), "press": (touch, press), "slide": (press, press),
                "release": (press, None)}[primitive]  # fmt: skip
    pinch = overhang_mid(points, edge_x)
    if pinch is None or primitive not in ("touch", "grasp", "lift"):  # the approach is A's 'touch' stage
        return None, None
    return (pinch, None) if primitive == "lift" else (pinch, pinch)


def _b(index: int, primitive: str, points: np.ndarray, xy, table: float, edge_x: float):
    top = object_top(points)
    if top is None or primitive not in ("touch", "squeeze", "lift"):
        return None, None
    z = table + max(B_MIN_HEIGHT, top - table - B_BELOW_TOP)
    return (z, None) if primitive == "lift" else (z, z)


def _c(index: int, primitive: str, points: np.ndarray, xy, table: float, edge_x: float):
    press, pinch = press_tcp_z(table), pinch_tcp_z(table)
    return {"touch": (press + C_TOUCH_ABOVE, press), "squeeze": (press, press),
            "press": (pinch + C_STRADDLE_ABOVE, pinch), "grasp": (pinch, pinch),
            "lift": (pinch, None)}.get(primitive, (None, None))  # fmt: skip


# strategy -> (index, primitive, points, contact xy, table top, edge x) -> (z start, z end)
RULES = {"A": _a, "B": _b, "C": _c}


C_PINCH_STAGES = ("press", "grasp", "lift")  # C's stages of the pinching hand (the other one stays out of the way)


def contact_heights(strategy: str, index: int, primitive: str, points: np.ndarray, xy, table: float, edge_x: float,
                    pinching: bool = True):  # fmt: skip
    """(z of the start, z of the end) for one commanded arm's motion of this stage; None: keep the learned.
    ``pinching``: in C's pinch stages, whether this arm is the pinching one (the other keeps its learned heights)."""
    rule = RULES.get(strategy)
    if rule is None or (strategy == "C" and primitive in C_PINCH_STAGES and not pinching):
        return None, None
    return rule(index, primitive, points, xy, table, edge_x)


def contact_xy(primitive: str, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Where a stage's motion ``p0 -> p1`` meets the object, for the rules' heights: where a touch ends, else where
    the motion starts."""
    return p1[:2] if primitive == "touch" else p0[:2]


def apply_heights(p0: np.ndarray, p1: np.ndarray, z0: float | None, z1: float | None) -> tuple[np.ndarray, np.ndarray]:
    """The motion with its heights set; a missing one keeps the learned displacement from the other."""
    p0, p1 = np.array(p0, float), np.array(p1, float)
    if z0 is not None and z1 is not None:
        p0[2], p1[2] = z0, z1
    elif z0 is not None:
        p1[2] += z0 - p0[2]
        p0[2] = z0
    elif z1 is not None:
        p0[2] += z1 - p1[2]
        p1[2] = z1
    return p0, p1


def object_footprint_x(object_cloud: np.ndarray) -> tuple[float, float] | None:
    """(largest x, extent along x) of the seen object points (all-zero rows are unseen); None if none.
    What the expert's push-pass rules read from the privileged footprint."""
    pts = seen_points(object_cloud)
    if not len(pts):
        return None
    return float(pts[:, 0].max()), float(pts[:, 0].max() - pts[:, 0].min())


def slide_cap(points: np.ndarray, edge_x: float) -> float | None:
    """The longest slide along +x (m) the expert's rule allows for the object as seen; None if unseen."""
    if len(points) < MIN_POINTS:
        return None
    max_x, length_x = object_footprint_x(points)
    return slide_distance(overhang_missing(max_x, length_x, edge_x), length_x)


def shortened(p0: np.ndarray, p1: np.ndarray, length: float, cap: float | None, dims=slice(None)) -> np.ndarray:
    """``p1`` moved back along the motion ``p0 -> p1`` (its coordinates ``dims``) so that the motion's
    ``length`` (however the caller measures it) becomes at most ``cap`` (negative: no motion); unchanged
    when ``cap`` is None or the motion does not go forwards."""
    p1 = np.array(p1, float)
    if cap is None or length <= 0 or length <= cap:
        return p1
    p1[dims] = p0[dims] + (p1[dims] - p0[dims]) * (max(cap, 0.0) / length)
    return p1


def cap_slide(p0: np.ndarray, p1: np.ndarray, cap: float | None) -> np.ndarray:
    """The slide's end moved back along its own direction so that its x advance is at most ``cap``."""
    return shortened(p0, p1, float(p1[0] - p0[0]), cap)


def a_touch_xy(points: np.ndarray) -> np.ndarray | None:
    """(x, y) of A's press point on the seen object: ``A_PRESS_BEHIND`` behind the centre of its cloud, as the
    expert's ``_a_press_pose`` from the true centre; None when too few points are seen."""
    if len(points) < MIN_POINTS:
        return None
    return seen_centre(points) - np.r_[A_PRESS_BEHIND, 0.0]


def full_slide(p0: np.ndarray, p1: np.ndarray, cap: float | None) -> np.ndarray:
    """The slide's end ``cap`` ahead of its start along +x, level with its start (the expert's slide: straight
    along +x, ``slide_distance`` long); its height as given; unchanged when the object is unseen."""
    if cap is None:
        return np.array(p1, float)
    return np.r_[p0[0] + max(cap, 0.0), p0[1], p1[2]]


def seen_centre(points: np.ndarray) -> np.ndarray:
    """(x, y) of the seen object's centre: the mean of its cloud (the expert reads the sheet's centroid)."""
    return points[:, :2].mean(0)


def squeeze_end(p0: np.ndarray, p1: np.ndarray, points: np.ndarray) -> np.ndarray:
    """C's squeeze end moved along the squeeze's own horizontal direction to stop C_END_HALF_GAP short of
    the seen cloth's centre (never behind its start); unchanged when the cloth is unseen or it does not move."""
    d = np.asarray(p1[:2], float) - np.asarray(p0[:2], float)
    if len(points) < MIN_POINTS or np.linalg.norm(d) < 1e-6:
        return p1
    d /= np.linalg.norm(d)
    reach = max(float((seen_centre(points) - np.asarray(p0[:2], float)) @ d) - C_END_HALF_GAP, 0.0)
    end = np.array(p1, float)
    end[:2] = np.asarray(p0[:2], float) + reach * d
    return end


def c_pinch_xy(primitive: str, points: np.ndarray, hand_xy) -> np.ndarray | None:
    """Where (x, y) C's pinching hand works in ``primitive``: its press (the straddle) at the seen cloth's
    centre, its grasp and lift where the hand is (``hand_xy``); None: keep the learned (other stages, or
    too few points seen)."""
    if primitive == "press":
        return None if len(points) < MIN_POINTS else seen_centre(points)
    if primitive in ("grasp", "lift"):
        return np.asarray(hand_xy, float)[:2]
    return None


def apply_xy(p0: np.ndarray, p1: np.ndarray, xy) -> tuple[np.ndarray, np.ndarray]:
    """The motion shifted so that it starts at ``xy`` (its learned horizontal displacement kept); None: unchanged."""
    p0, p1 = np.array(p0, float), np.array(p1, float)
    if xy is not None:
        shift = np.asarray(xy, float)[:2] - p0[:2]
        p0[:2] += shift
        p1[:2] += shift
    return p0, p1


def a_side_arm(points: np.ndarray) -> str | None:
    """The arm that grasps A's overhang (or, ``contact_a_pusher_side``, pushes it): the one on the side of the
    seen object's centre (``right`` at y <= 0, as the expert's ``_a_grasp_arm`` and ``_a_arm``); None when too
    few points are seen."""
    if len(points) < MIN_POINTS:
        return None
    return arm_on_side(float(seen_centre(points)[1]))


def mirror_pose(p: np.ndarray, R: np.ndarray, y_centre: float) -> tuple[np.ndarray, np.ndarray]:
    """A TCP pose mirrored across the vertical plane y = ``y_centre``: the position reflected, the
    approach (z) and finger (y) axes reflected, x completing a right-handed frame, so a finger axis that
    points up still points up (``tcp_rotation``'s convention for the other arm's mirrored approach)."""
    p = np.array(p, float)
    p[1] = 2.0 * y_centre - p[1]
    S = np.diag([1.0, -1.0, 1.0])
    return p, S @ np.asarray(R, float) @ np.diag([-1.0, 1.0, 1.0])


def a_side_arms(learned: list[str], prob: dict[str, float], side: str | None,
                preapproach: bool = False) -> tuple[list[str], str | None]:  # fmt: skip
    """(arms commanded, arm whose learned motion is mirrored onto ``side`` or None) for one of A's grasp
    stages: the rule's arm alone, with its own learned motion, or, where the executor does not command it,
    with the mirror image of the most active learned arm's motion.  In the ``preapproach`` the learned arms
    stay when they include the rule's arm (the expert backs the pusher off there); with no side known,
    the learned arms.  After it the expert commands the grasping arm only: a second learned arm (the
    pusher, 10 cm above the object after its release) was driven down onto the object by the grasp's
    height rule and held it on the table (``magazine_tv_guide``, ``diskcase_dvd``, seed 1003)."""
    if side is None:
        return learned, None
    if side in learned:
        return (learned if preapproach else [side]), None
    return [side], max(learned, key=prob.get)


def starts_at_hand(strategy: str, index: int, from_hand: bool) -> bool:
    """Whether ``contact_from_hand`` starts stage ``index`` of ``strategy`` at the commanded hand: the
    expert starts it where the hand is (A's press, slide, release, grasp, lift; B's squeeze, lift)."""
    return from_hand and strategy in FROM_HAND_STRATEGIES and STAGE_SPECS[strategy][index].start == "current"


def turned_from_hand(R0: np.ndarray, R1: np.ndarray, R_hand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A learned turn ``R0 -> R1`` started in the hand's orientation: ``(R_hand, R1 R0^T R_hand)``, the same
    turn in the world frame (``contact_from_hand`` and ``continue_from_hand`` alike)."""
    R_hand = np.asarray(R_hand, float)
    return R_hand, R1 @ R0.T @ R_hand


def continued_motion(p0: np.ndarray, R0: np.ndarray, p1: np.ndarray, R1: np.ndarray, hand: np.ndarray,
                     R_hand: np.ndarray, level: bool = False,
                     deeper: float = 0.0) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """``continue_from_hand`` (contact=learned): the learned motion ``(p0, R0) -> (p1, R1)`` moved to start at
    the commanded hand ``(hand, R_hand)``: the same displacement ``p1 - p0`` and the same turn ``R1 R0^T``
    (world frame, :func:`turned_from_hand`), so the runner needs no transit to the start.  ``level`` (a
    slide, ``continue_level_slide``; a squeeze, ``continue_level_squeeze``): the displacement's vertical part
    is dropped, the hand moves at its height as the expert's slide and squeeze do in every demo; ``deeper`` (a press,
    ``continue_press_deeper``): the press ends that much lower than learned.  Reads no cloud:
    proprioception only."""
    here = np.asarray(hand, float)
    Ra, Rb = turned_from_hand(R0, R1, R_hand)
    d = np.asarray(p1, float) - np.asarray(p0, float)
    if level:
        d[2] = 0.0
    d[2] -= deeper
    return (here.copy(), Ra), (here + d, Rb)


def b_from_hand(primitive: str, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """B's squeeze or lift started at the hand (``contact_from_hand``): the squeeze runs at most the expert's
    B_SQUEEZE along its own horizontal direction, the lift rises straight (its learned horizontal drift
    dropped), as the expert's do.  With the learned starts a transit back outwards relaxed the squeeze before
    each of them; from the hand the learned 3-4 cm squeeze and 1 cm inward lift pressed 3.4 cm into a plywood
    board's sides (``board_plywood``, seed 1000) and it dropped during the hold."""
    p1 = np.array(p1, float)
    if primitive == "lift":
        p1[:2] = p0[:2]
    elif primitive == "squeeze":
        p1 = shortened(p0, p1, float(np.linalg.norm(p1[:2] - p0[:2])), B_SQUEEZE, dims=slice(0, 2))
    return p1


def b_touch_at_face(p0: np.ndarray, p1: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """B's touch ``p0 -> p1`` moved along its own horizontal direction so that it ends FINGER_HALF_WIDTH
    outside the face of the seen cloud it approaches (the points' B_FACE_QUANTILE-th percentile along the
    approach, from the seen centre); unchanged when the object is unseen or the touch does not move."""
    p0, p1 = np.array(p0, float), np.array(p1, float)
    d = p1[:2] - p0[:2]
    if len(points) < MIN_POINTS or np.linalg.norm(d) < 1e-6:
        return p0, p1
    d /= np.linalg.norm(d)
    c = seen_centre(points)
    face = float(np.percentile((points[:, :2] - c) @ d, B_FACE_QUANTILE))  # < 0: the face the hand comes to
    shift = (face - FINGER_HALF_WIDTH - float((p1[:2] - c) @ d)) * d
    p0[:2] += shift
    p1[:2] += shift
    return p0, p1


def _seen_rect(points: np.ndarray):
    """The smallest rectangle around the seen object's points seen from above (``cv2.minAreaRect``: centre, size,
    angle); None when it is unseen."""
    if len(points) < MIN_POINTS:
        return None
    return cv2.minAreaRect(np.ascontiguousarray(points[:, :2], dtype=np.float32))


def seen_sides(points: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The horizontal directions (unit, (2,)) of the two sides of the seen object's outline: the edges of
    :func:`_seen_rect`; None when it is unseen."""
    rect = _seen_rect(points)
    if rect is None:
        return None
    box = cv2.boxPoints(rect).astype(float)
    sides = [box[1] - box[0], box[2] - box[1]]
    if min(float(np.linalg.norm(e)) for e in sides) < 1e-6:
        return None
    return sides[0] / np.linalg.norm(sides[0]), sides[1] / np.linalg.norm(sides[1])


def seen_width(points: np.ndarray) -> float | None:
    """The seen object's shorter horizontal side (m): the shorter edge of :func:`_seen_rect`; None when it is unseen."""
    rect = _seen_rect(points)
    return None if rect is None else float(min(rect[1]))


def b_align_turn(R: np.ndarray, points: np.ndarray) -> float | None:
    """The turn about the vertical (rad) that lays the finger axis (the hand's y, ``R[:, 1]``) of B's touch
    along the nearest side of the seen outline (:func:`seen_sides`), as the expert's fingers lie along the
    object's side (``b_squeeze._b_targets``: the finger axis at right angles to the squeeze axis); None when
    the object is unseen or the finger axis is vertical."""
    sides = seen_sides(points)
    y = np.asarray(R, float)[:2, 1]
    if sides is None or np.linalg.norm(y) < 1e-6:
        return None
    y = y / np.linalg.norm(y)
    d = max((s * e for e in sides for s in (1.0, -1.0)), key=lambda c: float(c @ y))
    return float(np.arctan2(y[0] * d[1] - y[1] * d[0], float(y @ d)))


def turned_about_z(R: np.ndarray, angle: float) -> np.ndarray:
    """``R`` turned by ``angle`` (rad) about the world's vertical."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.asarray(R, float)


def b_aligned(p0: np.ndarray, p1: np.ndarray, R0: np.ndarray, R1: np.ndarray, points: np.ndarray):
    """B's learned touch ``(p0, R0) -> (p1, R1)`` turned about the vertical through the seen centre by
    :func:`b_align_turn` (its fingers then lie along the seen side, its approach at right angles to that
    side, where the learned approach was at right angles to the learned fingers).  Returns
    ``(p0, p1, R0, R1, turn)``; unchanged with ``turn`` None when there is nothing to align to."""
    turn = b_align_turn(R1, points)
    if turn is None:
        return p0, p1, R0, R1, None
    c = seen_centre(points)
    Rz = turned_about_z(np.eye(3), turn)
    p0, p1 = (np.r_[c[:2] + Rz[:2, :2] @ (np.asarray(p[:2], float) - c[:2]), p[2]] for p in (p0, p1))
    return p0, p1, turned_about_z(R0, turn), turned_about_z(R1, turn), turn


def b_centred(p0: np.ndarray, p1: np.ndarray, R1: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """B's touch ``p0 -> p1`` shifted along its finger axis (the hand's y, ``R1[:, 1]``, horizontal) so that the
    hand faces the seen centre, as the expert's two hands face each other across the object's centre
    (``b_squeeze._b_targets``); unchanged when the object is unseen or the finger axis is vertical.  Learned
    touches 9 cm apart along the side squeezed a painting off-centre and it crept 1.6 cm in the hold (desk 25)."""
    y = np.asarray(R1, float)[:2, 1]
    if len(points) < MIN_POINTS or np.linalg.norm(y) < 1e-6:
        return np.array(p0, float), np.array(p1, float)
    y = y / np.linalg.norm(y)
    off = float((np.asarray(p1, float)[:2] - seen_centre(points)) @ y)
    return tuple(np.r_[np.asarray(p[:2], float) - off * y, p[2]] for p in (p0, p1))


def observed_motion(
    strategy: str, index: int, primitive: str, p0: np.ndarray, p1: np.ndarray, points: np.ndarray,
    table: float, edge_x: float, pinching: bool, hand, from_hand: bool = False, b_face: bool = False,
    a_grasp: bool = False, a_sheet_lift: bool = False, b_steady: bool = False, a_slide_full: bool = False,
    a_touch: bool = False,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """One commanded arm's learned motion ``p0 -> p1`` of this stage with every rule above applied: the
    heights, A's slide cap, C's pinch position and C's squeeze length.  ``pinching``: this arm is the one
    whose learned gripper closes most; ``hand()``: where this arm's hand is, (3,) (called only for C's
    pinch and, with ``from_hand``, for the stages :func:`starts_at_hand` names, which then start exactly
    there: the rules' end height kept where they set one, else the learned displacement).  ``b_face``:
    B's touch ends at the seen face (:func:`b_touch_at_face`).  ``a_grasp``: A's pre-approach starts at the
    hand and ends at its learned pose (``log["line"]``: the caller keeps the learned end orientation and
    gives the line the stage's transit time); A's grasp closes without moving (``log["still"]``: the caller
    keeps the start orientation).  ``a_sheet_lift``: A's lift of a seen sheet rises at least its length + 8 cm
    (:func:`sheet_lift_end`; ``log["sheet_lift"]``).  ``b_steady`` (with ``from_hand``): B's squeeze and lift
    keep the hand's orientation (``log["steady"]``: the caller ends them in the start orientation).
    ``a_slide_full``: A's slide goes the whole expert's distance (:func:`full_slide`), not at most it.
    ``a_touch``: A's push-pass touch comes straight down at the seen press point (:func:`a_touch_xy`).
    Returns the motion and what was decided (the stage log)."""
    log: dict = {"learned": [float(p0[2]), float(p1[2])]}
    if a_grasp and strategy == "A" and index == A_PREAPPROACH:
        log["line"] = True
        return np.asarray(hand(), float).copy(), np.array(p1, float), log
    if b_face and strategy == "B" and primitive == "touch":
        p0, p1 = b_touch_at_face(p0, p1, points)
        log["b_face"] = [float(v) for v in p1[:2]]
    if a_touch and strategy == "A" and primitive == "touch" and index < A_PREAPPROACH:
        xy = a_touch_xy(points)
        if xy is not None:  # straight down there, as the expert's touch
            p0, p1 = np.r_[xy, p0[2]], np.r_[xy, p1[2]]
            log["a_touch"] = [float(v) for v in xy]
    at_hand = starts_at_hand(strategy, index, from_hand)
    if at_hand:
        here = np.asarray(hand(), float)
        p0, p1 = apply_xy(p0, p1, here[:2])
    z = contact_heights(strategy, index, primitive, points, contact_xy(primitive, p0, p1), table, edge_x, pinching=pinching)
    log["observed"] = list(z)
    p0, p1 = apply_heights(p0, p1, *z)
    if at_hand:  # exactly where the hand is, so the runner needs no transit to the start
        p1 = p1 + (here - p0) * [0.0, 0.0, z[1] is None]  # xy already moved; z too unless the rule set it
        p0 = here.copy()
        log["from_hand"] = True
        if strategy == "B":  # no transit relaxes the squeeze any more: the expert's squeeze length, a straight lift
            p1 = b_from_hand(primitive, p0, p1)
            if b_steady:  # and no turn of the clamping hands, as the expert's squeeze and lift
                log["steady"] = True
    if a_grasp and strategy == "A" and primitive == "grasp":  # the expert's grasp closes where the hand is
        p1 = p0.copy()
        log["still"] = True
    if a_sheet_lift and strategy == "A" and primitive == "lift":
        p1, log["sheet_lift"] = sheet_lift_end(p0, p1, points, table, edge_x)
    if strategy == "A" and primitive == "slide":
        cap = slide_cap(points, edge_x)
        log["slide"] = {"learned_dx": float(p1[0] - p0[0]), "cap": cap}
        p1 = full_slide(p0, p1, cap) if a_slide_full else cap_slide(p0, p1, cap)
    if strategy == "C" and pinching and primitive in C_PINCH_STAGES:
        p0, p1 = apply_xy(p0, p1, c_pinch_xy(primitive, points, hand()))
    if strategy == "C" and primitive == "squeeze":
        log["squeeze"] = {"learned_end": [float(v) for v in p1[:2]]}
        p1 = squeeze_end(p0, p1, points)
    return p0, p1, log

"""``--policy.contact=observed`` (observed_contact.py): the expert's height and slide rules evaluated on
the observed cloud, checked against the expert's own poses for the same object."""

import numpy as np
import pytest

from flatlab_lerobot.policies.unified.configuration_flatlab_unified import FlatLabUnifiedConfig
from flatlab_lerobot.policies.unified.observed_contact import (
    apply_heights,
    a_touch_xy,
    apply_xy,
    b_align_turn,
    b_aligned,
    b_centred,
    b_from_hand,
    b_touch_at_face,
    c_pinch_xy,
    cap_slide,
    full_slide,
    contact_heights,
    continued_motion,
    object_top,
    observed_motion,
    overhang_mid,
    press_floor,
    seen_sides,
    seen_width,
    shortened,
    slide_cap,
    squeeze_end,
    turned_about_z,
)
from flatlab_lerobot.strategies.a_push_to_edge import a_press, a_slide, a_touch, slide_distance
from flatlab_lerobot.strategies.world import FINGER_HALF_WIDTH, FINGER_TIP_BELOW_TCP

TABLE, EDGE = 0.75, 0.30


def _box_cloud(centre, size, n=2000, seed=0):
    """What cameras see of an axis-aligned box resting on the table: its top face (80 % of the points)
    and its sides."""
    rng = np.random.default_rng(seed)
    lo = np.r_[centre[0] - size[0] / 2, centre[1] - size[1] / 2, TABLE]
    pts = lo + rng.random((n, 3)) * np.asarray(size)
    pts[: int(0.8 * n), 2] = TABLE + size[2]
    return pts


def test_object_top_is_local_when_the_contact_point_has_points():
    thin, thick = _box_cloud((0.0, -0.1), (0.1, 0.1, 0.005)), _box_cloud((0.0, 0.1), (0.1, 0.1, 0.05), seed=1)
    pts = np.r_[thin, thick]
    assert object_top(pts, (0.0, -0.1)) == pytest.approx(TABLE + 0.005, abs=5e-4)  # the thin part under the finger
    assert object_top(pts) == pytest.approx(TABLE + 0.05)  # no contact point: the whole cloud
    assert object_top(pts, (1.0, 1.0)) == object_top(pts)  # nothing near: the whole cloud
    assert object_top(pts[:5]) is None  # too few points seen


def test_a_push_heights_are_the_experts_for_the_seen_top():
    from flatlab_lerobot.strategies import World

    pts = _box_cloud((0.0, 0.0), (0.12, 0.12, 0.004))
    top = object_top(pts, (0.0, 0.0))
    touch = contact_heights("A", 0, "touch", pts, (0.0, 0.0), TABLE, EDGE)
    press = contact_heights("A", 1, "press", pts, (0.0, 0.0), TABLE, EDGE)
    slide = contact_heights("A", 2, "slide", pts, (0.0, 0.0), TABLE, EDGE)
    # the expert's own primitives for an object with that top
    w = World(pos=np.r_[0.0, 0.0, TABLE + 0.002], yaw=0.0, size=np.r_[0.12, 0.12, top - TABLE], deformable=False,
              table_height=TABLE, edge_x=EDGE)  # fmt: skip
    ctx: dict = {}
    t = a_touch(None, w, {}, {}, ctx).motions[ctx["arm"]]
    assert touch == pytest.approx((t.start[0][2], t.end[0][2]))
    poses = {ctx["arm"]: t.end}
    p = a_press(None, w, poses, {}, ctx).motions[ctx["arm"]]
    assert press == pytest.approx((p.start[0][2], p.end[0][2]))
    sl = a_slide(None, w, {ctx["arm"]: p.end}, {}, ctx).motions[ctx["arm"]]
    assert slide == pytest.approx((sl.start[0][2], sl.end[0][2]))
    assert touch[1] == pytest.approx(top + FINGER_TIP_BELOW_TCP + 0.002)


def test_a_grasp_at_the_overhang_mid_height_and_b_squeeze_rule():
    board = _box_cloud((EDGE, 0.0), (0.2, 0.2, 0.01))  # half of it past the edge
    assert overhang_mid(board, EDGE) == pytest.approx(TABLE + 0.005, abs=5e-4)
    assert contact_heights("A", 13, "touch", board, None, TABLE, EDGE)[0] == pytest.approx(TABLE + 0.005, abs=5e-4)
    assert contact_heights("A", 15, "lift", board, None, TABLE, EDGE)[1] is None  # the learned lift stays
    assert overhang_mid(_box_cloud((0.0, 0.0), (0.2, 0.2, 0.01)), EDGE) is None  # nothing overhangs yet
    thin, thick = _box_cloud((0, 0), (0.3, 0.2, 0.015)), _box_cloud((0, 0), (0.3, 0.2, 0.08))
    assert contact_heights("B", 2, "squeeze", thin, None, TABLE, EDGE)[0] == pytest.approx(TABLE + 0.014)
    assert contact_heights("B", 2, "squeeze", thick, None, TABLE, EDGE)[0] == pytest.approx(TABLE + 0.04)
    assert contact_heights("C", 2, "release", thin, None, TABLE, EDGE) == (None, None)  # C's release: learned
    assert contact_heights("C", 5, "press", thin, None, TABLE, EDGE, pinching=False) == (None, None)  # the other hand


def test_c_heights_are_the_experts_and_the_squeeze_stops_short_of_the_seen_centre():
    from flatlab_lerobot.strategies import World
    from flatlab_lerobot.strategies.c_fold_pinch import C_END_HALF_GAP, c_lift, c_squeeze, c_straddle, c_touch

    w = World(pos=np.r_[0.02, 0.01, TABLE + 0.002], yaw=0.0, size=np.r_[0.3, 0.25, 0.004], deformable=True,
              table_height=TABLE, edge_x=EDGE)  # fmt: skip
    sheet = _box_cloud((0.02, 0.01), (0.3, 0.25, 0.004))
    rule = {prim: contact_heights("C", i, prim, sheet, None, TABLE, EDGE) for i, prim in
            enumerate(("touch", "squeeze", "release", "move", "move", "press", "grasp", "lift"))}  # fmt: skip
    touch = c_touch(None, w, {}, {}, {})
    for a in ("left", "right"):
        m = touch.motions[a]
        assert rule["touch"] == pytest.approx((m.start[0][2], m.end[0][2]))
        sq = c_squeeze(None, w, {a: m.end for a, m in touch.motions.items()}, {}, {}).motions[a]
        assert rule["squeeze"] == pytest.approx((sq.start[0][2], sq.end[0][2]))
        # a learned squeeze in the same direction that stops 6 cm short ends where the expert's does
        d = sq.end[0] - sq.start[0]
        short = sq.start[0] + d * (1 - 0.06 / np.linalg.norm(d[:2]))
        end = squeeze_end(sq.start[0], short, sheet)
        assert end[:2] == pytest.approx(sq.end[0][:2], abs=2e-3)
        assert abs(float(np.linalg.norm(end[:2] - sheet[:, :2].mean(0)))) == pytest.approx(C_END_HALF_GAP, abs=2e-3)
    st = c_straddle(None, w, {"left": touch.motions["left"].end}, {}, {}).motions["right"]
    assert rule["press"] == pytest.approx((st.start[0][2], st.end[0][2]))
    assert rule["grasp"] == (st.end[0][2], st.end[0][2])
    lift = c_lift(None, w, {"right": st.end}, {}, {}).motions["right"]
    assert rule["lift"] == (pytest.approx(lift.start[0][2]), None)
    p0 = np.r_[0.0, 0.1, 0.76]
    np.testing.assert_array_equal(squeeze_end(p0, p0, sheet), p0)  # no motion: nothing to stretch
    np.testing.assert_array_equal(squeeze_end(p0, p0 + 0.05, sheet[:3]), p0 + 0.05)  # unseen cloth: learned


def test_apply_heights_keeps_the_learned_displacement_where_one_end_is_free():
    p0, p1 = np.r_[0.0, 0.0, 0.80], np.r_[0.05, 0.0, 0.95]
    a, b = apply_heights(p0, p1, 0.76, None)
    assert a[2] == pytest.approx(0.76) and b[2] == pytest.approx(0.91) and b[0] == 0.05
    a, b = apply_heights(p0, p1, 0.76, 0.77)
    assert (a[2], b[2]) == (0.76, 0.77)
    a, b = apply_heights(p0, p1, None, None)
    np.testing.assert_array_equal(a, p0)
    np.testing.assert_array_equal(b, p1)


def test_slide_is_capped_by_the_experts_distance_on_the_seen_cloud():
    disc = _box_cloud((0.15, 0.0), (0.12, 0.12, 0.002))
    cap = slide_cap(disc, EDGE)
    max_x, length = disc[:, 0].max(), np.ptp(disc[:, 0])
    from flatlab_lerobot.strategies.a_push_to_edge import overhang_missing

    assert cap == pytest.approx(slide_distance(overhang_missing(max_x, length, EDGE), length))
    p0 = np.r_[0.1, 0.0, 0.76]
    long = cap_slide(p0, p0 + np.r_[0.3, 0.03, 0.0], cap)
    assert long[0] - p0[0] == pytest.approx(cap) and long[1] - p0[1] == pytest.approx(0.03 * cap / 0.3)
    short = p0 + np.r_[0.5 * cap, 0, 0]
    np.testing.assert_array_equal(cap_slide(p0, short, cap), short)  # a shorter learned slide stays


def test_full_slide_goes_the_experts_distance_straight_along_x():
    """contact_a_slide_full: a learned slide that stops short, or veers, goes the whole expert's distance for
    the seen cloud, straight along +x from where it starts (the expert's slide), at the height it was given;
    an unseen object keeps the learned slide; through ``observed_motion`` only with the switch."""
    disc = _box_cloud((0.15, 0.0), (0.12, 0.12, 0.002))
    cap = slide_cap(disc, EDGE)
    p0 = np.r_[0.1, 0.02, 0.76]
    short = p0 + np.r_[0.3 * cap, 0.01, -0.001]
    np.testing.assert_allclose(full_slide(p0, short, cap), [0.1 + cap, 0.02, 0.759])
    np.testing.assert_array_equal(full_slide(p0, short, None), short)
    hand = np.r_[0.1, 0.02, 0.80]
    _, b, log = observed_motion("A", 2, "slide", p0, short, disc, TABLE, EDGE, False, lambda: hand,
                                from_hand=True, a_slide_full=True)  # fmt: skip
    assert b[0] - hand[0] == pytest.approx(cap) and b[1] == pytest.approx(hand[1])
    assert log["slide"]["cap"] == pytest.approx(cap)
    _, b0, _ = observed_motion("A", 2, "slide", p0, short, disc, TABLE, EDGE, False, lambda: hand, from_hand=True)
    assert b0[0] - hand[0] == pytest.approx(0.3 * cap)  # without the switch the short learned slide stays


def test_a_touch_comes_down_at_the_experts_press_point_on_the_seen_object():
    """contact_a_touch: A's push-pass touch comes straight down 2 cm behind the seen object's centre (the expert's
    press point), whatever the learned touch aimed at; its heights are the rule's; the approach (also a
    "touch") and an unseen object keep the learned motion; through ``observed_motion`` only with the switch."""
    from flatlab_lerobot.strategies.a_push_to_edge import A_PREAPPROACH, A_PRESS_BEHIND, _a_press_pose

    disc = _box_cloud((0.05, -0.1), (0.12, 0.12, 0.004))
    xy = a_touch_xy(disc)
    np.testing.assert_allclose(xy, disc[:, :2].mean(0) - [A_PRESS_BEHIND, 0.0])
    assert a_touch_xy(disc[:3]) is None
    p0, p1 = np.r_[-0.12, 0.06, 0.85], np.r_[-0.13, 0.08, 0.76]  # a learned touch aimed 20 cm away
    a, b, log = observed_motion("A", 0, "touch", p0, p1, disc, TABLE, EDGE, False, None, a_touch=True)
    np.testing.assert_allclose([a[:2], b[:2]], [xy, xy])
    assert log["a_touch"] == pytest.approx(list(xy))
    z = contact_heights("A", 0, "touch", disc, xy, TABLE, EDGE)
    assert (a[2], b[2]) == pytest.approx(z)
    from flatlab_lerobot.strategies import World

    w = World(pos=np.r_[0.05, -0.1, TABLE + 0.002], yaw=0.0, size=np.r_[0.12, 0.12, 0.004], deformable=False,
              table_height=TABLE, edge_x=EDGE)  # fmt: skip
    ctx: dict = {}
    t = a_touch(None, w, {}, {}, ctx).motions[ctx["arm"]]  # the expert's touch: straight down at its press point
    np.testing.assert_allclose([t.start[0][:2], t.end[0][:2]], [_a_press_pose(w)[0][:2]] * 2)
    assert t.end[0][:2] == pytest.approx([0.05 - A_PRESS_BEHIND, -0.1])
    for index, switch, pts in ((0, False, disc), (A_PREAPPROACH + 1, True, disc), (0, True, disc[:3])):
        a, b, _ = observed_motion("A", index, "touch", p0, p1, pts, TABLE, EDGE, False, None, a_touch=switch)
        np.testing.assert_allclose([a[:2], b[:2]], [p0[:2], p1[:2]])


def test_shortened_caps_only_the_named_coordinates_and_never_reverses():
    p0, p1 = np.r_[0.0, 0.0, 0.8], np.r_[0.03, 0.04, 0.7]  # 5 cm horizontally, 10 cm down
    xy = shortened(p0, p1, 0.05, 0.025, dims=slice(0, 2))
    np.testing.assert_allclose(xy, [0.015, 0.02, 0.7])  # half the horizontal motion, the height untouched
    np.testing.assert_allclose(shortened(p0, p1, 0.05, -0.01), p0)  # a negative cap: no motion at all
    for cap in (None, 0.05, 0.2):  # no cap, or one the motion already keeps: unchanged
        np.testing.assert_array_equal(shortened(p0, p1, 0.05, cap), p1)
    np.testing.assert_array_equal(shortened(p0, p1, -0.05, 0.01), p1)  # a motion going backwards: unchanged


def test_contact_switch_is_validated():
    with pytest.raises(ValueError, match="--policy.contact"):
        FlatLabUnifiedConfig(contact="expert")
    for flag in ("contact_from_hand", "contact_b_face", "contact_b_align", "contact_grip_closed",
                 "contact_a_slide_full", "contact_a_touch", "contact_a_pusher_side", "contact_b_centred"):
        with pytest.raises(ValueError, match=f"{flag}=true needs --policy.contact=observed"):
            FlatLabUnifiedConfig(**{flag: True})
        assert getattr(FlatLabUnifiedConfig(contact="observed", **{flag: True}), flag)


def test_from_hand_starts_the_experts_current_stages_at_the_hand_and_caps_the_slide_from_there():
    """contact_from_hand: A's and B's stages the expert starts where the hand is begin at the commanded hand
    with their learned displacement; the slide cap then bounds the push from where the finger is.  Their
    other stages, and C's, are unchanged."""
    disc = _box_cloud((0.15, 0.0), (0.12, 0.12, 0.002))
    hand = np.r_[0.13, 0.01, TABLE + 0.009]
    p0, p1 = np.r_[0.14, -0.005, 0.80], np.r_[0.40, 0.0, 0.80]  # a learned slide starting 1.8 cm off the hand
    a, b, log = observed_motion("A", 2, "slide", p0, p1, disc, TABLE, EDGE, False, lambda: hand, from_hand=True)
    assert a == pytest.approx(hand) and log["from_hand"]  # exactly at the hand
    assert b[0] - a[0] == pytest.approx(slide_cap(disc, EDGE))  # the cap, counted from the hand
    assert b[1] - a[1] == pytest.approx(0.005 * slide_cap(disc, EDGE) / 0.26)  # the learned direction kept
    a0, b0, log0 = observed_motion("A", 2, "slide", p0, p1, disc, TABLE, EDGE, False, lambda: hand)
    assert a0[:2] == pytest.approx(p0[:2]) and a0[2] < 0.78 and "from_hand" not in log0  # off: the learned start
    assert a0[2] == pytest.approx(b0[2]) and a0[2] != pytest.approx(hand[2])  # ... at the rule's press height
    assert b[2] == pytest.approx(b0[2], abs=1e-3)  # the rule's end height is kept from the hand too
    rise = np.r_[0.003, 0.0, 0.1]
    for strategy, index, prim in (("A", 1, "press"), ("A", 3, "release"), ("A", 14, "grasp"), ("A", 15, "lift"),
                                  ("B", 2, "squeeze"), ("B", 3, "lift")):
        a, b, log = observed_motion(strategy, index, prim, p0, p0 + rise, disc, TABLE, EDGE, False, lambda: hand,
                                    from_hand=True)  # fmt: skip
        assert a == pytest.approx(hand) and log["from_hand"], prim
        # A keeps the learned horizontal displacement; B's lift rises straight, its squeeze is the expert's length
        assert b[:2] - a[:2] == pytest.approx(rise[:2] if strategy == "A" else ([0, 0] if prim == "lift" else rise[:2])), prim
        if prim in ("release", "lift"):  # no end height by the rules: the learned rise
            assert b[2] - a[2] == pytest.approx(0.1)
    for strategy, index, prim in (("A", 0, "touch"), ("A", 12, "move"), ("B", 1, "touch"), ("C", 1, "squeeze"),
                                  ("C", 2, "release")):
        a, _, log = observed_motion(strategy, index, prim, p0, p1, disc, TABLE, EDGE, False, lambda: hand,
                                    from_hand=True)  # fmt: skip
        assert a[:2] == pytest.approx(p0[:2]) and "from_hand" not in log, prim


def test_continue_from_hand_moves_the_learned_motion_to_the_hand_and_keeps_its_displacement_and_turn():
    """continue_from_hand (contact=learned): the learned motion starts exactly at the commanded hand, in its
    orientation, and moves by the learned displacement and turns by the learned turn; nothing else."""
    from scipy.spatial.transform import Rotation

    p0, p1 = np.r_[0.14, -0.005, 0.80], np.r_[0.40, 0.01, 0.79]
    R0 = Rotation.from_euler("xyz", [180, 0, 10], degrees=True).as_matrix()
    R1 = Rotation.from_euler("z", 25, degrees=True).as_matrix() @ R0  # a learned 25-degree turn about z
    hand, R_hand = np.r_[0.13, 0.01, 0.759], Rotation.from_euler("xyz", [180, 5, 0], degrees=True).as_matrix()
    (a, Ra), (b, Rb) = continued_motion(p0, R0, p1, R1, hand, R_hand)
    assert a == pytest.approx(hand) and Ra == pytest.approx(R_hand)
    assert b - a == pytest.approx(p1 - p0)
    assert Rb @ Ra.T == pytest.approx(R1 @ R0.T)  # the same turn, in the world frame
    assert Rotation.from_matrix(Rb @ Ra.T).magnitude() == pytest.approx(np.radians(25))
    with pytest.raises(ValueError, match="continue_from_hand=A needs --policy.contact=learned"):
        FlatLabUnifiedConfig(contact="observed", continue_from_hand="A")
    for bad in ("D", "AA", "A,C", "a"):
        with pytest.raises(ValueError, match="--policy.continue_from_hand: distinct letters of ABC"):
            FlatLabUnifiedConfig(continue_from_hand=bad)
    assert FlatLabUnifiedConfig(continue_from_hand="AC").continue_from_hand == "AC"


def test_continued_slide_can_stay_level_and_press_go_deeper():
    """continue_level_slide drops the learned slide's rise (a learned +1.4 cm over a 25 cm slide lifted the
    finger off a cork coaster, disk_cork_coaster seed 1000) and keeps its horizontal part;
    continue_press_deeper lowers only the press's end; both need continue_from_hand."""
    R = np.eye(3)
    p0, p1, hand = np.r_[-0.02, 0.02, 0.767], np.r_[0.237, 0.03, 0.781], np.r_[-0.016, 0.016, 0.766]
    (a, _), (b, _) = continued_motion(p0, R, p1, R, hand, R, level=True)
    assert b[2] == pytest.approx(hand[2]) and b[:2] - a[:2] == pytest.approx((p1 - p0)[:2])
    (a, _), (b, _) = continued_motion(p0, R, p1, R, hand, R, deeper=0.004)
    assert a == pytest.approx(hand) and b - a == pytest.approx(p1 - p0 - [0, 0, 0.004])
    for flag in ("continue_level_slide", "continue_level_squeeze"):
        with pytest.raises(ValueError, match="continue_level_squeeze need --policy.continue_from_hand"):
            FlatLabUnifiedConfig(**{flag: True})
    with pytest.raises(ValueError, match="continue_press_deeper: metres in"):
        FlatLabUnifiedConfig(continue_from_hand="A", continue_press_deeper=-0.001)


def test_b_squeeze_from_the_hand_is_the_experts_length_and_the_lift_straight():
    from flatlab_lerobot.strategies.b_squeeze import B_SQUEEZE

    p0 = np.r_[0.02, 0.18, 0.764]
    long = b_from_hand("squeeze", p0, p0 + [0.003, -0.041, 0.0])  # the learned 4.1-cm squeeze
    assert np.linalg.norm(long[:2] - p0[:2]) == pytest.approx(B_SQUEEZE) and long[1] < p0[1]
    short = p0 + [0.0, -0.01, 0.0]
    np.testing.assert_array_equal(b_from_hand("squeeze", p0, short), short)  # a shorter one stays
    lift = b_from_hand("lift", p0, p0 + [-0.002, -0.011, 0.15])
    assert lift == pytest.approx(p0 + [0, 0, 0.15])


def test_b_steady_marks_bs_squeeze_and_lift_from_the_hand_only():
    """contact_b_steady: B's squeeze and lift started at the hand are marked ``steady`` (the caller ends them in
    the hand's orientation); B's touch, A's stages and a run without contact_from_hand are not."""
    with pytest.raises(ValueError, match="contact_b_steady=true needs --policy.contact_from_hand=true"):
        FlatLabUnifiedConfig(contact="observed", contact_b_steady=True)
    assert FlatLabUnifiedConfig(contact="observed", contact_from_hand=True, contact_b_steady=True).contact_b_steady
    board = _box_cloud((0.0, 0.0), (0.36, 0.25, 0.022))
    hand = np.r_[0.01, 0.15, 0.765]
    p0, p1 = np.r_[0.012, 0.149, 0.77], np.r_[0.011, 0.124, 0.77]
    for strategy, index, prim, from_hand, want in (("B", 2, "squeeze", True, True), ("B", 3, "lift", True, True),
                                                    ("B", 1, "touch", True, False), ("B", 2, "squeeze", False, False),
                                                    ("A", 2, "slide", True, False)):  # fmt: skip
        _, _, log = observed_motion(strategy, index, prim, p0, p1, board, TABLE, EDGE, False, lambda: hand,
                                    from_hand=from_hand, b_steady=True)  # fmt: skip
        assert log.get("steady", False) is want, (strategy, prim, from_hand, log)
    _, _, log = observed_motion("B", 2, "squeeze", p0, p1, board, TABLE, EDGE, False, lambda: hand, from_hand=True)
    assert "steady" not in log  # the switch off: the learned turn stays


def test_b_align_lays_the_fingers_along_the_seen_side_of_a_turned_board():
    """contact_b_align: a board turned -18.7 degrees (board_oak_shelf, seed 1001) and a learned finger axis 6.7
    degrees off its side: the turn is the 6.7 degrees back onto the side, whichever way the hand faces; the
    fingers then lie along it.  An unseen object or a vertical finger axis: no turn."""
    from flatlab_lerobot.sim.robot import tcp_rotation

    yaw = np.radians(-18.7)
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    board = _box_cloud((0.0, 0.0), (0.40, 0.18, 0.035))
    board[:, :2] = board[:, :2] @ rot.T + [0.013, -0.044]
    along = rot @ [1.0, 0.0]  # the board's long side
    sides = seen_sides(board)
    assert min(abs(float(s @ along)) for s in sides) < 0.02 and max(abs(float(s @ along)) for s in sides) > 0.999
    for sign in (1.0, -1.0):
        off = np.radians(6.7)
        y = sign * np.r_[np.cos(yaw + off), np.sin(yaw + off), 0.0]
        R = tcp_rotation([0, 0, -1], y)
        turn = b_align_turn(R, board)
        assert np.degrees(turn) == pytest.approx(-6.7, abs=0.5)
        assert abs(float(turned_about_z(R, turn)[:2, 1] @ along)) == pytest.approx(1.0, abs=1e-4)
    assert b_align_turn(tcp_rotation([0, 0, -1], [0, 1, 0]), board[:3]) is None  # unseen
    assert b_align_turn(tcp_rotation([1, 0, 0], [0, 0, 1]), board) is None  # fingers vertical


def test_b_aligned_turns_the_touch_about_the_seen_centre_so_it_approaches_the_side_square_on():
    """A square album turned -21.7 degrees (album_wedding, seed 1004) and a learned touch straight along -y with
    the fingers along x: turned about the seen centre, the touch approaches along the album's own axis and
    keeps its distance from the centre; the face rule then stops it FINGER_HALF_WIDTH outside the side (not
    outside the corner, 4.5 cm further out along y)."""
    from flatlab_lerobot.sim.robot import tcp_rotation

    yaw = np.radians(-21.7)
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    centre = np.r_[-0.05, -0.037]
    album = _box_cloud((0.0, 0.0), (0.30, 0.30, 0.05))
    album[:, :2] = album[:, :2] @ rot.T + centre
    R = tcp_rotation([0, 0, -1], [1, 0, 0])
    p0, p1 = np.r_[-0.035, 0.192, 0.764], np.r_[-0.035, 0.154, 0.764]
    a0, a1, R0, R1, turn = b_aligned(p0, p1, R, R, album)
    assert np.degrees(turn) == pytest.approx(-21.7, abs=1.0)
    c = album[:, :2].mean(0)
    for p, a in ((p0, a0), (p1, a1)):
        assert np.linalg.norm(a[:2] - c) == pytest.approx(np.linalg.norm(p[:2] - c)) and a[2] == p[2]
    d = (a1[:2] - a0[:2]) / np.linalg.norm(a1[:2] - a0[:2])
    assert abs(float(d @ (rot @ [0.0, 1.0]))) > 0.999  # along the album's own axis
    _, end = b_touch_at_face(a0, a1, album)
    assert float((end[:2] - centre) @ (rot @ [0.0, 1.0])) == pytest.approx(0.15 + FINGER_HALF_WIDTH, abs=0.004)
    assert b_aligned(p0, p1, R, R, album[:3])[4] is None  # unseen: unchanged


def test_b_centred_slides_each_touch_along_its_fingers_to_face_the_seen_centre():
    """contact_b_centred: desk 25's painting (seen centre (-0.10, 0.19)) and learned touches 9 cm apart along
    the side (x -0.07 and -0.17, fingers along x): each is shifted along its finger axis, keeping its approach
    and height, so both face the centre; a turned finger axis moves the hand along that axis; unseen: unchanged."""
    from flatlab_lerobot.sim.robot import tcp_rotation

    painting = _box_cloud((-0.10, 0.19), (0.26, 0.26, 0.02))
    c = painting[:, :2].mean(0)
    R = tcp_rotation([0, 0, -1], [1, 0, 0])  # fingers along x, approach along y
    left = (np.r_[-0.062, 0.356, 0.764], np.r_[-0.071, 0.322, 0.764])
    right = (np.r_[-0.173, 0.033, 0.764], np.r_[-0.165, 0.060, 0.764])
    for p0, p1 in (left, right):
        a0, a1 = b_centred(p0, p1, R, painting)
        assert a1[0] == pytest.approx(c[0]) and a1[1] == pytest.approx(p1[1]) and a1[2] == p1[2]
        np.testing.assert_allclose(a1 - a0, p1 - p0, atol=1e-12)  # the approach kept
    yaw = np.radians(20.0)
    fingers = np.r_[np.cos(yaw), np.sin(yaw), 0.0]
    a0, a1 = b_centred(*left, tcp_rotation([0, 0, -1], fingers), painting)
    assert float((a1[:2] - c) @ fingers[:2]) == pytest.approx(0.0, abs=1e-12)
    assert np.cross(fingers[:2], a1[:2] - left[1][:2]) == pytest.approx(0.0, abs=1e-12)  # moved along the fingers
    for got, want in zip(b_centred(*left, R, painting[:3]), left):
        np.testing.assert_array_equal(got, want)


def test_b_touch_ends_just_outside_the_seen_face_it_approaches():
    """contact_b_face: a learned touch that ends 4 cm inside a large board's side is moved back along its own
    direction to end FINGER_HALF_WIDTH outside the seen face (the expert's b_touch); one that stops short
    is moved in; the approach's length and its height are kept."""
    board = _box_cloud((0.0, 0.01), (0.25, 0.32, 0.035), n=4000)
    left0, left1 = np.r_[0.015, 0.176, 0.764], np.r_[0.012, 0.140, 0.764]  # the learned left hand (seen)
    a, b = b_touch_at_face(left0, left1, board)
    assert b[1] == pytest.approx(0.01 + 0.16 + FINGER_HALF_WIDTH, abs=3e-3)
    assert b - a == pytest.approx(left1 - left0)
    right0, right1 = np.r_[0.0, -0.30, 0.764], np.r_[0.0, -0.26, 0.764]  # stops 11 cm short of the right face
    _, b = b_touch_at_face(right0, right1, board)
    assert b[1] == pytest.approx(0.01 - 0.16 - FINGER_HALF_WIDTH, abs=3e-3)
    a, b, log = observed_motion("B", 1, "touch", left0, left1, board, TABLE, EDGE, False, None, b_face=True)
    assert b[1] == pytest.approx(0.18, abs=3e-3) and log["b_face"]
    assert b[2] == pytest.approx(TABLE + max(0.014, 0.035 - 0.04))  # the B height rule as before
    _, b, log = observed_motion("B", 1, "touch", left0, left1, board, TABLE, EDGE, False, None)
    assert b[1] == pytest.approx(0.140) and "b_face" not in log  # off: learned
    np.testing.assert_array_equal(b_touch_at_face(left0, left1, board[:3])[1], left1)  # unseen: unchanged


def test_c_pinch_at_the_seen_centre_then_where_the_hand_is():
    sheet = _box_cloud((0.02, 0.03), (0.2, 0.1, 0.03))  # a squeezed sheet with its fold
    centre = c_pinch_xy("press", sheet, (0.5, 0.5))
    assert centre == pytest.approx(sheet[:, :2].mean(0)) and centre == pytest.approx((0.02, 0.03), abs=4e-3)
    assert c_pinch_xy("grasp", sheet, (0.01, 0.02)) == pytest.approx((0.01, 0.02))  # where the hand is
    assert c_pinch_xy("lift", sheet, (0.01, 0.02)) == pytest.approx((0.01, 0.02))
    assert c_pinch_xy("squeeze", sheet, (0.01, 0.02)) is None and c_pinch_xy("press", sheet[:3], None) is None
    p0, p1 = np.r_[0.0, -0.01, 0.82], np.r_[0.003, -0.006, 0.76]  # a straddle: down, a few mm sideways
    a, b = apply_xy(p0, p1, centre)
    assert a[:2] == pytest.approx(centre) and b[:2] - a[:2] == pytest.approx(p1[:2] - p0[:2])
    assert (a[2], b[2]) == (0.82, 0.76)
    a, b = apply_xy(p0, p1, None)
    np.testing.assert_array_equal(b, p1)


def test_a_grasp_arm_is_the_seen_sides_and_a_far_arms_motion_is_mirrored_onto_it():
    from flatlab_lerobot.policies.unified.observed_contact import a_side_arms, a_side_arm, mirror_pose
    from flatlab_lerobot.sim.robot import tcp_rotation

    assert a_side_arm(_box_cloud((0.2, -0.05), (0.28, 0.2, 0.008))) == "right"  # y <= 0: the expert's rule
    assert a_side_arm(_box_cloud((0.2, 0.05), (0.28, 0.2, 0.008))) == "left"
    assert a_side_arm(np.zeros((3, 3))) is None  # too few points: no rule
    # the expert's approach of the left arm, mirrored across the object's centre line, is the right arm's
    yaw, yc = np.radians(35.0), -0.04
    a_left, a_right = np.r_[-np.cos(yaw), -np.sin(yaw), 0.0], np.r_[-np.cos(yaw), np.sin(yaw), 0.0]
    end_left = np.r_[0.34, yc, 0.755] + 0.04 * a_left
    p, R = mirror_pose(end_left, tcp_rotation(a_left, [0, 0, 1]), yc)
    np.testing.assert_allclose(p, np.r_[0.34, yc, 0.755] + 0.04 * a_right, atol=1e-12)
    np.testing.assert_allclose(R, tcp_rotation(a_right, [0, 0, 1]), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    prob = {"left": 0.9, "right": 0.2}
    assert a_side_arms(["left"], prob, "right") == (["right"], "left")  # the far arm's motion, mirrored
    assert a_side_arms(["left", "right"], prob, "right") == (["right"], None)  # the grasping arm only
    assert a_side_arms(["left", "right"], prob, "right", preapproach=True) == (["left", "right"], None)
    assert a_side_arms(["right"], prob, "right") == (["right"], None)
    assert a_side_arms(["left"], prob, None) == (["left"], None)  # nothing seen: learned


def test_contact_a_grasp_needs_observed():
    with pytest.raises(ValueError, match="contact_a_grasp"):
        FlatLabUnifiedConfig(contact_a_grasp=True)
    assert FlatLabUnifiedConfig(contact="observed", contact_a_grasp=True).contact_a_grasp


def test_a_grasp_preapproach_is_a_line_from_the_hand_to_the_learned_pose():
    from flatlab_lerobot.strategies.a_push_to_edge import A_PREAPPROACH

    cloud = _box_cloud((0.25, -0.04), (0.28, 0.2, 0.008))
    hand = np.r_[0.247, -0.033, 0.86]  # the pusher 10 cm above the magazine after its release
    p0, p1 = np.r_[0.43, -0.08, 0.87], np.r_[0.44, -0.083, 0.868]
    args = ("A", A_PREAPPROACH, "move", p0, p1, cloud, TABLE, EDGE, False, lambda: hand)
    a, b, log = observed_motion(*args, a_grasp=True)
    np.testing.assert_array_equal(a, hand)
    np.testing.assert_array_equal(b, p1)
    assert log["line"]
    a, b, log = observed_motion(*args)  # without the switch: the learned transit target, untouched
    np.testing.assert_array_equal(a, p0)
    assert "line" not in log
    a, b, log = observed_motion("A", A_PREAPPROACH + 1, "touch", p0, p1, cloud, TABLE, EDGE, False, lambda: hand,
                                a_grasp=True)  # fmt: skip
    assert "line" not in log  # the approach keeps its learned start (and its transit)


def test_contact_a_backoff_needs_a_grasp_and_is_the_experts_backoff():
    from flatlab_lerobot.strategies import World
    from flatlab_lerobot.strategies.a_push_to_edge import a_preapproach, pusher_backoff

    with pytest.raises(ValueError, match="contact_a_backoff"):
        FlatLabUnifiedConfig(contact="observed", contact_a_backoff=True)
    assert FlatLabUnifiedConfig(contact="observed", contact_a_grasp=True, contact_a_backoff=True).contact_a_backoff
    # the expert's pre-approach backs its pusher off by the same rule: the left arm pushed, the pushes left
    # the object right of the centre, so the right arm grasps
    w = World(pos=np.r_[0.3, -0.01, TABLE + 0.004], yaw=0.0, size=np.r_[0.3, 0.2, 0.008], deformable=False,
              table_height=TABLE, edge_x=EDGE)  # fmt: skip
    hand = np.r_[0.25, 0.05, 0.86]
    poses = {a: (hand, np.eye(3)) for a in ("left", "right")}
    prim = a_preapproach(None, w, poses, {"left": 0.01, "right": 0.01}, {"arm": "left"})
    np.testing.assert_allclose(prim.motions["left"].end[0], pusher_backoff("left", hand))
    np.testing.assert_allclose(pusher_backoff("right", hand) - hand, [-0.05, -0.15, 0.05])


def _draped_sheet(length=0.22, width=0.18, over=0.06, droop=0.03, n=2000, seed=0):
    """What cameras see of a sheet pushed ``over`` past the edge: flat on the table, its overhang hanging
    ``droop`` below the table top at its front edge."""
    rng = np.random.default_rng(seed)
    u = rng.random(n) * length  # along the sheet from its back edge
    x = EDGE - (length - over) + u
    past = np.clip((x - EDGE) / over, 0, 1)
    z = TABLE + 0.003 - droop * past**2
    x = np.where(x > EDGE, EDGE + (x - EDGE) * 0.8, x)  # the hanging part is foreshortened in x
    return np.c_[x, -width / 2 + rng.random(n) * width, z]


def test_a_sheet_lift_rises_a_seen_sheets_length_and_leaves_a_rigid_lift_learned():
    from flatlab_lerobot.strategies.a_push_to_edge import A_PREAPPROACH, A_SHEET_LIFT_MARGIN, STAGES, a_lift

    with pytest.raises(ValueError, match="contact_a_sheet_lift"):
        FlatLabUnifiedConfig(contact_a_sheet_lift=True)
    i = STAGES.index(a_lift)
    assert i > A_PREAPPROACH
    hand = np.r_[0.33, -0.02, 0.755]
    p0, p1 = hand.copy(), hand + [0.05, 0.0, 0.2]  # a learned 20 cm rise
    sheet = _draped_sheet()
    a, b, log = observed_motion("A", i, "lift", p0, p1, sheet, TABLE, EDGE, True, lambda: hand, from_hand=True,
                                a_sheet_lift=True)  # fmt: skip
    assert log["sheet_lift"]["droop"] == pytest.approx(0.03 - 0.003, abs=0.002)  # its lowest point below the table top
    # the sheet's length (22 cm, its longer side) + the expert's margin, from the hand; the drift kept
    assert b[2] - a[2] == pytest.approx(0.22 + A_SHEET_LIFT_MARGIN, abs=0.02)
    np.testing.assert_allclose(b[:2], a[:2] + [0.05, 0.0])
    _, b_off, log_off = observed_motion("A", i, "lift", p0, p1, sheet, TABLE, EDGE, True, lambda: hand, from_hand=True)
    assert b_off[2] - hand[2] == pytest.approx(0.2) and "sheet_lift" not in log_off  # the switch off: learned
    # a rigid board pushed over the edge: its overhang is seen at the table top, the learned rise stays
    board = _box_cloud((EDGE - 0.05, 0.0), (0.26, 0.2, 0.01))
    _, b, log = observed_motion("A", i, "lift", p0, p1, board, TABLE, EDGE, True, lambda: hand, from_hand=True,
                                a_sheet_lift=True)  # fmt: skip
    assert log["sheet_lift"]["droop"] < 0.004 and "rise" not in log["sheet_lift"]
    assert b[2] - hand[2] == pytest.approx(0.2)
    # a learned rise already higher than the sheet's needs stays
    _, b, _ = observed_motion("A", i, "lift", p0, hand + [0, 0, 0.5], sheet, TABLE, EDGE, True, lambda: hand,
                              from_hand=True, a_sheet_lift=True)  # fmt: skip
    assert b[2] - hand[2] == pytest.approx(0.5)


def test_press_floor_bounds_a_deep_press_on_a_thick_object_and_leaves_a_thin_one():
    """continue_press_floor: the fingertips at most ``depth`` below the seen top under the press (desk 88: an 8-mm
    coaster pressed through to the table); a press already above the floor, a thin sheet whose floor lies below the
    table, and an unseen object keep the learned end."""
    coaster = _box_cloud((0.0, 0.0), (0.10, 0.10, 0.008))
    top = object_top(coaster, np.r_[-0.02, 0.0])
    deep = np.r_[-0.02, 0.0, TABLE + FINGER_TIP_BELOW_TCP - 0.001]  # fingertips 1 mm into the table
    p1, raised = press_floor(deep, coaster, 0.003)
    assert p1[2] == pytest.approx(top + FINGER_TIP_BELOW_TCP - 0.003) and raised == pytest.approx(p1[2] - deep[2])
    assert p1[:2].tolist() == deep[:2].tolist()
    high = np.r_[-0.02, 0.0, top + FINGER_TIP_BELOW_TCP]
    assert press_floor(high, coaster, 0.003) == (pytest.approx(high), 0.0)
    sheet = _box_cloud((0.0, 0.0), (0.20, 0.20, 0.002))  # 2 mm: its floor lies 1 mm below the table top
    at_table = np.r_[-0.02, 0.0, TABLE + FINGER_TIP_BELOW_TCP]  # a press through the sheet to the table stays
    assert press_floor(at_table, sheet, 0.003) == (pytest.approx(at_table), 0.0)
    assert press_floor(deep, np.zeros((0, 3)), 0.003) == (pytest.approx(deep), 0.0)
    with pytest.raises(ValueError, match="continue_press_floor needs A"):
        FlatLabUnifiedConfig(continue_from_hand="C", continue_press_floor=0.003)
    with pytest.raises(ValueError, match="continue_press_floor: must be in"):
        FlatLabUnifiedConfig(continue_from_hand="A", continue_press_floor=0.05)


def test_seen_width_is_the_shorter_side_of_the_outline_seen_from_above_whatever_its_yaw():
    """b_min_width's measure: a 7.6-cm pad and a 29 x 10.5-cm keyboard, each turned by 25 degrees, read within a few
    mm of their shorter sides; too few points read as unseen."""
    yaw = np.radians(25.0)
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    for size, width in (((0.076, 0.076, 0.02), 0.076), ((0.29, 0.105, 0.032), 0.105)):
        pts = _box_cloud((0.0, 0.0), size)
        pts[:, :2] = pts[:, :2] @ rot.T + [0.05, -0.1]
        assert seen_width(pts) == pytest.approx(width, abs=0.003)
    assert seen_width(_box_cloud((0.0, 0.0), (0.1, 0.1, 0.01), n=5)) is None

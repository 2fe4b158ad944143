"""The scripted expert on the reference objects: right strategies lift, wrong ones fail.

The acceptance protocol (10 seeds per object, the issue's 9/10 bar) is what the ``slow`` tests
run for the book and the box; the towel, whose cloth is slow to simulate, gets two seeds here
(10/10 at seeds 0-9 and 10-19 were measured, see the README's "Expert" table)."""

import pytest

from flatlab_lerobot.demo import run_expert_episode
from flatlab_lerobot.strategies import World

SEEDS = range(10)


def _rate(object_id, strategy, seeds=SEEDS):
    return [run_expert_episode(object_id, strategy, s)["success"] for s in seeds]


@pytest.mark.slow
def test_strategy_b_lifts_the_box():
    assert sum(_rate("ref_box", "B")) >= 9


@pytest.mark.slow
def test_strategy_a_lifts_the_book():
    # Measured 10/10 at seeds 0-9; 30/30 over seeds 0-29 with the 1 ms step (27/30 at 2 ms; see README).
    assert sum(_rate("ref_book", "A")) >= 9


@pytest.mark.slow
# Not A on the 25 cm reference towel: since the sheet pinch/lift it pushes the towel to the edge in
# one piece and lifts it by the droop at seed 1 (a real lift, seen in the frames; washcloth-sized
# towels are labelled A by the grounded labels). A 34x18 cm silk scarf crumples instead (0/3).
@pytest.mark.parametrize("object_id,strategy", [("ref_box", "A"), ("scarf_silk_blue", "A"), ("ref_towel", "B")])
def test_wrong_strategies_fail(object_id, strategy):
    seeds = range(3)
    assert not any(_rate(object_id, strategy, seeds))


def test_success_needs_the_object_aloft():
    rec = run_expert_episode("ref_box", "B", 0, max_time=3.0)  # stops before the lift finishes
    assert not rec["success"] and rec["failure_reason"] in ("not_aloft", "not_held")


@pytest.mark.slow
def test_strategy_c_lifts_the_towel():
    # 10/10 at seeds 0-9 and 10-19 were measured (README); two seeds keep the suite short.
    assert all(_rate("ref_towel", "C", range(2)))


@pytest.mark.slow
def test_strategy_a_lifts_light_thin_objects():
    # A 30 g CD and a 20 g coaster: at a 2 ms step the pressed disc was shot through the table
    # (0/10); at 1 ms with the capped slide, 10/10 at seeds 0-4 (README, "A on light, thin objects").
    wins = _rate("disk_compact_disc", "A", range(3)) + _rate("disk_cork_coaster", "A", range(3))
    assert sum(wins) >= 5, wins


@pytest.mark.slow
def test_strategy_a_lifts_a_mouse_pad_by_its_edge():
    # The pad hangs its full length from the pinch, so the lift must exceed it (12/12 measured).
    assert all(_rate("mousepad_standard", "A", range(2)))


def test_slide_never_pushes_a_small_object_past_its_balance_point():
    """The slide overshoots to make up for lag, but by at most half the margin left before the
    object's centre would pass the edge: a light object follows the finger fully."""
    import numpy as np

    from flatlab_lerobot.sim.robot import tcp_rotation
    from flatlab_lerobot.strategies.a_push_to_edge import A_SLIDE_EXTRA, _a_overhang_target, a_slide

    for diameter in (0.10, 0.12, 0.30):
        w = World(np.array([0.0, 0.0, 0.752]), 0.0, np.array([diameter, diameter, 0.005]), False, 0.75, 0.3)
        pose = (np.array([-0.02, 0.0, 0.77]), tcp_rotation(np.array([0.0, 0.0, -1.0]), [0.0, 1.0, 0.0]))
        prim = a_slide(None, w, {"left": pose, "right": pose}, {"left": 0.0, "right": 0.0}, {"skipping": False})
        (motion,) = prim.motions.values()
        dist = float(motion.end[0][0] - motion.start[0][0])
        missing = w.edge_x + _a_overhang_target(w) - w.max_x()
        centre_margin = 0.5 * diameter - _a_overhang_target(w)
        assert missing < dist <= missing + min(A_SLIDE_EXTRA, 0.5 * centre_margin) + 1e-9
        assert w.max_x() + dist - w.edge_x < 0.5 * diameter  # the centre stays on the table


def test_c_lifts_a_sheet_higher_than_it_can_hang():
    """A fold pinched near an edge lets a square cloth hang up to its diagonal: the C lift must clear
    that (a 25 x 25 cm washcloth hung 2.9 cm above the table after the old fixed 32 cm lift)."""
    import numpy as np

    from flatlab_lerobot.sim.robot import tcp_rotation
    from flatlab_lerobot.strategies.c_fold_pinch import c_lift

    pose = (np.array([0.0, 0.0, 0.76]), tcp_rotation(np.array([0.0, 0.0, -1.0]), [0.0, 1.0, 0.0]))
    for size in ((0.25, 0.25), (0.35, 0.3), (0.1, 0.1)):
        w = World(np.array([0.0, 0.0, 0.752]), 0.0, np.array([*size, 0.003]), True, 0.75, 0.3)
        prim = c_lift(None, w, {"left": pose, "right": pose}, {"left": 0.0, "right": 0.0}, {})
        dz = float(prim.motions["right"].end[0][2] - pose[0][2])
        assert dz >= np.hypot(*size) + 0.05 and dz >= 0.3


def test_runner_reach_tol_refuses_a_start_out_of_reach_before_any_action():
    """PrimitiveRunner.actions(reach_tol=): a start pose the transit's IK misses by more raises Unreachable at
    the first action, before the arm moves; a reachable one runs as without it."""
    import numpy as np

    from flatlab_lerobot.primitives import ArmMotion, Primitive, Unreachable
    from flatlab_lerobot.sim.robot import HOME_Q
    from flatlab_lerobot.strategies import Expert

    e = Expert()
    q = np.r_[HOME_Q, HOME_Q]
    grip = {"left": 0.04, "right": 0.04}
    R = e.fk(q)["left"][1]
    near = (np.array([0.1, 0.1, 0.8]), R)
    far = (np.array([-0.2, -0.6, 0.764]), R)  # the left arm, 80 cm across to the right-hand back corner
    ok = Primitive("touch", {"left": ArmMotion(near, near, (0.04, 0.04))}, 0.5)
    assert [a for _, a in e.runner.actions(ok, q, grip)][-1].tolist() == [
        a for _, a in e.runner.actions(ok, q, grip, reach_tol=0.03)][-1].tolist()  # fmt: skip
    steps = e.runner.actions(Primitive("touch", {"left": ArmMotion(far, far, (0.04, 0.04))}, 0.5), q, grip, reach_tol=0.03)
    with pytest.raises(Unreachable, match="touch: start missed by left") as err:
        next(steps)
    assert err.value.miss["left"] > 0.3


def _final_right_wrist(object_id, yaw_deg, **options):
    import numpy as np

    from flatlab_lerobot.env import FlatLabEnv
    from flatlab_lerobot.rollout import ExpertPolicy, rollout
    from flatlab_lerobot.strategies.expert import ExpertOptions

    env = FlatLabEnv(object_id=object_id, obs_pixels=False, obs_pointcloud=False)
    try:
        policy = ExpertPolicy("B", env.cell, env.control_dt, options=ExpertOptions(**options))
        ep = rollout(env, policy, seed=0, options={"placement": (0.0, 0.0, np.deg2rad(yaw_deg))},
                     before_step=lambda st: np.asarray(st.action))  # fmt: skip
    finally:
        env.close()
    return ep.success, float(ep.frames[-1][14])  # action (16,): right arm joints at 8..14


def test_b_right_half_turn_keeps_the_right_wrist_inside_its_range():
    """box_shoe at yaw 25 deg (docs/results/expert_wrist_branches*.json): the default expert's right wrist
    ends at its +2.897 rad limit (past the jump at yaw 15-20 deg); with ``b_right_half_turn`` the right hand
    is the left hand's mirror image, the wrist well inside its range, and the box is still lifted."""
    ok, wrist = _final_right_wrist("box_shoe", 25.0)
    assert ok and wrist > 2.85, wrist
    ok, wrist = _final_right_wrist("box_shoe", 25.0, b_right_half_turn=True)
    assert ok and 0.0 < wrist < 1.0, wrist


def test_b_right_half_turn_turns_only_the_right_hand():
    import numpy as np

    from flatlab_lerobot.strategies.b_squeeze import HALF_TURN, _b_targets
    from flatlab_lerobot.strategies.world import World

    w = World(np.array([0.05, -0.02, 0.8]), 0.4, np.array([0.3, 0.2, 0.06]), False, 0.76, 0.5)
    plain, turned = _b_targets(w, 0.0), _b_targets(w, 0.0, right_half_turn=True)
    np.testing.assert_allclose(turned["left"][1], plain["left"][1])
    np.testing.assert_allclose(turned["right"][1], plain["right"][1] @ HALF_TURN)
    for arm in ("left", "right"):
        np.testing.assert_allclose(turned[arm][0], plain[arm][0])
    # the same approach axis (the hand's z), the finger axis reversed
    np.testing.assert_allclose(turned["right"][1][:, 2], plain["right"][1][:, 2])
    np.testing.assert_allclose(turned["right"][1][:, :2], -plain["right"][1][:, :2])


def test_the_scripted_policy_passes_the_option_to_its_experts():
    """``flatlab eval --policy oracle --policy.b_right_half_turn=true`` (docs/baselines.md) reaches the expert."""
    from flatlab_lerobot.policies.scripted import FlatLabScriptedConfig
    from flatlab_lerobot.policies.scripted.modeling_flatlab_scripted import FlatLabScriptedPolicy

    for on in (False, True):
        policy = FlatLabScriptedPolicy(FlatLabScriptedConfig(device="cpu", b_right_half_turn=on))
        assert policy._expert(0, None).options.b_right_half_turn is on

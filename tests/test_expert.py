"""The scripted expert on the reference objects: right strategies lift, wrong ones fail.

The acceptance protocol (10 seeds per object, the issue's 9/10 bar) is what the ``slow`` tests
run for the book and the box; the towel, whose cloth is slow to simulate, gets two seeds here
(10/10 at seeds 0-9 and 10-19 were measured, see the README's "Expert" table)."""

import pytest

from flatlab_lerobot.demo import run_expert_episode

SEEDS = range(10)


def _rate(object_id, strategy, seeds=SEEDS):
    return [run_expert_episode(object_id, strategy, s)["success"] for s in seeds]


@pytest.mark.slow
def test_strategy_b_lifts_the_box():
    assert sum(_rate("ref_box", "B")) >= 9


@pytest.mark.slow
def test_strategy_a_lifts_the_book():
    # Measured 10/10 at seeds 0-9 and 27/30 over seeds 0-29 (see README).
    assert sum(_rate("ref_book", "A")) >= 9


@pytest.mark.slow
@pytest.mark.parametrize("object_id,strategy", [("ref_box", "A"), ("ref_towel", "A"), ("ref_towel", "B")])
def test_wrong_strategies_fail(object_id, strategy):
    seeds = range(3)
    assert not any(_rate(object_id, strategy, seeds))


def test_success_needs_the_object_aloft():
    rec = run_expert_episode("ref_box", "B", 0, max_time=3.0)  # stops before the lift finishes
    assert not rec["success"] and "timeout" in rec["failure_reason"]


@pytest.mark.slow
def test_strategy_c_lifts_the_towel():
    # 10/10 at seeds 0-9 and 10-19 were measured (README); two seeds keep the suite short.
    assert all(_rate("ref_towel", "C", range(2)))

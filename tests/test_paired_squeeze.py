"""``--policy.pair_squeeze``: B's hands on one line along the observed object's squeeze axis."""

import numpy as np
import pytest

from flatlab_lerobot.policies.unified.paired_squeeze import observed_squeeze_axis, pair


def _box_cloud(yaw_deg: float, size=(0.20, 0.30), n=400, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    local = (rng.random((n, 2)) - 0.5) * np.asarray(size)
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    xy = local @ np.array([[c, s], [-s, c]]) + [0.02, -0.01]
    return np.c_[xy, np.full(n, 0.78)]


@pytest.mark.parametrize("yaw", [0.0, 20.0, -35.0, 80.0])
def test_axis_is_the_rectangle_side_closest_to_y(yaw):
    u = observed_squeeze_axis(_box_cloud(yaw))
    c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    sides = [np.array([c, s]), np.array([-s, c])]  # the box's local x and y axes in the world
    want = max(sides, key=lambda v: abs(v[1]))
    want = want if want[1] >= 0 else -want
    assert u[1] >= 0 and abs(float(u @ want)) == pytest.approx(1.0, abs=2e-3)


def test_too_few_or_degenerate_points_keep_the_learned_poses():
    assert observed_squeeze_axis(_box_cloud(0.0, n=5)) is None
    line = np.c_[np.linspace(0, 0.2, 50), np.zeros(50), np.zeros(50)]
    assert observed_squeeze_axis(line) is None or np.isfinite(observed_squeeze_axis(line)).all()


def test_pair_moves_only_across_the_axis():
    u = np.array([0.0, 1.0])
    left, right = np.array([0.026, 0.133, 0.768]), np.array([-0.006, -0.122, 0.770])
    pl, pr = pair(left, right, u)
    # on one line along u, through the learned midpoint; along-axis positions and heights unchanged
    assert pl[0] == pytest.approx(pr[0]) == pytest.approx((left[0] + right[0]) / 2)
    assert (pl[1], pl[2], pr[1], pr[2]) == pytest.approx((left[1], left[2], right[1], right[2]))
    # a tilted axis: the separation ends up parallel to u, the midpoint stays
    u = np.array([np.sin(0.3), np.cos(0.3)])
    pl, pr = pair(left, right, u)
    d = (pl - pr)[:2]
    assert abs(d @ np.array([-u[1], u[0]])) < 1e-12
    assert (pl + pr)[:2] / 2 == pytest.approx((left + right)[:2] / 2)
    assert (d @ u) == pytest.approx(((left - right)[:2]) @ u)

"""MuJoCo Menagerie-style model test: every reference cell loads with no warning and survives
1 s of random joint-noise control with no NaN and no warning."""

import mujoco
import numpy as np
import pytest

from flatlab_lerobot.catalog import REFERENCE_OBJECTS, get_object
from flatlab_lerobot.sim.core import FlatLabSim
from flatlab_lerobot.sim.robot import ARMS, HOME_Q


@pytest.mark.parametrize("object_id", sorted(REFERENCE_OBJECTS.values()))
def test_cell_survives_joint_noise(object_id):
    sim = FlatLabSim(get_object(object_id))
    m, d = sim.model, sim.data
    assert all(w.number == 0 for w in d.warning), "warning at load"
    sim.reset(0.0, 0.0, 0.0)
    rng = np.random.default_rng(0)
    ids = np.concatenate([sim.arms[a].ctrl for a in ARMS])
    lo, hi = m.actuator_ctrlrange[ids, 0], m.actuator_ctrlrange[ids, 1]
    base = np.r_[HOME_Q, 0.04, HOME_Q, 0.04]
    while d.time < 1.0 + 0.3:
        d.ctrl[ids] = np.clip(base + rng.normal(0, 0.1, ids.size) * (hi - lo) * 0.1, lo, hi)
        mujoco.mj_step(m, d)
    assert np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))
    assert all(w.number == 0 for w in d.warning), {mujoco.mjtWarning(i).name: w.number for i, w in enumerate(d.warning) if w.number}


def test_panda_kinematics_match_published_dh():
    """TCP of the MJCF arm equals the Craig-DH forward kinematics of the published parameters."""
    from flatlab_lerobot.sim.scene import CellConfig, build_model

    m = build_model(CellConfig(), None)
    d = mujoco.MjData(m)
    dh = [(0, 0.333, 0), (0, 0, -np.pi / 2), (0, 0.316, np.pi / 2), (0.0825, 0, np.pi / 2),
          (-0.0825, 0.384, -np.pi / 2), (0, 0, np.pi / 2), (0.088, 0, np.pi / 2)]  # fmt: skip
    rng = np.random.default_rng(1)
    arm = "right"
    qadr = [m.jnt_qposadr[m.joint(f"{arm}/joint{i}").id] for i in range(1, 8)]
    base = m.body(f"{arm}/link0").id
    for _ in range(10):
        q = rng.uniform(-1.5, 1.5, 7)
        q[3] = rng.uniform(-2.8, -0.2)
        d.qpos[qadr] = q
        mujoco.mj_kinematics(m, d)
        T = np.eye(4)
        for (a, dd, al), th in zip(dh, q):
            ca, sa, ct, st = np.cos(al), np.sin(al), np.cos(th), np.sin(th)
            T = T @ np.array([[ct, -st, 0, a], [st * ca, ct * ca, -sa, -dd * sa], [st * sa, ct * sa, ca, dd * ca], [0, 0, 0, 1]])
        T = T @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.107 + 0.1034], [0, 0, 0, 1]])
        Rb, pb = d.xmat[base].reshape(3, 3), d.xpos[base]
        expected = pb + Rb @ T[:3, 3]
        np.testing.assert_allclose(d.site_xpos[m.site(f"{arm}/tcp").id], expected, atol=1e-6)


@pytest.mark.parametrize("object_id", sorted(REFERENCE_OBJECTS.values()))
def test_reset_places_the_object(object_id):
    """reset(x, y, yaw) really moves the object (also with sleeping islands in cloth scenes), and
    the privileged pose reports that placement."""
    sim = FlatLabSim(get_object(object_id))
    for x, y, yaw in [(0.04, -0.03, 0.4), (-0.02, 0.05, -0.5)]:
        sim.reset(x, y, yaw, settle=0.0)
        pos, quat = sim.object_pose()
        np.testing.assert_allclose(pos[:2], [x, y], atol=2e-3)
        np.testing.assert_allclose(2 * np.arctan2(quat[3], quat[0]), yaw, atol=2e-2)
        np.testing.assert_allclose(sim.object_extent()[:2], get_object(object_id).size[:2], atol=2e-3)


def test_finger_pads_sit_flush_on_their_fingers():
    """No gap between a finger's pad and its box where a thin object could wedge, and the pads'
    inner faces meet at a closed gripper (the gripper width is the distance between the pads)."""
    from flatlab_lerobot.sim.scene import CellConfig, build_model

    m = build_model(CellConfig(), None)
    fingers = [b for b in range(m.nbody) if m.body(b).name.endswith("finger")]
    assert len(fingers) == 4
    for b in fingers:
        geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == b]
        pads = [g for g in geoms if m.geom(g).name.endswith("pad")]
        boxes = [g for g in geoms if g not in pads]
        assert len(pads) == 1 and len(boxes) == 1, m.body(b).name
        pad, box = pads[0], boxes[0]
        side = np.sign(m.geom_pos[box][1])  # the box lies on the finger's outer side
        pad_outer = side * m.geom_pos[pad][1] + m.geom_size[pad][1]
        pad_inner = side * m.geom_pos[pad][1] - m.geom_size[pad][1]
        box_inner = side * m.geom_pos[box][1] - m.geom_size[box][1]
        assert pad_outer >= box_inner - 1e-9, f"{m.body(b).name}: {1e3 * (box_inner - pad_outer):.1f} mm gap"
        assert abs(pad_inner) < 1e-9

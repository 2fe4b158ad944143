"""Every catalog object compiles into the cell, loads with no MuJoCo warning and settles on the table.

(The MuJoCo Menagerie model test: one parametrised case per registered asset.)
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from flatlab_lerobot.assets import RIGID_BUILDERS, garment_mesh, object_xml, rigid_geoms
from flatlab_lerobot.catalog import DEFORMABLE_FAMILIES, FAMILIES, load_objects
from flatlab_lerobot.sim.robot import ARMS, HOME_Q
from flatlab_lerobot.sim.scene import CellConfig, build_model

OBJECTS = load_objects()
IDS = sorted(OBJECTS)


def _home_arms(m: mujoco.MjModel, d: mujoco.MjData) -> None:
    for arm in ARMS:
        for i, q in enumerate(HOME_Q):
            d.qpos[m.jnt_qposadr[m.joint(f"{arm}/joint{i + 1}").id]] = q
            d.ctrl[m.actuator(f"{arm}/actuator{i + 1}").id] = q


def _object_speed(m: mujoco.MjModel, d: mujoco.MjData, deformable: bool) -> float:
    if deformable:
        f = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_FLEX, "cloth")
        bodies = m.flex_vertbodyid[m.flex_vertadr[f] : m.flex_vertadr[f] + m.flex_vertnum[f]]
    else:
        bodies = [m.body("object").id]
    return float(np.max(np.linalg.norm(d.cvel[bodies][:, 3:], axis=1)))


# Cloth settles at ~300 steps/s: those ~25 cases take ~1 s each, hence marked slow.
@pytest.mark.parametrize(
    "object_id", [pytest.param(i, marks=pytest.mark.slow) if OBJECTS[i].deformable else i for i in IDS]
)
def test_object_settles_in_cell(object_id):
    obj = OBJECTS[object_id]
    m = build_model(CellConfig(), obj)
    d = mujoco.MjData(m)
    _home_arms(m, d)
    mujoco.mj_forward(m, d)
    bid = m.body("object").id
    if obj.deformable:
        assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_FLEX, "cloth") >= 0
    else:
        assert m.joint("object_free").type == mujoco.mjtJoint.mjJNT_FREE
        assert m.body_mass[bid] == pytest.approx(obj.mass)
        assert np.allclose(m.body_ipos[bid], obj.com_offset)
        assert m.geom("object_geom").bodyid == bid
    for _ in range(round(1.0 / m.opt.timestep)):
        mujoco.mj_step(m, d)
    assert not any(w.number for w in d.warning), [(i, w.number) for i, w in enumerate(d.warning) if w.number]
    assert np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))
    assert _object_speed(m, d, obj.deformable) < 1e-3
    pen = min((d.contact.dist[i] for i in range(d.ncon)), default=0.0)
    assert pen > -1e-3, f"penetration {pen * 1000:.2f} mm"
    if not obj.deformable:  # still resting flat at the table centre
        assert abs(d.xpos[bid][2] - (CellConfig().table_height + obj.size[2] / 2)) < 2e-3


@pytest.mark.parametrize("object_id", [i for i in IDS if not OBJECTS[i].deformable])
def test_rigid_geoms_inside_bounding_box(object_id):
    obj = OBJECTS[object_id]
    half = np.array(obj.size) / 2
    geoms = rigid_geoms(obj)
    assert any(g.collide for g in geoms)
    for g in geoms:
        lo = np.array(g.pos) - g.aabb_half()
        hi = np.array(g.pos) + g.aabb_half()
        assert np.all(lo >= -half - 1e-3) and np.all(hi <= half + 1e-3), (g, half)
    assert any(not g.hidden for g in geoms)  # something is drawn


def test_every_family_has_a_builder():
    rigid = set(FAMILIES) - set(DEFORMABLE_FAMILIES)
    assert rigid == set(RIGID_BUILDERS)
    used = {o.shape for o in OBJECTS.values()}
    assert used == set(FAMILIES)


@pytest.mark.parametrize("object_id", [i for i in IDS if OBJECTS[i].shape in ("shorts", "skirt")])
def test_garment_outline(object_id):
    obj = OBJECTS[object_id]
    pts, tris = garment_mesh(obj)
    assert tris.min() == 0 and tris.max() == len(pts) - 1
    ext = pts.max(0) - pts.min(0)
    assert np.allclose(ext[:2], obj.size[:2])
    area = 0.5 * np.abs(np.cross(pts[tris[:, 1]] - pts[tris[:, 0]], pts[tris[:, 2]] - pts[tris[:, 0]])[:, 2]).sum()
    assert area < 0.99 * obj.size[0] * obj.size[1]  # not a plain rectangle


def test_object_xml_contract():
    xml = object_xml(OBJECTS["ref_book"], 0.75)
    assert 'name="object"' in xml and 'name="object_free"' in xml and 'name="object_geom"' in xml
    assert 'name="cloth"' in object_xml(OBJECTS["ref_towel"], 0.75)

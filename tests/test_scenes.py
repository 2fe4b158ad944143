"""The 18 scenes as MuJoCo models: they load without warnings, a box settles on every table, the
table top is where the scene file says, edge profiles keep the top flat up to the usable edge,
materials reach the model, and the visual-only props stay out of the arms' workspace and out of
the cell cameras' view of the table."""

import dataclasses
import re

import mujoco
import numpy as np
import pytest

import flatlab_lerobot  # noqa: F401  (sets MUJOCO_GL before mujoco is imported)
from flatlab_lerobot.catalog import CatalogError, get_object, load_materials, load_scenes
from flatlab_lerobot.sim.cameras import GEOM, CameraRig
from flatlab_lerobot.sim.core import FailureReason, FlatLabSim
from flatlab_lerobot.sim.room import KEEP_OUT_BEHIND, KEEP_OUT_SIDE, PROPS
from flatlab_lerobot.sim.scene import CellConfig, build_model, scene_xml
from flatlab_lerobot.tasks import ResetDistribution

SCENES = load_scenes()
MATERIALS = load_materials()
SCENE_IDS = sorted(SCENES)
TABLE_GEOMS = ("table_top", "table_edge", "table_under")


def _cell(sid: str) -> CellConfig:
    return CellConfig.from_scene(sid)


def _geom_ids(m, names):
    return [i for i in (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n) for n in names) if i >= 0]


def _world_aabb(m, d, g) -> tuple[np.ndarray, np.ndarray]:
    """World-frame axis-aligned box of geom ``g`` (from its local AABB, after mj_forward)."""
    c, h = m.geom_aabb[g, :3], m.geom_aabb[g, 3:]
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h + c
    w = corners @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
    return w.min(axis=0), w.max(axis=0)


def test_all_scenes_and_props_are_known():
    assert len(SCENE_IDS) == 18
    assert len(MATERIALS) >= 10
    assert len({round(m.friction, 3) for m in MATERIALS.values()}) >= 8  # distinct friction
    used = {p for s in SCENES.values() for p in s.props}
    assert used <= set(PROPS)
    assert {s.edge for s in SCENES.values()} == {"square", "rounded", "bevelled"}


@pytest.mark.parametrize("sid", SCENE_IDS)
def test_scene_loads_and_box_settles(sid, capfd):
    """Compiles with no MuJoCo warning; the reference box comes to rest (< 1 mm/s after 1 s) on the
    table top at the scene's height, penetration < 1 mm, no NaN; geometry and material as in the files."""
    spec, mat = SCENES[sid], MATERIALS[SCENES[sid].material]
    cell = _cell(sid)
    box = get_object("ref_box")
    sim = FlatLabSim(box, cell)
    m, d = sim.model, sim.data
    sim.reset(0.02, -0.03, 0.3, settle=0.3)
    for _ in range(7):  # reset settled 0.3 s; 0.7 s more = 1 s
        sim.step(sim._target)
    assert "WARNING" not in capfd.readouterr().err
    assert not any(w.number for w in d.warning), [i for i, w in enumerate(d.warning) if w.number]
    assert np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))
    a = sim._free_qadr
    v = d.qvel[m.jnt_dofadr[m.joint("object_free").id]:][:6]
    r = 0.5 * np.linalg.norm(box.size)
    assert np.linalg.norm(v[:3]) + np.linalg.norm(v[3:]) * r < 1e-3  # fastest point of the box, m/s
    dist = [d.contact[i].dist for i in range(d.ncon)]
    assert dist and min(dist) > -1e-3
    # the box lies on the top: its bottom at the scene's table height
    assert abs(d.qpos[a + 2] - box.size[2] / 2 - spec.table_height) < 1e-3
    # table top at the file's height, flat up to the edge, front edge at table_size[0] / 2
    tx, ty = spec.table_size
    top = m.geom("table_top").id
    assert m.geom_pos[top][2] + m.geom_size[top][2] == pytest.approx(spec.table_height, abs=1e-9)
    tables = _geom_ids(m, TABLE_GEOMS)
    assert len(tables) == {"square": 1, "rounded": 2, "bevelled": 3}[spec.edge]
    boxes = [_world_aabb(m, d, g) for g in tables]
    assert max(hi[2] for _, hi in boxes) == pytest.approx(spec.table_height, abs=1e-6)  # nothing sticks up
    assert max(hi[0] for _, hi in boxes) == pytest.approx(tx / 2, abs=1e-6)  # the usable edge
    assert min(lo[2] for lo, _ in boxes) == pytest.approx(spec.table_height - spec.table_thickness, abs=1e-6)
    hi = boxes[0][1]
    assert hi[0] >= tx / 2 - spec.table_thickness / 2 - 1e-9 and hi[1] == pytest.approx(ty / 2)  # flat top extent
    # material: friction and table collision bits on every table geom
    for g in tables:
        assert m.geom_friction[g][0] == pytest.approx(mat.friction)
        assert m.geom_contype[g] == m.geom_contype[top] and m.geom_conaffinity[g] == m.geom_conaffinity[top]
    # arm pedestals follow the table: 0.2 m beside it (at most 0.65 m out), at most 0.3 m behind the edge
    base_y = min(ty / 2 + 0.2, 0.65)
    assert m.geom("left_pedestal").pos[1] == pytest.approx(base_y) and m.geom("right_pedestal").pos[1] == pytest.approx(-base_y)
    assert m.geom("left_pedestal").pos[0] == pytest.approx(max(0.0, tx / 2 - 0.3))


@pytest.mark.parametrize("sid", SCENE_IDS)
def test_props_stay_out_of_workspace_and_camera_views(sid):
    """Every prop geom is visual only and lies outside the keep-out zone (the table, the space
    behind it up to KEEP_OUT_BEHIND, the arms' side up to KEEP_OUT_SIDE beyond a base, and more than
    20 cm in front of the edge, towards the cameras); the four cameras see exactly as much table with the props as without, and
    the top camera's depth puts the table top at the file's height."""
    spec = SCENES[sid]
    cell = _cell(sid)
    tx, ty = spec.table_size
    m = build_model(cell, None)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    prop_bodies = [b for b in range(m.nbody) if m.body(b).name.startswith("prop")]
    assert len(prop_bodies) == len(spec.props)
    for g in range(m.ngeom):
        if m.geom_bodyid[g] not in prop_bodies:
            continue
        assert m.geom_contype[g] == 0 and m.geom_conaffinity[g] == 0
        lo, hi = _world_aabb(m, d, g)
        if hi[2] < 0.01:  # a rug on the floor
            continue
        behind = hi[0] <= -tx / 2 - KEEP_OUT_BEHIND
        beside = lo[1] >= cell.arm_base_y + KEEP_OUT_SIDE or hi[1] <= -(cell.arm_base_y + KEEP_OUT_SIDE)
        assert (behind or beside) and hi[0] < tx / 2 + 0.2, (m.body(m.geom_bodyid[g]).name, lo, hi)

    bare = build_model(dataclasses.replace(cell, props=()), None)
    db = mujoco.MjData(bare)
    mujoco.mj_forward(bare, db)
    cams = [c.name for c in cell.camera_specs()]
    with_props, without = CameraRig(m, 64, 64, cams), CameraRig(bare, 64, 64, cams)
    try:
        for cam in cams:
            n = []
            for model, data, rig in ((m, d, with_props), (bare, db, without)):
                seg = rig.segmentation(data, cam)
                table = np.isin(seg[..., 0], _geom_ids(model, TABLE_GEOMS)) & (seg[..., 1] == GEOM)
                n.append(int(table.sum()))
            assert n[0] == n[1] > 100, (cam, n)
        top = m.geom("table_top").id
        seg = with_props.segmentation(d, "top")
        mask = (seg[..., 1] == GEOM) & (seg[..., 0] == top)
        pts = with_props.depth_to_points(with_props.depth(d, "top"), "top", d, mask)
        inner = pts[(np.abs(pts[:, 0]) < tx / 2 - 0.03) & (np.abs(pts[:, 1]) < ty / 2 - 0.01)]
        assert len(inner) > 200 and np.max(np.abs(inner[:, 2] - spec.table_height)) < 2e-3
    finally:
        with_props.close()
        without.close()


def test_default_cell_is_plain():
    cell = CellConfig()
    assert cell.arm_base_y == pytest.approx(0.65) and cell.edge == "square" and cell.props == ()
    xml = scene_xml(cell, None)
    assert "wall_left" not in xml and "prop" not in xml and 'name="table_edge"' not in xml
    assert CellConfig(table_size=(0.6, 0.7)).arm_base_y == pytest.approx(0.55)
    assert CellConfig(table_size=(0.6, 1.0)).arm_base_y == pytest.approx(0.65)
    assert CellConfig(table_size=(0.7, 0.9)).arm_base_x == pytest.approx(0.05)
    assert CellConfig(table_size=(0.5, 0.9)).arm_base_x == 0.0


def test_edge_profiles_keep_a_box_on_the_top():
    """Same table, three edges: the rounded / bevelled parts stay below the top surface and the
    edge stays at x = depth / 2 (a box pushed to the edge rests at the same height on all three)."""
    base = _cell("study_desk")
    for edge in ("square", "rounded", "bevelled"):
        m = build_model(dataclasses.replace(base, edge=edge), None)
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        boxes = [_world_aabb(m, d, g) for g in _geom_ids(m, TABLE_GEOMS)]
        assert max(hi[0] for _, hi in boxes) == pytest.approx(base.edge_x, abs=1e-6), edge
        assert max(hi[2] for _, hi in boxes) == pytest.approx(base.table_height, abs=1e-6), edge


@pytest.mark.parametrize("oid", ["disk_compact_disc", "towel_hand_white"])
def test_object_pushed_off_the_table_lands_on_the_floor(oid):
    """An object that leaves the table lies on the floor (it fell through a visual-only floor to
    z = -2 km before, which also put -2 km into recorded environment states), and the failure
    reason says it fell.  The floor is invisible to the cameras."""
    sim = FlatLabSim(get_object(oid))
    sim.reset(0.0, 0.0, 0.3)
    assert not sim.grasp_status().fallen
    sim.reset(sim.cell.edge_x + 0.35, 0.0, 0.3)  # placed at table height, past the usable edge
    m, d = sim.model, sim.data
    t0 = d.time
    while d.time - t0 < 2.0:
        mujoco.mj_step(m, d)
    lowest = sim.object_points(0)[:, 2].min()
    assert -0.001 < lowest < 0.005, lowest
    st = sim.grasp_status()
    assert st.fallen and st.shortfall == FailureReason.FELL_OFF_TABLE == "fell_off_table"
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor_collision")
    assert m.geom_group[g] >= 3  # hidden from renders


def test_arms_collide_with_the_floor():
    """The floor is an infinite plane the arms touch too: with a 6 x 6 m slab for objects only, an
    object swept off the table by an end-to-end baseline rolled off the slab's edge (a clock on its rim,
    3 m in 6 s) and fell to z = -3 km, and a hand could press through it.  Checked with MuJoCo's own
    collision filter: the floor plane raised to each hand's height touches that arm."""
    sim = FlatLabSim(get_object("box_shoe"))
    sim.reset(0.0, 0.0, 0.0)
    m, d = sim.model, sim.data
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor_collision")
    for arm in ("left", "right"):
        hand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{arm}/hand")
        arm_geoms = {i for i in range(m.ngeom) if m.body(m.geom_bodyid[i]).name.startswith(f"{arm}/")}
        mujoco.mj_forward(m, d)
        d.geom_xpos[g, 2] = d.xpos[hand][2]  # the floor plane at the hand's origin (a world geom: set in data)
        mujoco.mj_collision(m, d)
        pairs = {(int(c.geom1), int(c.geom2)) for c in d.contact[: d.ncon]}
        assert any(g in p and (p[0] in arm_geoms or p[1] in arm_geoms) for p in pairs), arm


def test_bad_scene_inputs_name_file_and_field(tiny_scene_catalog):
    scenes, mats, good = tiny_scene_catalog("edge: rounded, material: oak, props: [bookshelf, chair]")
    cell = CellConfig.from_scene("s1", scenes, mats)
    assert cell.props == ("bookshelf", "chair") and cell.edge == "rounded" and cell.table_friction == 0.4
    for old, new, fld in [("chair]", "piano]", "props[1]"), ("material: oak", "material: jade", "material")]:
        (scenes / "s.yaml").write_text(good.replace(old, new))
        with pytest.raises(CatalogError, match=rf"s\.yaml: scene 's1': field '{re.escape(fld)}'"):
            load_scenes(scenes, mats)
    with pytest.raises(ValueError, match=r"scene 'x': field 'props': unknown prop 'piano'"):
        build_model(CellConfig(props=("piano",), scene_id="x"), None)
    with pytest.raises(ValueError, match=r"field 'edge'"):
        build_model(CellConfig(edge="wavy"), None)
    with pytest.raises(KeyError, match="unknown scene id"):
        CellConfig.from_scene("no_such_scene")


def test_reset_distribution_scenes():
    rd = ResetDistribution(scenes=("study_desk", "kitchen_counter", "warehouse_steel"))
    picks = [rd.scene(s) for s in range(30)]
    assert set(picks) == set(rd.scenes) and picks == [rd.scene(s) for s in range(30)]
    assert ResetDistribution().scene(0) is None
    assert rd.sample(3) == ResetDistribution().sample(3)  # the scene draw leaves placements alone


def test_env_scene_option():
    from flatlab_lerobot.env import FlatLabEnv

    env = FlatLabEnv(object_id="ref_box", scene="kitchen_counter", obs_pixels=False, obs_pointcloud=False)
    try:
        obs, _ = env.reset(seed=0)
        assert env.cell.table_height == SCENES["kitchen_counter"].table_height
        assert env.cell.props == SCENES["kitchen_counter"].props
        assert np.isfinite(obs["environment_state"]).all()
    finally:
        env.close()
    with pytest.raises(ValueError, match="not both"):
        FlatLabEnv(scene="kitchen_counter", cell=CellConfig())


def test_env_config_scene_field():
    from flatlab_lerobot.lerobot_env import FlatLabEnvConfig  # imports lerobot (several seconds)

    assert FlatLabEnvConfig(scene="study_desk").gym_kwargs["scene"] == "study_desk"
    assert FlatLabEnvConfig().gym_kwargs["scene"] is None

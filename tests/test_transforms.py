"""Catalog transformations (paper §3.2.2): uniform scales, rigid counterparts, recomputed labels."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest

from flatlab_lerobot import transforms as T
from flatlab_lerobot.assets import garment_mesh, rigid_geoms
from flatlab_lerobot.catalog import FAMILIES, benchmark_objects, load_objects
from flatlab_lerobot.sim.robot import ARMS, HOME_Q
from flatlab_lerobot.sim.scene import CellConfig, build_model

OBJECTS = load_objects()
BENCH = benchmark_objects()
CELL = CellConfig()


def _spec(**kw):
    return dataclasses.replace(OBJECTS["ref_book"], **kw)


# ------------------------------------------------------------------------------ labels
def test_label_rule_on_synthetic_objects():
    assert T.label(_spec(size=(0.15, 0.10, 0.02))) == "A"  # thin and small
    assert T.label(_spec(size=(0.15, 0.10, 0.04))) == "B"  # thick
    assert T.label(_spec(size=(0.35, 0.25, 0.015))) == "B"  # large and squeezable
    assert T.label(_spec(size=(0.35, 0.25, 0.006))) == "A"  # large but too thin to squeeze
    assert T.label(OBJECTS["ref_towel"]) == "C"


def test_label_rule_reproduces_the_catalog():
    wrong = T.label_disagreements(BENCH)
    assert all(o.paper_strategy == "C" for o in BENCH if o.deformable)
    assert all(T.label(OBJECTS[r]) == s for s, r in {"A": "ref_book", "B": "ref_box", "C": "ref_towel"}.items())
    # the fitted thresholds leave at most 8 % of the 104 objects out, and only thin-but-large
    # objects the catalog calls A (README: lifting often succeeds on those)
    assert len(wrong) <= 8, wrong
    assert all((cat, rule) == ("A", "B") for _, cat, rule in wrong), wrong
    assert {"book_atlas", "album_travel"}.isdisjoint(i for i, _, _ in wrong)  # the book threshold's neighbours


# ------------------------------------------------------------------------------ scaling
def test_scaled_rigid_object():
    o = OBJECTS["cutboard_oak_handle"]
    s = 0.75
    v = T.scaled(o, s)
    assert v.id == "cutboard_oak_handle@s0.75" and v.material == "rigid"
    assert np.allclose(v.size, np.array(o.size) * s)
    assert np.allclose(v.com_offset, np.array(o.com_offset) * s)
    assert v.mass == pytest.approx(o.mass * s**3)
    for key, (kind, *_rest) in FAMILIES[o.shape].items():
        if kind == "num":
            assert v.param(key) == pytest.approx(o.param(key) * s), key
    assert v.strategy == T.label(v)
    lap = T.scaled(OBJECTS["laptop_13in"], 1.2)
    assert lap.param("base_fraction") == OBJECTS["laptop_13in"].param("base_fraction")  # a ratio stays


def test_scaled_cloth_keeps_its_fabric():
    o = OBJECTS["shorts_denim"]
    v = T.scaled(o, 1.25)
    assert np.allclose(v.size[:2], np.array(o.size[:2]) * 1.25) and v.size[2] == o.size[2]
    assert v.mass == pytest.approx(o.mass * 1.25**2)
    assert v.flex == o.flex and v.strategy == "C"
    assert v.param("leg_gap") == pytest.approx(o.param("leg_gap") * 1.25) and v.param("rise") == o.param("rise")
    pts, _ = garment_mesh(v)
    assert np.allclose(pts.max(0)[:2] - pts.min(0)[:2], v.size[:2])


@pytest.mark.parametrize("bad", [0, -0.5, math.nan, math.inf, "1.0", None, True])
def test_bad_scale_is_a_value_error(bad):
    with pytest.raises(ValueError, match="ref_book"):
        T.scaled(OBJECTS["ref_book"], bad)


def test_scale_outside_the_range_is_a_value_error():
    o = OBJECTS["disk_vinyl_lp"]
    lo, hi = T.scale_range(o, CELL)
    T.scaled(o, hi, cell=CELL)
    with pytest.raises(ValueError, match=r"disk_vinyl_lp.*outside its sensible range"):
        T.scaled(o, hi * 1.01, cell=CELL)
    with pytest.raises(ValueError, match="outside"):
        T.scaled(o, lo * 0.99, cell=CELL)
    with pytest.raises(ValueError, match="number of scales"):
        T.seven_scales(o, n=0)


@pytest.mark.parametrize("obj", BENCH, ids=[o.id for o in BENCH])
def test_scale_range(obj):
    lo, hi = T.scale_range(obj, CELL)
    assert 0 < lo <= 1.0 <= hi  # every catalog object is itself a sensible size
    small, big = T.scaled(obj, lo), T.scaled(obj, hi)
    margin = 0.05 + T.TABLE_EDGE_MARGIN  # reset planar range + edge margin
    # largest: the footprint is as large as the table allows, on one axis exactly
    assert big.size[0] <= CELL.table_size[0] - 2 * margin + 1e-9
    assert big.size[1] <= CELL.table_size[1] - 2 * margin + 1e-9
    assert math.isclose(big.size[0], CELL.table_size[0] - 2 * margin) or math.isclose(
        big.size[1], CELL.table_size[1] - 2 * margin
    )
    # smallest: a catalog lower bound is met exactly
    if obj.deformable:
        sides = sorted(small.size[:2])
        assert sides[0] >= 0.08 - 1e-9 and sides[1] >= 0.10 - 1e-9
        assert math.isclose(sides[0], 0.08) or math.isclose(sides[1], 0.10)
        assert small.size[2] == obj.size[2]
    else:
        assert min(small.size[:2]) >= 0.04 - 1e-9 and small.size[2] >= 0.004 - 1e-9
        assert math.isclose(min(small.size[:2]), 0.04) or math.isclose(small.size[2], 0.004)
    scales = T.seven_scales(obj, CELL)
    assert len(scales) == 7 and lo - 1e-9 <= scales[0] and scales[-1] <= hi + 1e-9
    steps = np.diff(scales)
    assert np.all(steps > 0) and np.ptp(steps) < 2e-3  # uniform up to the 3-decimal rounding


# ------------------------------------------------------------------------------ counterparts
def _area(geoms):
    return sum(4 * g.size[0] * g.size[1] for g in geoms)


@pytest.mark.parametrize("oid", ["fabric_cotton", "shorts_denim", "shorts_kids", "skirt_a_line"])
def test_rigid_counterpart(oid):
    o = OBJECTS[oid]
    r = T.rigid_counterpart(o)
    assert r.id == f"{oid}@rigid" and r.material == "rigid" and not r.deformable and r.flex is None
    assert r.size == o.size and r.mass == o.mass and r.category == o.category and r.split == o.split
    assert r.strategy == "A" == T.label(r)
    geoms = rigid_geoms(r)
    assert all(g.collide and g.type == "box" for g in geoms)
    assert all(math.isclose(2 * g.size[2], o.size[2]) for g in geoms)  # the sheet's thickness
    if o.shape == "sheet":
        area = o.size[0] * o.size[1]
    else:  # the cloth's own outline (the triangles of its flex mesh)
        pts, tris = garment_mesh(o)
        e1, e2 = pts[tris[:, 1]] - pts[tris[:, 0]], pts[tris[:, 2]] - pts[tris[:, 0]]
        area = 0.5 * np.abs(np.cross(e1, e2)[:, 2]).sum()
    assert _area(geoms) == pytest.approx(area, rel=0.01)


def test_rigid_object_has_no_counterpart():
    with pytest.raises(ValueError, match="ref_book"):
        T.rigid_counterpart(OBJECTS["ref_book"])


def test_variants():
    cloth = T.variants(OBJECTS["mousepad_standard"])
    assert len(cloth) == 16
    assert [v.transform for v in cloth] == ["original"] + ["scale"] * 7 + ["rigid"] + ["scale+rigid"] * 7
    # the original keeps its (grounded) catalog label -- A, measured; the rule says C for the original
    # and its scales alike, so the scales keep A too (no transform crosses a threshold of the rule);
    # the rigid counterparts change the rule's label (C -> A): they carry the rule's A
    assert [v.strategy for v in cloth] == ["A"] * 16
    assert [v.label_source for v in cloth] == ["catalog"] + ["catalog_kept"] * 7 + ["rule"] * 8
    assert OBJECTS["mousepad_standard"].paper_strategy == "C"
    assert cloth[9].spec.id == cloth[1].spec.id + "@rigid" and cloth[9].spec.size == cloth[1].spec.size
    book = T.variants(OBJECTS["book_cookbook"], n_scales=3)
    assert len(book) == 4 and book[0].spec is OBJECTS["book_cookbook"]
    assert (
        book[0].strategy == "A" and book[0].label_source == "catalog"
    )  # the catalog label, even where the rule says B
    assert [v.strategy for v in book[1:]] == [T.label(v.spec) if T.label(v.spec) != T.label(book[0].spec) else "A" for v in book[1:]]
    thin = T.variants(OBJECTS["book_paperback_novel"], n_scales=7)  # a thin A book: its thickest scales cross into B
    assert {v.label_source for v in thin[1:]} == {"catalog_kept", "rule"}
    assert all(v.strategy == "B" for v in thin if v.label_source == "rule")
    assert len({v.spec.id for v in T.variants(OBJECTS["box_gift"])}) == 8


# ------------------------------------------------------------------------------ models
def _compile_and_step(spec, seconds=0.5):
    m = build_model(CELL, spec)
    d = mujoco.MjData(m)
    for arm in ARMS:
        for i, q in enumerate(HOME_Q):
            d.qpos[m.jnt_qposadr[m.joint(f"{arm}/joint{i + 1}").id]] = q
            d.ctrl[m.actuator(f"{arm}/actuator{i + 1}").id] = q
    mujoco.mj_forward(m, d)
    for _ in range(round(seconds / m.opt.timestep)):
        mujoco.mj_step(m, d)
    return m, d


TRANSFORMED = [
    ("book_a5_notebook", "min", False),
    ("box_shoe", "max", False),
    ("cutboard_butcher_block", "min", False),
    ("keyboard_full_size", "max", False),
    ("plate_side_ceramic", "min", False),
    ("mousepad_large", "max", False),
    ("shorts_denim", "min", True),
    ("skirt_a_line", "max", True),
    ("fabric_linen", None, True),
]


@pytest.mark.parametrize(
    "oid,end,rigid", TRANSFORMED, ids=[f"{o}-{e}-{'rigid' if r else 'own'}" for o, e, r in TRANSFORMED]
)
def test_transformed_object_compiles_and_settles(oid, end, rigid):
    o = OBJECTS[oid]
    spec = o if end is None else T.scaled(o, dict(zip(("min", "max"), T.scale_range(o, CELL)))[end])
    if rigid:
        spec = T.rigid_counterpart(spec)
    m, d = _compile_and_step(spec)
    assert not any(w.number for w in d.warning), [(i, w.number) for i, w in enumerate(d.warning) if w.number]
    assert np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))
    if not spec.deformable:
        bid = m.body("object").id
        assert m.body_mass[bid] == pytest.approx(spec.mass, rel=1e-5)  # MJCF keeps 6 digits
        assert abs(d.xpos[bid][2] - (CELL.table_height + spec.size[2] / 2)) < 2e-3  # resting flat on the table
        assert np.linalg.norm(d.cvel[bid][3:]) < 1e-2

"""The catalog: the paper's 21 categories / 104 objects, and one clear CatalogError per mistake."""

from __future__ import annotations

import collections
import re
import textwrap

import pytest

from flatlab_lerobot.catalog import (
    CATEGORIES,
    REFERENCE_OBJECTS,
    CatalogError,
    benchmark_objects,
    check_counts,
    load_materials,
    load_objects,
    load_scenes,
)
from flatlab_lerobot.sim.scene import CellConfig


def test_paper_counts():
    objs = load_objects()
    assert check_counts(objs) == []
    bench = benchmark_objects()
    assert len(bench) == 104 and len(CATEGORIES) == 21
    per_split = collections.Counter(o.split for o in bench)
    assert per_split == {"train": 30, "test_alpha": 30, "test_beta": 44}
    assert {o.category for o in bench} == set(CATEGORIES)


def test_strategy_labels_follow_design():
    for o in benchmark_objects():
        if o.deformable:
            assert o.paper_strategy == "C", o.id
        elif o.category in ("Book", "Photo Album"):
            assert o.paper_strategy == ("A" if o.size[2] <= 0.03 else "B"), o.id
        else:
            assert o.paper_strategy == CATEGORIES[o.category].strategies[0], o.id
        assert o.relabelled == (o.strategy != o.paper_strategy)
    # thickness decides within the mixed categories: both labels occur
    for cat in ("Book", "Photo Album"):
        assert {o.paper_strategy for o in benchmark_objects() if o.category == cat} == {"A", "B"}


def test_objects_differ_within_category():
    by_cat = collections.defaultdict(list)
    for o in benchmark_objects():
        by_cat[o.category].append(o)
    for cat, objs in by_cat.items():
        looks = {(o.size, o.mass, o.rgba) for o in objs}
        assert len(looks) == len(objs), cat
        assert len({o.rgba for o in objs}) >= len(objs) - 1, f"{cat}: objects should look different"


def test_physical_ranges():
    for o in benchmark_objects():
        if o.deformable:
            assert 0.1 <= o.size[0] <= 0.35 + 1e-9 and 0.1 <= o.size[1] <= 0.35 + 1e-9, o.id
            assert o.flex.count[0] <= 15 and o.flex.count[1] <= 15, o.id
        else:
            assert 0.005 <= o.size[2] <= 0.08, o.id
            assert max(o.size[:2]) <= 0.4, o.id
    pads = [o for o in benchmark_objects() if o.category == "Mouse Pad"]
    fabrics = [o for o in benchmark_objects() if o.category in ("Fabric", "Towel")]
    assert min(p.flex.young for p in pads) > max(f.flex.young for f in fabrics)


def test_reference_objects_unchanged():
    objs = load_objects()
    book, box, towel = (objs[REFERENCE_OBJECTS[s]] for s in "ABC")
    assert book.size == (0.22, 0.15, 0.02) and book.mass == 0.4 and book.shape == "slab"
    assert box.size == (0.30, 0.22, 0.08) and box.mass == 1.0 and box.strategy == "B"
    assert towel.deformable and towel.flex.count == (15, 15) and towel.shape == "sheet"


GOOD = """\
objects:
  - id: my_book
    category: Book
    split: train
    material: rigid
    shape: book
    size: [0.2, 0.15, 0.02]
    mass: 0.3
    strategy: A
"""


def _write(tmp_path, text, name="cat.yaml"):
    (tmp_path / name).write_text(textwrap.dedent(text))
    return tmp_path


def test_good_file_loads(tmp_path):
    objs = load_objects(_write(tmp_path, GOOD))
    assert objs["my_book"].param("page_rgba") == (0.95, 0.93, 0.86, 1)
    assert objs["my_book"].paper_strategy == "A" and not objs["my_book"].relabelled


def test_grounded_relabel(tmp_path):
    """A grounded label may leave the category's strategies; the paper's label stays alongside."""
    objs = load_objects(_write(tmp_path, GOOD.replace("strategy: A\n", "strategy: C\n    paper_strategy: A\n")))
    book = objs["my_book"]
    assert (book.strategy, book.paper_strategy, book.relabelled) == ("C", "A", True)


@pytest.mark.parametrize(
    "edit, field, message",
    [
        (("    mass: 0.3\n", ""), "mass", "missing"),
        (("category: Book", "category: Spaceship"), "category", "must be one of"),
        (("split: train", "split: validation"), "split", "must be one of"),
        (("split: train", "split: test_beta"), "split", "has no objects in split"),
        (("mass: 0.3", "mass: -1"), "mass", "must be >="),
        (("mass: 0.3", "mass: heavy"), "mass", "must be a number"),
        (("size: [0.2, 0.15, 0.02]", "size: [0.2, 0.15, 0.3]"), "size[2]", "must be in"),
        (("size: [0.2, 0.15, 0.02]", "size: [0.2, 0.15]"), "size", "list of 3"),
        (("strategy: A", "strategy: C"), "strategy", "expects strategy"),
        (("material: rigid", "material: deformable"), "material", "is rigid"),
        (("shape: book", "shape: teapot"), "shape", "must be one of"),
        (("strategy: A\n", "strategy: A\n    colour: red\n"), "colour", "unknown field"),
        (("strategy: A\n", "strategy: A\n    params: {cover: 0.5}\n"), "params.cover", "must be <="),
        (("strategy: A\n", "strategy: A\n    params: {wheels: 4}\n"), "params.wheels", "unknown parameter"),
        (("strategy: A\n", "strategy: A\n    com_offset: [0.5, 0, 0]\n"), "com_offset[0]", "inside the object"),
        (("strategy: A\n", "strategy: A\n    rgba: [1, 0, 0, 2]\n"), "rgba[3]", "must be <="),
        (("strategy: A\n", "strategy: A\n    flex: {count: [5, 5]}\n"), "flex", "only deformable"),
        (("strategy: A\n", "strategy: B\n    paper_strategy: C\n"), "paper_strategy", "expects strategy"),
        (("strategy: A\n", "strategy: A\n    paper_strategy: A\n"), "paper_strategy", "only for a grounded relabel"),
        (("strategy: A\n", "strategy: D\n    paper_strategy: A\n"), "strategy", "must be one of"),
    ],
)
def test_one_clear_error(tmp_path, edit, field, message):
    old, new = edit
    assert old in GOOD
    path = _write(tmp_path, GOOD.replace(old, new))
    with pytest.raises(CatalogError) as exc:
        load_objects(path)
    text = str(exc.value)
    assert "cat.yaml" in text and "'my_book'" in text and f"field '{field}'" in text and message in text, text


def test_malformed_yaml(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with pytest.raises(CatalogError, match=r"(?s)bad\.yaml: not valid YAML.*line 2"):
        load_objects(_write(tmp_path / "a", "objects:\n  - id: [unclosed\n", "bad.yaml"))
    with pytest.raises(CatalogError, match=r"list\.yaml: field 'objects'"):
        load_objects(_write(tmp_path / "b", "things: 3\n", "list.yaml"))


def test_duplicate_and_missing_id(tmp_path):
    dup = tmp_path / "dup"
    dup.mkdir()
    _write(dup, GOOD, "a.yaml")
    _write(dup, GOOD, "b.yaml")
    with pytest.raises(CatalogError, match=r"b\.yaml: object 'my_book': field 'id': duplicate"):
        load_objects(dup)
    with pytest.raises(CatalogError, match=r"cat\.yaml: object .*: field 'id': missing"):
        load_objects(_write(tmp_path, GOOD.replace("- id: my_book", "- name: x")))


def test_deformable_flex_validation(tmp_path):
    sheet = """\
objects:
  - id: my_towel
    category: Towel
    split: test_beta
    material: deformable
    shape: sheet
    size: [0.3, 0.3, 0.002]
    mass: 0.1
    strategy: C
    flex: {count: [15, 15], young: 1.0e+6}
"""
    assert load_objects(_write(tmp_path, sheet))["my_towel"].flex.young == 1e6
    with pytest.raises(CatalogError, match=r"'my_towel': field 'flex.count\[0\]': must be <= 15"):
        load_objects(_write(tmp_path, sheet.replace("[15, 15]", "[40, 15]")))
    with pytest.raises(CatalogError, match=r"field 'flex.young'"):
        load_objects(_write(tmp_path, sheet.replace("1.0e+6", "-3")))
    with pytest.raises(CatalogError, match=r"field 'shape'"):
        load_objects(_write(tmp_path, sheet.replace("shape: sheet", "shape: slab")))


def test_scenes_and_materials():
    mats, scenes = load_materials(), load_scenes()
    assert len(mats) >= 10 and len(scenes) == 18
    rooms = collections.Counter(s.room for s in scenes.values())
    assert rooms == {r: 3 for r in ("Bedroom", "Kitchen", "Laundryroom", "Livingroom", "Study", "Warehouse")}
    for sid in scenes:
        cell = CellConfig.from_scene(sid)
        assert cell.table_friction == mats[scenes[sid].material].friction


def test_scene_errors(tiny_scene_catalog):
    scenes, mats, good = tiny_scene_catalog("edge: square, material: oak")
    assert load_scenes(scenes, mats)["s1"].room == "Study"
    for old, new, field in [("Study", "Garage", "room"), ("material: oak", "material: jade", "material"),
                            ("table_height: 0.75", "table_height: 2.0", "table_height"),
                            ("edge: square", "edge: wavy", "edge"), ("[0.6, 0.9]", "[0.6, 3.0]", "table_size[1]")]:
        (scenes / "s.yaml").write_text(good.replace(old, new))
        with pytest.raises(CatalogError, match=rf"s\.yaml: scene 's1': field '{re.escape(field)}'"):
            load_scenes(scenes, mats)
    (mats / "m.yaml").write_text("materials:\n  - {id: oak, name: oak, friction: 9, rgba: [0.6, 0.4, 0.3, 1]}\n")
    with pytest.raises(CatalogError, match=r"m\.yaml: material 'oak': field 'friction'"):
        load_materials(mats)

"""``flatlab strategy-set``: normalized object clouds with strategy labels, from the sim pipeline."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from flatlab_lerobot import transforms as T
from flatlab_lerobot.catalog import load_objects
from flatlab_lerobot.learning import strategy_set as S

OBJECTS = load_objects()
# one A book, one B box, one cloth (C, and its rigid counterparts: A); 2 scales each
CFG = S.SetConfig(objects=("book_a5_notebook", "box_gift", "mousepad_standard"), n_scales=2, image_size=256, settle=0.3)
CLI = ["--objects", ",".join(CFG.objects), "--scales", "2", "--image-size", "256", "--settle", "0.3", "--quiet"]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("sset") / "set"
    S.build(CFG, out, workers=1, progress=False)
    return out, *S.load(out)


def test_shapes_and_normalization(built):
    out, clouds, index, meta = built
    n = 3 + 3 + 6  # (original + 2 scales) per object, + the cloth's 3 rigid counterparts
    assert clouds.shape == (n, 2048, 3) and clouds.dtype == np.float32
    assert len(index) == n == meta["n_clouds"]
    norms = np.linalg.norm(clouds, axis=2)
    assert norms.max() <= 1 + 1e-5 and np.allclose(norms.max(axis=1), 1.0, atol=1e-5)  # inside, touching the sphere
    assert np.abs(clouds.mean(axis=1)).max() < 1e-5  # centred
    assert not any(p.name.startswith(".") for p in out.parent.iterdir())  # no temporary folder left
    # enough object pixels for 2048 distinct points, re-rendered larger where the object is small
    assert ((index.n_points_raw >= 2048) | (index.image_size == S.MAX_UPSCALE * CFG.image_size)).all()
    assert set(index.image_size) > {CFG.image_size}


def test_labels_and_transformations(built):
    _, _, index, meta = built
    variants = {v.spec.id: v for o in CFG.objects for v in T.variants(OBJECTS[o], 2)}
    assert list(index.object_id) == list(variants)
    for row in index.itertuples():
        v = variants[row.object_id]
        assert row.strategy == v.strategy and row.label == "ABC".index(row.strategy)
        assert row.base_object_id == v.base.id and row.category == v.base.category and row.split == "train"
        assert row.transform == v.transform and row.rigid_counterpart == v.rigid_counterpart
        if row.transform == "original":
            assert (
                row.strategy == OBJECTS[row.object_id].strategy and row.label_source == "catalog" and row.scale == 1.0
            )
        else:
            # the rule's label where the transform changes it, the base's grounded label otherwise
            kept = T.label(v.spec) == T.label(v.base)
            assert row.label_source == ("catalog_kept" if kept else "rule")
            assert row.strategy == (OBJECTS[row.base_object_id].strategy if kept else T.label(v.spec))
    cloth = index[index.base_object_id == "mousepad_standard"]
    assert list(cloth.strategy) == ["A"] * 6  # grounded A; the rule says C for every scale: A kept
    assert meta["counts"]["strategy"] == dict(sorted(index.strategy.value_counts().items()))
    assert meta["scale_ranges"]["box_gift"]["scales"] == list(T.seven_scales(OBJECTS["box_gift"], n=2))


def test_clouds_are_the_object(built):
    """Denormalized, an original rigid object's cloud lies on the object at its placement."""
    _, clouds, index, _ = built
    for i in index.index[(index.transform == "original") & (index.material == "rigid")]:
        row = index.loc[i]
        pts = clouds[i] * row.radius + np.array([row.centre_x, row.centre_y, row.centre_z])
        half_diag = 0.5 * np.hypot(row.size_x, row.size_y)
        assert np.linalg.norm(pts[:, :2] - [row.placement_x, row.placement_y], axis=1).max() <= half_diag + 0.005
        assert pts[:, 2].min() >= 0.75 - 0.002 and pts[:, 2].max() <= 0.75 + row.size_z + 0.002
        assert row.n_points_raw > 2048  # enough pixels: pure farthest-point samples
        assert len(np.unique(clouds[i], axis=0)) == 2048


def test_resample_is_deterministic_and_exact():
    pts = np.random.default_rng(1).random((5000, 3))
    a = S.resample(pts, 2048, np.random.default_rng(7))
    b = S.resample(pts, 2048, np.random.default_rng(7))
    assert a.shape == (2048, 3) and np.array_equal(a, b) and len(np.unique(a, axis=0)) == 2048
    few = S.resample(pts[:100], 2048, np.random.default_rng(7))  # every point kept, repeats fill up
    assert few.shape == (2048, 3) and len(np.unique(few, axis=0)) == 100
    with pytest.raises(ValueError):
        S.resample(pts[:0], 2048, np.random.default_rng(0))


def test_cli_rejects_bad_input(capsys):
    with pytest.raises(SystemExit) as e:
        S.main(["--objects", "no_such_thing"])
    assert e.value.code == 2 and "no_such_thing" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        S.main(["--splits", "nope"])
    with pytest.raises(SystemExit):
        S.main(["--scales", "-1"])
    with pytest.raises(SystemExit):
        S.main(["--cameras", "front,side"])


def test_failed_build_leaves_the_old_set(tmp_path, monkeypatch):
    out = tmp_path / "set"
    out.mkdir()
    (out / "meta.json").write_text("{}")

    def boom(variant, cfg):
        raise RuntimeError("simulated crash")

    monkeypatch.setattr(S, "capture_variant", boom)
    with pytest.raises(RuntimeError, match="book_a5_notebook.*simulated crash"):
        S.build(CFG, out, workers=1, progress=False)
    assert [p.name for p in tmp_path.iterdir()] == ["set"] and json.loads((out / "meta.json").read_text()) == {}


@pytest.mark.slow
def test_rebuild_is_deterministic(built, tmp_path, capsys):
    """The same settings through the CLI, with 2 worker processes and over an existing set,
    write the same clouds and index."""
    _, clouds, index, _ = built
    out = tmp_path / "set"
    assert S.main([*CLI, "--out", str(out), "--workers", "2"]) == 0
    assert S.main([*CLI, "--out", str(out), "--workers", "2"]) == 0  # replaces the first one
    assert "12 clouds of 2048 points from 3 objects" in capsys.readouterr().out
    clouds2, index2, meta2 = S.load(out)
    assert np.array_equal(clouds, clouds2)
    pd.testing.assert_frame_equal(index, index2)
    assert meta2["workers"] == 2 and meta2["settings"]["objects"] == list(CFG.objects)

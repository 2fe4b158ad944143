"""Depth back-projection and segmentation-based object clouds (CameraRig)."""

import numpy as np
import pytest

import flatlab_lerobot  # noqa: F401  (sets MUJOCO_GL before mujoco is imported)
from flatlab_lerobot.catalog import load_objects
from flatlab_lerobot.sim.cameras import GEOM, CameraRig, crop, sample
from flatlab_lerobot.sim.core import FlatLabSim

SIZE = 96


@pytest.fixture(scope="module", params=["ref_book", "ref_box", "ref_towel"])
def scene(request):
    sim = FlatLabSim(load_objects()[request.param])
    sim.reset(0.03, -0.02, 0.35)
    cams = [c.name for c in sim.cell.camera_specs()]
    rig = CameraRig(sim.model, SIZE, SIZE, cams)
    yield sim, rig, cams
    rig.close()


def test_table_plane_is_flat_at_true_height(scene):
    sim, rig, cams = scene
    h = sim.cell.table_height
    hx, hy = sim.cell.table_size[0] / 2, sim.cell.table_size[1] / 2
    for cam in cams:
        seg = rig.segmentation(sim.data, cam)
        mask = (seg[..., 1] == GEOM) & (seg[..., 0] == sim.table_geom)
        pts = rig.depth_to_points(rig.depth(sim.data, cam), cam, sim.data, mask)
        # the top face only: the slab's side faces lie exactly on |x| = hx or |y| = hy
        top = pts[(np.abs(pts[:, 0]) < hx - 1e-3) & (np.abs(pts[:, 1]) < hy - 1e-3)]
        assert len(top) > 200, cam
        assert np.max(np.abs(top[:, 2] - h)) < 2e-3, (cam, top[:, 2].min() - h, top[:, 2].max() - h)


def test_object_cloud_contains_only_object_points(scene):
    sim, rig, cams = scene
    tol = 4e-3
    for cam in cams:
        pts = rig.object_points(sim.data, sim.obj_geoms, sim.flex_id, [cam])
        assert len(pts) > 20, cam
        if sim.flex_id >= 0:
            verts = sim.object_points()
            r = sim.model.flex_radius[sim.flex_id]
            lo, hi = verts.min(0) - r - tol, verts.max(0) + r + tol
            assert np.all((pts >= lo) & (pts <= hi)), cam
        else:
            pos, R = sim.data.xpos[sim.obj_body], sim.data.xmat[sim.obj_body].reshape(3, 3)
            local = (pts - pos) @ R
            half = np.asarray(sim.obj.size) / 2
            assert np.all(np.abs(local) <= half + tol), (cam, np.abs(local).max(0), half)


def test_intrinsics_match_back_projection(scene):
    sim, rig, _ = scene
    fx, fy, cx, cy = rig.intrinsics("front")
    fovy = np.deg2rad(sim.model.cam_fovy[sim.model.camera("front").id])
    assert fx == fy == pytest.approx((SIZE / 2) / np.tan(fovy / 2))
    assert cx == cy == pytest.approx(SIZE / 2 - 0.5)
    _, R = rig.extrinsics(sim.data, "front")
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-9)


def test_rgb_depth_come_from_one_cached_render(scene):
    sim, rig, _ = scene
    rgb, depth = rig.rgb(sim.data, "top"), rig.depth(sim.data, "top")
    assert rgb.shape == (SIZE, SIZE, 3) and rgb.dtype == np.uint8
    assert depth.shape == (SIZE, SIZE) and depth.dtype == np.float32
    assert rig.rgb(sim.data, "top") is rgb  # cached, not re-rendered
    # matches mujoco.Renderer's own depth mode
    r = rig.renderer()
    r.update_scene(sim.data, "top")
    r.enable_depth_rendering()
    ref = r.render()
    r.disable_depth_rendering()
    assert np.allclose(depth, ref, atol=1e-4)


def test_crop_and_sample_are_deterministic():
    pts = np.random.default_rng(0).uniform(-1, 1, (500, 3))
    inside = crop(pts, [-0.5] * 3, [0.5] * 3)
    assert np.all(np.abs(inside) <= 0.5)
    a = sample(pts, 64, np.random.default_rng(3))
    b = sample(pts, 64, np.random.default_rng(3))
    assert a.shape == (64, 3) and a.dtype == np.float32 and np.array_equal(a, b)
    few = sample(pts[:5], 12, np.random.default_rng(1))  # padded by repetition
    assert few.shape == (12, 3) and len(np.unique(few, axis=0)) == 5
    assert np.array_equal(sample(pts[:0], 8, np.random.default_rng(1)), np.zeros((8, 3), np.float32))

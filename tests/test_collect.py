"""``flatlab collect``: recipes, the episode runner, the LeRobotDataset v3 writer, crash/resume.

Kept fast: 32 px images, the rigid box (strategy B), 20-25 control steps per episode."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from flatlab_lerobot.collect.collector import collect
from flatlab_lerobot.collect.recipe import RecipeError, load_recipe, recipe_from_dict
from flatlab_lerobot.collect.runner import run_episode
from flatlab_lerobot.collect.features import depth_to_points, episode_cameras
from flatlab_lerobot.collect.store import EPISODES_JSONL, META_JSON, READY, DatasetStore

REPO = Path(__file__).resolve().parents[1]
PY = sys.executable
BIN = Path(sys.executable).parent

TINY = {
    "name": "t",
    "repo_id": "local/flatlab_t",
    "seed": 7,
    "episodes": 2,
    "objects": ["ref_box"],
    "max_steps": 20,
    "cameras": ["front", "top"],
    "image_size": 32,
    "modalities": ["rgb", "depth", "pointcloud", "object_pointcloud", "ee_pose", "environment_state"],
    "n_points": 128,
    "n_object_points": 32,
}
NON_VIDEO = [
    "observation.state", "action", "observation.pointcloud", "observation.object_pointcloud",
    "observation.ee_pose", "observation.environment_state", "stage_index", "stage", "strategy",
    "object_id", "success", "failure_reason", "episode_seed", "episode_index", "frame_index", "index",
]  # fmt: skip


def write_recipe(path: Path, **over) -> Path:
    path.write_text(yaml.safe_dump({**TINY, **over}))
    return path


def load_ds(root: Path, repo_id="local/flatlab_t"):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(repo_id, root=root, video_backend="pyav")


def table(root: Path) -> pd.DataFrame:
    """All data rows (arrays as numpy), sorted by global index (pandas cannot read Array2D columns)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    files = sorted((root / "data").rglob("*.parquet"))
    t = pa.concat_tables([pq.read_table(f) for f in files], promote_options="default")
    cols = {}
    for name in t.column_names:
        vals = t.column(name).to_pylist()
        cols[name] = [np.asarray(v) for v in vals] if vals and isinstance(vals[0], list) else vals
    return pd.DataFrame(cols).sort_values("index").reset_index(drop=True)


def assert_same_nonvideo(a: Path, b: Path):
    ta, tb = table(a), table(b)
    assert len(ta) == len(tb)
    for col in NON_VIDEO:
        va, vb = ta[col].tolist(), tb[col].tolist()
        if isinstance(va[0], np.ndarray):
            np.testing.assert_array_equal(np.stack(va), np.stack(vb), err_msg=col)
        else:
            assert va == vb, col


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    d = tmp_path_factory.mktemp("collect")
    recipe = load_recipe(write_recipe(d / "t.yaml"))
    t0 = time.perf_counter()
    summary = collect(recipe, d / "out", progress=False)
    summary["wall"] = time.perf_counter() - t0
    return recipe, d / "out" / "t", summary


# ------------------------------------------------------------------------------------ recipes
def test_shipped_recipes_load():
    for p in sorted((REPO / "datasets").glob("*.yaml")):
        r = load_recipe(p)
        assert r.episodes >= 1 and r.objects, p
    assert not (REPO / "datasets" / "__init__.py").exists()


@pytest.mark.parametrize(
    "over, field",
    [
        ({"image_size": "big"}, "image_size"),
        ({"image_size": 4}, "image_size"),
        ({"camras": ["front"]}, "camras"),
        ({"objects": ["no_such_object"]}, "objects"),
        ({"modalities": ["rgb", "lidar"]}, "modalities"),
        ({"cameras": ["front", "ceiling"]}, "cameras"),
        ({"fps": 0}, "fps"),
        ({"video": {"vcodec": "mjpeg"}}, "video.vcodec"),
        ({"video": {"codec": "h264"}}, "video.codec"),
        ({"randomization": {"xy_range": -1}}, "randomization.xy_range"),
        ({"strategy": "D"}, "strategy"),
        ({"episodes": None}, "episodes"),
        ({"workers": 0}, "workers"),
        ({"video": {"preset": "warp"}}, "video.preset"),
        ({"video": {"depth_preset": 3}}, "video.depth_preset"),
        ({"video": {"vcodec": "libsvtav1", "preset": "fast"}}, "video.preset"),
        ({"randomization": {"joint_noise": 2.0}}, "randomization.joint_noise"),
        ({"randomization": {"mass_scale": [1.2, 0.8]}}, "randomization.mass_scale"),
        ({"randomization": {"friction_scale": "wet"}}, "randomization.friction_scale"),
        ({"randomization": {"camera_rot_jitter_deg": -1}}, "randomization.camera_rot_jitter_deg"),
        ({"randomization": {"light": 1}}, "randomization.light"),
        ({"expert": {"b_right_half_turn": "yes"}}, "expert.b_right_half_turn"),
        ({"expert": {"left_half_turn": True}}, "expert.left_half_turn"),
        ({"expert": True}, "expert"),
    ],
)
def test_malformed_recipe_names_file_and_field(tmp_path, over, field):
    p = write_recipe(tmp_path / "bad.yaml", **over)
    with pytest.raises(RecipeError) as e:
        load_recipe(p)
    msg = str(e.value)
    assert str(p) in msg and f"field '{field}'" in msg, msg


def test_missing_field_and_bad_yaml(tmp_path):
    raw = dict(TINY)
    del raw["objects"]
    p = tmp_path / "missing.yaml"
    p.write_text(yaml.safe_dump(raw))
    with pytest.raises(RecipeError, match=r"missing\.yaml: field 'objects': is required"):
        load_recipe(p)
    q = tmp_path / "broken.yaml"
    q.write_text("name: [unclosed\n")
    with pytest.raises(RecipeError, match=r"broken\.yaml: invalid YAML"):
        load_recipe(q)


def test_workers_and_commit_size_do_not_change_the_fingerprint():
    import dataclasses

    r = recipe_from_dict(TINY, "t.yaml")
    assert r.workers == 1
    assert dataclasses.replace(r, workers=4, commit_every=7).fingerprint() == r.fingerprint()
    fast = recipe_from_dict({**TINY, "video": {"preset": "veryfast", "depth_preset": "ultrafast"}}, "t.yaml")
    assert fast.video.preset == "veryfast" and fast.fingerprint() != r.fingerprint()


def test_expert_options_change_the_fingerprint_and_the_default_keeps_older_ones():
    r = recipe_from_dict(TINY, "t.yaml")
    same = recipe_from_dict({**TINY, "expert": {"b_right_half_turn": False}}, "t.yaml")
    turned = recipe_from_dict({**TINY, "expert": {"b_right_half_turn": True}}, "t.yaml")
    assert not r.expert.b_right_half_turn and turned.expert.b_right_half_turn
    assert same.fingerprint() == r.fingerprint() != turned.fingerprint()
    assert "expert" not in r.to_dict() or r.to_dict()["expert"] == {"b_right_half_turn": False}
    # the collected overfit_box_shoe demos (stop 54) carry this fingerprint; the field added later must keep it
    assert load_recipe(REPO / "datasets" / "overfit_box_shoe.yaml").fingerprint() == "49bdc84f6057a2db"


def test_cli_rejects_bad_worker_count(tmp_path, capsys):
    from flatlab_lerobot.collect.collector import main

    p = write_recipe(tmp_path / "t.yaml")
    assert main(["--recipe", str(p), "--out", str(tmp_path), "--workers", "0"]) == 2
    assert "--workers" in capsys.readouterr().err and not (tmp_path / "t").exists()


def test_cli_reports_recipe_error(tmp_path):
    p = write_recipe(tmp_path / "bad.yaml", image_size="huge")
    r = subprocess.run([PY, "-m", "flatlab_lerobot.collect", "--recipe", str(p), "--out", str(tmp_path)],
                       check=False, capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2 and "field 'image_size'" in r.stderr and str(p) in r.stderr


# ------------------------------------------------------------------------------------ dataset
def test_dataset_loads_with_all_features(tiny):
    _, root, summary = tiny
    ds = load_ds(root)
    assert ds.num_episodes == 2 and summary["episodes_total"] == 2
    x = ds[0]
    assert x["observation.images.front"].shape == (3, 32, 32)
    assert x["observation.depth.top"].shape == (1, 32, 32)
    assert x["observation.pointcloud"].shape == (128, 3) and x["observation.object_pointcloud"].shape == (32, 3)
    assert x["observation.ee_pose"].shape == (14,) and x["observation.environment_state"].shape == (14,)
    assert x["observation.state"].shape == (16,) and x["action"].shape == (16,)
    assert x["stage_index"].dtype.is_floating_point is False and isinstance(x["stage"], str)
    assert x["strategy"] == "B" and x["object_id"] == "ref_box" and x["episode_seed"] == 7
    # success / failure label constant within each episode, and consistent with the records
    df = table(root)
    recs = [json.loads(line) for line in (root / EPISODES_JSONL).read_text().splitlines()]
    assert [r["seed"] for r in recs] == [7, 8]
    for r in recs:
        ep = df[df.episode_index == r["dataset_episode_index"]]
        assert ep.success.nunique() == 1 and bool(ep.success.iloc[0]) == r["success"]
        assert set(ep.failure_reason) == {r["failure_reason"]} and len(ep) == r["num_frames"]
        if not r["success"]:
            assert r["failure_reason"]
    # ee quaternions are unit
    q = np.stack(df["observation.ee_pose"].tolist()).reshape(-1, 2, 7)[..., 3:]
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-5)
    assert (root / "README.md").read_text().startswith("---")
    print(f"tiny collect: {summary['wall']:.1f} s")


def test_camera_meta_rebuilds_clouds_from_depth(tiny):
    """The saved intrinsics/extrinsics back-project depth exactly as the sim's own rig does."""
    from flatlab_lerobot.collect.runner import make_env

    recipe, root, _ = tiny
    meta = json.loads((root / META_JSON).read_text())
    assert set(meta["cameras"]) == {"front", "top"}
    env = make_env(recipe, "ref_box")
    try:
        env.reset(seed=0)
        for cam in ("front", "top"):
            depth = env.rig.depth(env.sim.data, cam)
            ours = depth_to_points(depth, meta["cameras"][cam])
            theirs = env.rig.depth_to_points(depth, cam, env.sim.data)
            np.testing.assert_allclose(ours, theirs, atol=1e-6)
    finally:
        env.close()
    # the decoded depth of frame 0 (mm, lossy 12-bit log quantisation) rebuilds the true cloud
    from flatlab_lerobot.collect.runner import sample_placement

    env = make_env(recipe, "ref_box")
    try:
        env.reset(seed=recipe.seed, options={"placement": sample_placement(recipe, recipe.seed)})
        ds = load_ds(root)
        for cam in ("front", "top"):
            true_m = env.rig.depth(env.sim.data, cam)
            dec_m = ds[0][f"observation.depth.{cam}"][0].numpy() / 1000.0
            hit = true_m < 0.9 * meta["cameras"][cam]["zfar"]
            assert np.median(np.abs(dec_m - true_m)[hit] / true_m[hit]) < 0.01
            a = depth_to_points(np.where(hit, dec_m, 0.0), meta["cameras"][cam])
            b = env.rig.depth_to_points(np.where(hit, true_m, np.inf), cam, env.sim.data)
            assert a.shape == b.shape and np.median(np.linalg.norm(a - b, axis=1)) < 0.02
    finally:
        env.close()


JITTER = {"joint_noise": 0.08, "camera_pos_jitter": 0.02, "camera_rot_jitter_deg": 2.0,
          "mass_scale": [0.7, 1.3], "friction_scale": [0.7, 1.3]}  # fmt: skip


def test_domain_randomization_is_recorded_applied_and_rebuilds_clouds(tmp_path):
    """Start posture, object mass/friction and camera poses are drawn per episode seed, recorded
    with the episode, really set in the sim, and the recorded camera poses back-project the
    episode's depth exactly as the sim's rig does."""
    from flatlab_lerobot.collect.runner import make_env, sample_placement
    from flatlab_lerobot.sim.domain import Domain
    from flatlab_lerobot.sim.robot import HOME_Q

    recipe = load_recipe(write_recipe(tmp_path / "t.yaml", episodes=2, max_steps=3, randomization=JITTER))
    assert recipe.randomization.domain(7, ["front"]) == recipe.randomization.domain(7, ["front"])
    collect(recipe, tmp_path / "out", progress=False)
    root = tmp_path / "out" / "t"
    recs = DatasetStore(recipe, tmp_path / "out").records()
    meta = json.loads((root / META_JSON).read_text())
    doms = [r["domain"] for r in recs]
    assert doms[0] != doms[1] and all(0.7 <= d["mass_scale"] <= 1.3 for d in doms)
    rows = table(root)
    for r, d in zip(recs, doms):  # the arms start where the domain put them
        first = rows[rows.episode_index == r["dataset_episode_index"]].iloc[0]["observation.state"]
        home = np.r_[first[:7], first[8:15]]
        np.testing.assert_allclose(home - np.r_[HOME_Q, HOME_Q], d["home_offsets"], atol=0.02)
    rec, dom = recs[1], Domain.from_json(doms[1])
    cams = episode_cameras(meta["cameras"], rec)
    for c in ("front", "top"):
        assert not np.allclose(cams[c]["cam_to_world"], meta["cameras"][c]["cam_to_world"])
    env = make_env(recipe, "ref_box")
    try:
        env.reset(seed=rec["seed"], options={"placement": sample_placement(recipe, rec["seed"]), "domain": dom})
        m, o = env.sim.model, env.sim.objects[0]
        nominal = env.sim.domain_nominal
        assert m.body_mass[o.body] == pytest.approx(nominal.body_mass[o.body] * dom.mass_scale)
        assert m.geom_friction[o.geoms[0], 0] == pytest.approx(nominal.geom_friction[o.geoms[0], 0] * dom.friction_scale)
        for c in ("front", "top"):
            depth = env.rig.depth(env.sim.data, c)
            ours = depth_to_points(depth, cams[c])
            np.testing.assert_allclose(ours, env.rig.depth_to_points(depth, c, env.sim.data), atol=1e-6)
            assert not np.allclose(ours, depth_to_points(depth, meta["cameras"][c]), atol=1e-3)
        env.reset(seed=0)  # no domain: back to the nominal cell
        assert m.body_mass[o.body] == nominal.body_mass[o.body]
        np.testing.assert_array_equal(m.cam_pos, nominal.cam_pos)
    finally:
        env.close()


def test_same_recipe_and_seed_give_identical_data(tiny, tmp_path):
    recipe, root, _ = tiny
    collect(recipe, tmp_path, progress=False)
    assert_same_nonvideo(root, tmp_path / "t")


def test_two_workers_give_the_same_dataset(tiny, tmp_path):
    """Episodes simulated (and encoded) by a 2-process pool are added in index order: the data,
    lerobot's stats and the decoded depth equal the in-process run exactly.  The stats are
    computed on the raw frames, so equal stats mean the workers rendered the same RGB.  Decoded
    RGB is compared with a tolerance: it is lossy h264, whose bitstream is not reproducible run
    to run even from identical frames (a CI run saw one 32-px frame differ by 0.028 on average),
    and each copy may be off its raw frame by the codec's own error -- measured here as up to
    ~0.02 per frame at crf 30 -- so two copies may differ by about twice that."""
    from flatlab_lerobot.collect.collector import with_overrides

    recipe, root, _ = tiny
    s = collect(with_overrides(recipe, workers=2), tmp_path, progress=False)
    other = tmp_path / "t"
    assert s["workers"] == 2 and len(s["worker_peak_rss_mb"]) >= 1
    assert all(0 < v < 2048 for v in s["worker_peak_rss_mb"].values())
    assert_same_nonvideo(root, other)
    assert (other / "meta" / "stats.json").read_text() == (root / "meta" / "stats.json").read_text()
    strip = lambda p: [{k: v for k, v in json.loads(x).items() if k != "wall_time_s"}
                       for x in (p / EPISODES_JSONL).read_text().splitlines()]  # fmt: skip
    assert strip(other) == strip(root)
    a, b = load_ds(root), load_ds(other)
    assert len(a) == len(b) and sorted(a.meta.video_keys) == sorted(b.meta.video_keys)
    for i in range(len(a)):
        xa, xb = a[i], b[i]
        for k in a.meta.video_keys:
            if k.startswith("observation.depth."):
                np.testing.assert_array_equal(xa[k].numpy(), xb[k].numpy(), err_msg=k)
            else:
                assert float((xa[k] - xb[k]).abs().mean()) < 0.06, (k, i)
    assert not (tmp_path / ".t.work").exists()


def test_depth_quantiser_matches_lerobot():
    from lerobot.datasets.depth_utils import quantize_depth as lerobot_quantize

    from flatlab_lerobot.collect.video import quantize_depth, stream_specs

    spec = stream_specs(recipe_from_dict(TINY, "t.yaml"))["observation.depth.front"]
    rng = np.random.default_rng(0)
    depth = np.concatenate([[0.0, 0.01, 0.3, 1.0, 9.99, 10.0, 80.0], rng.uniform(0.0, 12.0, 5100)]).astype(np.float32)
    depth = depth[: 71 * 71].reshape(71, 71, 1)
    ours = quantize_depth(depth, spec)
    theirs = lerobot_quantize(depth, depth_min=spec.depth_min, depth_max=spec.depth_max, shift=spec.shift,
                              use_log=spec.use_log, pix_fmt=spec.pix_fmt, video_backend=None)  # fmt: skip
    assert ours.dtype == np.uint16 and ours.shape == (71, 71) and ours.max() <= spec.qmax
    np.testing.assert_array_equal(ours, theirs)


@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
def test_video_stats_are_exact_and_in_lerobot_layout(dtype):
    from lerobot.datasets.compute_stats import get_feature_stats

    from flatlab_lerobot.collect.video import STATS_QUANTILES, image_stats

    rng = np.random.default_rng(1)
    if dtype == np.uint8:
        frames = rng.integers(0, 256, (7, 20, 24, 3)).astype(np.uint8)
        frames[..., 1] //= 3  # channels with different spreads
    else:
        frames = rng.lognormal(0.0, 0.5, (7, 20, 24, 1)).astype(np.float32)
    st = image_stats(frames)
    x = frames.reshape(-1, frames.shape[-1]).astype(np.float64)
    np.testing.assert_allclose(st["mean"], x.mean(0), rtol=1e-12)
    np.testing.assert_allclose(st["std"], x.std(0), rtol=1e-9)
    np.testing.assert_array_equal(st["min"], x.min(0))
    np.testing.assert_array_equal(st["max"], x.max(0))
    for q in STATS_QUANTILES:
        np.testing.assert_allclose(st[f"q{round(q * 100):02d}"], np.quantile(x, q, axis=0), rtol=1e-6)
    assert st["count"].tolist() == [7]
    # the keys and per-channel shapes lerobot computes itself (its values are histogram estimates)
    ref = get_feature_stats(np.moveaxis(frames, -1, 1), axis=(0, 2, 3), keepdims=True)
    assert set(st) == set(ref)
    for k in ref:
        if k != "count":
            assert st[k].shape == ref[k].squeeze(0).reshape(-1).shape
            np.testing.assert_allclose(st[k], ref[k].reshape(-1), rtol=0.05, atol=2.0 if dtype == np.uint8 else 0.05)


def test_rerun_is_a_noop_and_extends(tiny, tmp_path):
    recipe, root, _ = tiny
    shutil.copytree(root, tmp_path / "t")
    s = collect(recipe, tmp_path, progress=False)
    assert s["episodes_new"] == 0 and s["episodes_total"] == 2
    other = recipe_from_dict({**TINY, "seed": 8}, "x.yaml")
    from flatlab_lerobot.collect.store import DatasetMismatch

    with pytest.raises(DatasetMismatch, match="different recipe"):
        collect(other, tmp_path, progress=False)


# ------------------------------------------------------------------------------------ faults
def test_injected_divergence_marks_episode_failed(tmp_path, monkeypatch):
    from flatlab_lerobot.sim.core import FlatLabSim, SimulationDiverged

    orig = FlatLabSim.step

    def step(self, target):
        if self.data.time > 1.0:  # after the reset's settling, a few control steps in
            raise SimulationDiverged("injected fault")
        return orig(self, target)

    monkeypatch.setattr(FlatLabSim, "step", step)
    recipe = recipe_from_dict({**TINY, "episodes": 1, "modalities": ["ee_pose"], "cameras": []}, "t.yaml")
    res = run_episode(recipe, 0)
    assert not res.success and "injected fault" in res.failure_reason and "diverged" in res.failure_reason
    assert 0 < len(res.frames) < recipe.max_steps
    assert all(not f["success"][0] and f["failure_reason"] == res.failure_reason for f in res.frames)
    # ... and it is kept in the dataset, labelled
    collect(recipe, tmp_path, progress=False)
    df = table(tmp_path / "t")
    assert len(df) == len(res.frames) and not df.success.any() and df.failure_reason.str.contains("injected").all()


def test_expert_exception_is_a_labelled_failure(monkeypatch):
    from flatlab_lerobot import strategies

    def boom(*a, **k):
        raise RuntimeError("IK exploded")

    monkeypatch.setattr(strategies.Expert, "ik", boom)
    recipe = recipe_from_dict({**TINY, "episodes": 1, "modalities": [], "cameras": []}, "t.yaml")
    res = run_episode(recipe, 0)
    assert not res.success and "IK exploded" in res.failure_reason


def test_recover_from_every_crash_point(tiny, tmp_path):
    """The commit protocol: whatever step a crash interrupts, one consistent version remains."""
    recipe, root, _ = tiny
    out = tmp_path
    store = DatasetStore(recipe, out)
    # crash while writing staging (no marker): staging dropped, committed kept
    shutil.copytree(root, store.root)
    shutil.copytree(root, store.staging)
    assert store.recover() == "discarded uncommitted episodes"
    assert not store.staging.exists() and len(store.records()) == 2
    # crash between rename(committed -> old) and rename(staging -> committed), marker written
    os.replace(store.root, store.old)
    shutil.copytree(store.old, store.staging)
    (store.staging / READY).write_text("ok")
    assert store.recover() == "completed an interrupted commit"
    assert store.root.exists() and not store.old.exists() and not (store.root / READY).exists()
    # same, but the marker never made it: roll back to the old version
    os.replace(store.root, store.old)
    shutil.copytree(store.old, store.staging)
    assert store.recover() == "restored the previous version"
    assert load_ds(store.root).num_episodes == 2


def test_kill_and_resume(tiny, tmp_path):
    """kill -9 the collector after its first committed episode; the re-run loses and duplicates
    nothing, and the result equals an uninterrupted run."""
    _, ref_root, _ = tiny
    p = write_recipe(tmp_path / "t.yaml", episodes=3)
    out = tmp_path / "out"
    cmd = [PY, "-m", "flatlab_lerobot.collect", "--recipe", str(p), "--out", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    recs = out / "t" / EPISODES_JSONL
    t0 = time.time()
    try:
        while time.time() - t0 < 90:
            if recs.is_file() and recs.read_text().count("\n") >= 1:
                break
            assert proc.poll() is None, "collector exited early"
            time.sleep(0.05)
        else:
            pytest.fail("no episode committed within 90 s")
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    n_before = len(load_ds(out / "t").meta.episodes)
    assert 1 <= n_before < 3
    r = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    ds = load_ds(out / "t")
    assert ds.num_episodes == 3
    df = table(out / "t")
    assert sorted(df.episode_index.unique()) == [0, 1, 2] and df["index"].is_unique
    assert [json.loads(x)["seed"] for x in recs.read_text().splitlines()] == [7, 8, 9]
    # the first two episodes equal the uninterrupted reference run
    full = table(ref_root)
    part = df[df.episode_index < 2].reset_index(drop=True)
    assert len(part) == len(full)
    for col in ("observation.state", "action", "observation.pointcloud"):
        np.testing.assert_array_equal(np.stack(part[col].tolist()), np.stack(full[col].tolist()), err_msg=col)
    assert not any(p.name.startswith(".t.") for p in out.iterdir())


@pytest.mark.slow
def test_kill_parent_with_workers_then_resume(tiny, tmp_path):
    """kill -9 only the writer process of a 2-worker run: its workers notice and exit, and the
    re-run (1 worker) completes a dataset equal to the reference run."""
    import psutil

    _, ref_root, _ = tiny
    p = write_recipe(tmp_path / "t.yaml", episodes=3, commit_every=1)
    out = tmp_path / "out"
    cmd = [PY, "-m", "flatlab_lerobot.collect", "--recipe", str(p), "--out", str(out), "--no-progress"]
    proc = subprocess.Popen([*cmd, "--workers", "2"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)  # fmt: skip
    recs = out / "t" / EPISODES_JSONL
    children = []
    try:
        t0 = time.time()
        while time.time() - t0 < 120:
            children = children or [c for c in psutil.Process(proc.pid).children() if "python" in c.name().lower()]
            if recs.is_file() and recs.read_text().count("\n") >= 1:
                break
            assert proc.poll() is None, "collector exited early"
            time.sleep(0.05)
        else:
            pytest.fail("no episode committed within 120 s")
        children = children or psutil.Process(proc.pid).children()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        assert children, "no worker processes seen"
        _, alive = psutil.wait_procs(children, timeout=15)
        assert not alive, f"orphaned workers: {alive}"
    finally:
        with __import__("contextlib").suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    r = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    assert load_ds(out / "t").num_episodes == 3
    full, part = table(ref_root), table(out / "t")
    part = part[part.episode_index < 2].reset_index(drop=True)
    for col in ("observation.state", "action", "observation.pointcloud"):
        np.testing.assert_array_equal(np.stack(part[col].tolist()), np.stack(full[col].tolist()), err_msg=col)
    assert not any(q.name.startswith(".t.") for q in out.iterdir())


# ------------------------------------------------------------------------------------ benchmark
def test_bench_collect_writes_its_numbers(tmp_path):
    from flatlab_lerobot.cli import main

    p = write_recipe(tmp_path / "b.yaml", episodes=3, max_steps=8)
    out = tmp_path / "bench.json"
    assert main(["bench-collect", "--recipe", str(p), "--episodes", "1", "--workers", "1", "--profile",
                 "--json", str(out)]) == 0  # fmt: skip
    res = json.loads(out.read_text())
    assert res["episodes"] == 1 and res["workers"] == 1 and len(res["loadavg_before"]) == 3
    c, r = res["collection"], res["raw"]
    assert c["frames"] == 8 and r["episodes"] == 1 and r["steps"] == 8
    for v in (c["wall_s"], c["episodes_per_hour"], c["cpu_s_per_episode"], c["episodes_per_hour_cpu_bound"],
              r["wall_s"], r["episodes_per_hour"], r["cpu_s_per_episode"], res["overhead_ratio"],
              res["overhead_ratio_cpu"], res["peak_rss_mb"]["writer"], res["peak_rss_mb"]["worker_max"],
              c["cpu_share"], r["cpu_share"], c["loadavg_during"] + 0.01):
        assert isinstance(v, (int, float)) and v > 0
    prof = res["profile"]["seconds"]
    assert prof["episode (run_episode)"] > 0 and prof["  physics (FlatLabSim.step)"] > 0
    assert prof["    render passes (CameraRig._render)"] > 0 and prof["video encoding (video.encode_stream)"] > 0
    assert prof["  lerobot save_episode"] > 0


# ------------------------------------------------------------------------------------ lerobot CLIs
@pytest.mark.slow
def test_lerobot_train_act_two_steps(tiny, tmp_path):
    _, root, _ = tiny
    feats = {
        "observation.state": {"type": "STATE", "shape": [16]},
        "observation.images.front": {"type": "VISUAL", "shape": [3, 32, 32]},
        "observation.images.top": {"type": "VISUAL", "shape": [3, 32, 32]},
    }
    out = tmp_path / "train"
    cmd = [
        str(BIN / "lerobot-train"), "--policy.type=act", "--policy.pretrained_backbone_weights=null",
        "--dataset.repo_id=local/flatlab_t", f"--dataset.root={root}", "--dataset.video_backend=pyav",
        "--steps=2", "--batch_size=2", "--num_workers=0", "--log_freq=1", "--save_freq=2",
        "--policy.device=cpu", "--policy.push_to_hub=false", f"--output_dir={out}",
        "--policy.chunk_size=5", "--policy.n_action_steps=5",
        f"--policy.input_features={json.dumps(feats)}",
    ]  # fmt: skip
    r = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    assert (out / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").is_file()


# lerobot-dataset-viz on a collected dataset: tests/test_view.py::test_lerobot_dataset_viz_saves_rrd.

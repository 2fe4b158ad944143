"""The primitive learning set (``flatlab primitive-set``): one sample per executed primitive, with
the scene cloud and the commanded start/end gripper poses, checked against the simulation."""

import json

import numpy as np
import pandas as pd
import pytest

import flatlab_lerobot  # noqa: F401  (before mujoco)
from flatlab_lerobot.learning import primitive_set as ps
from flatlab_lerobot.sim.robot import ARMS
from flatlab_lerobot.strategies import Expert

SMALL = {"n_points": 256, "n_object_points": 64, "image_size": 64}


def _cfg(**kw):
    return ps.PrimitiveSetConfig(objects=("ref_box",), demos=1, **{**SMALL, **kw})


def _trace(cfg):
    """Run demo 0 of ref_box, recording what the sim shows before every control step."""
    steps = []

    def on_step(env, stage, index, action):
        tcp = {a: env.sim.tcp_pose(a) for a in ARMS}
        steps.append({"stage": stage, "index": index, "action": np.array(action), "tcp": tcp, "cell": env.cell})

    return ps.run_demo(cfg, "ref_box", 0, on_step=on_step), steps


def _angle(Ra, Rb) -> float:
    return float(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))


def test_samples_match_the_primitives_the_expert_ran():
    res, steps = _trace(_cfg(capture="start"))
    assert res.success, res.failure_reason
    df = pd.DataFrame(res.samples)
    # A primitive starts at the first step that carries its own name (not the transit's "move").
    # B's first primitive is itself a "move" (both hands above their touch start): every step of it
    # is named "move", so it starts its own duration's worth of steps before its last step.
    by_index: dict[int, list[int]] = {}
    for k, s in enumerate(steps):
        by_index.setdefault(s["index"], []).append(k)
    durations = dict(zip(df.primitive_index, df.duration_s))
    ran = {}
    for i, ks in sorted(by_index.items()):
        named = [k for k in ks if steps[k]["stage"] != "move"]
        ran[i] = (named[0], steps[named[0]]["stage"]) if named else (ks[-1] - round(durations[i] / 0.1) + 1, "move")
    assert list(df.primitive_index) == sorted(ran) and list(df.primitive) == [ran[i][1] for i in sorted(ran)]
    assert list(df.primitive)[0] == "move"  # B: both hands above their touch start first
    assert set(df.primitive) >= {"touch", "squeeze", "lift"}
    expert = Expert(steps[0]["cell"], 0.1)
    checked_free = 0
    for _, row in df.iterrows():
        k0 = ran[row.primitive_index][0]
        last = by_index[row.primitive_index][-1]
        assert row.step == k0
        q_end = np.r_[steps[last]["action"][:7], steps[last]["action"][8:15]]
        fk_end = expert.fk(q_end)
        for i, arm in enumerate(ARMS):
            if not row[f"{arm}_active"]:
                continue
            pos, R = steps[k0]["tcp"][arm]  # measured in the sim at the capture
            np.testing.assert_allclose(row[f"{arm}_tcp_pos"], pos, atol=1e-6)
            err = np.linalg.norm(row[f"{arm}_start_pos"] - pos)
            if not row[f"{arm}_contact"]:  # free hand: the commanded start is where the hand is
                assert err < 0.01, (row.primitive, arm, err)
                assert _angle(row[f"{arm}_start_rotmat"].reshape(3, 3), R) < 0.06, (row.primitive, arm)
                checked_free += 1
            else:  # pushing against the object: the commanded pose lies inside it, by design
                assert err < 0.1, (row.primitive, arm, err)
            # the end pose is what the primitive's last action commands
            assert np.linalg.norm(row[f"{arm}_end_pos"] - fk_end[arm][0]) < 0.01
            assert _angle(row[f"{arm}_end_rotmat"].reshape(3, 3), fk_end[arm][1]) < 0.05
            assert row[f"{arm}_gripper_end"] == pytest.approx(steps[last]["action"][8 * i + 7], abs=1e-6)
            # rotation encodings agree with the stored matrix
            Rm = row[f"{arm}_start_rotmat"].reshape(3, 3)
            np.testing.assert_allclose(row[f"{arm}_start_rot6d"], np.r_[Rm[:, 0], Rm[:, 1]], atol=1e-6)
            w, x, y, z = row[f"{arm}_start_quat"]
            assert w >= 0
            Rq = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                           [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                           [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])  # fmt: skip
            np.testing.assert_allclose(Rq, Rm, atol=1e-5)
    assert checked_free >= 2  # at least the touch (both hands free) was checked at 1 cm
    # clouds: fixed size, finite, inside the env's workspace
    lo, hi = np.array(res.workspace["lo"]), np.array(res.workspace["hi"])
    assert res.scene_clouds.shape == (len(df), 256, 3) and res.object_clouds.shape == (len(df), 64, 3)
    assert np.isfinite(res.scene_clouds).all() and np.isfinite(res.object_clouds).all()
    assert ((res.scene_clouds >= lo - 1e-6) & (res.scene_clouds <= hi + 1e-6)).all()
    seen = df.object_points_seen.to_numpy() > 0
    assert seen.any()
    oc = res.object_clouds[seen]
    assert ((oc >= lo - 1e-6) & (oc <= hi + 1e-6)).all()
    assert df.demo_success.all() and (df.scene_points_seen > 256).all()

    # decision capture: same demo, same commanded poses, captured when the stage is posed
    res2, steps2 = _trace(_cfg(capture="decision"))
    df2 = pd.DataFrame(res2.samples)
    first = {}
    for k, s in enumerate(steps2):
        first.setdefault(s["index"], k)
    assert list(df2.primitive_index) == sorted(first) == list(df.primitive_index)
    assert list(df2.step) == [first[i] for i in sorted(first)]
    for arm in ARMS:
        np.testing.assert_array_equal(np.stack(df2[f"{arm}_start_pos"]), np.stack(df[f"{arm}_start_pos"]))
        np.testing.assert_array_equal(np.stack(df2[f"{arm}_end_quat"]), np.stack(df[f"{arm}_end_quat"]))
        for _, row in df2.iterrows():
            np.testing.assert_allclose(row[f"{arm}_tcp_pos"], steps2[row.step]["tcp"][arm][0], atol=1e-6)
    # the first decision is taken at home, away from the touch's start pose
    assert np.linalg.norm(df2.left_start_pos[0] - df2.left_tcp_pos[0]) > 0.05


@pytest.mark.slow
def test_cli_is_deterministic_resumable_and_worker_independent(tmp_path, capsys):
    from flatlab_lerobot.cli import main as flatlab

    common = ["--demos", "2", "--points", "256", "--object-points", "64", "--image-size", "64", "--no-progress"]
    a, b = tmp_path / "a", tmp_path / "b"
    assert flatlab(["primitive-set", "--objects", "ref_box", "--out", str(a), *common]) == 0
    assert flatlab(["primitive-set", "--objects", "ref_box,box_gift", "--workers", "2", "--out", str(b), *common]) == 0
    da, sa, oa = ps.load(a)
    db, sb, ob = ps.load(b)
    meta = json.loads((a / "meta.json").read_text())
    assert meta["counts"]["samples"] == len(da) == len(sa) == len(oa) and meta["counts"]["demos"] == 2
    assert sa.shape == (len(da), 256, 3) and oa.shape == (len(da), 64, 3)
    assert set(db.object_id) == {"ref_box", "box_gift"} and "demo_success" in db
    # ref_box's samples do not depend on the other objects, the worker count or the process
    nb = (db.object_id == "ref_box").to_numpy()
    np.testing.assert_array_equal(sb[nb], sa)
    np.testing.assert_array_equal(ob[nb], oa)
    pd.testing.assert_frame_equal(db[nb].reset_index(drop=True), da)
    # a re-run skips the finished shard and merges the same set again
    shard = a / "shards" / "ref_box" / "shard.json"
    before = shard.stat().st_mtime_ns
    capsys.readouterr()
    assert flatlab(["primitive-set", "--objects", "ref_box", "--out", str(a), *common]) == 0
    assert "1/1 object shards already done" in capsys.readouterr().out
    assert shard.stat().st_mtime_ns == before
    da2, sa2, _ = ps.load(a)
    pd.testing.assert_frame_equal(da2, da)
    np.testing.assert_array_equal(sa2, sa)


def test_bad_input_names_the_field(tmp_path, capsys):
    assert ps.main(["--objects", "no_such_object", "--out", str(tmp_path)]) == 2
    assert "--objects: unknown object id 'no_such_object'" in capsys.readouterr().err
    with pytest.raises(ps.PrimitiveSetError, match="field 'capture'"):
        _cfg(capture="later")
    # a shard made with other settings is not silently mixed in
    shard = tmp_path / "shards" / "ref_box"
    shard.mkdir(parents=True)
    old = _cfg(n_points=128)
    (shard / "shard.json").write_text(json.dumps({"fingerprint": old.fingerprint(), "settings": old.shard_settings()}))
    with pytest.raises(
        ps.PrimitiveSetError, match=r"shard.json: field 'settings' differs .*n_points: 128 there, 256 now"
    ):
        ps.build(_cfg(), tmp_path, progress=False)
    assert not (tmp_path / "meta.json").exists()

"""``flatlab_executor`` (the action execution module): geodesic loss, consistent augmentation,
privileged-state independence, ablation switches, the Train-only rule, and a real ``lerobot-train``
run on a tiny exported primitive set whose checkpoint reloads through lerobot's ``make_policy``."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from flatlab_lerobot.policies.executor import configuration_flatlab_executor as C
from flatlab_lerobot.policies.executor.modeling_flatlab_executor import (
    FlatLabExecutorPolicy,
    SceneFrame,
    geodesic_angle,
    geodesic_loss,
    quat_mul,
)

OBS_ENV = "observation.environment_state"
TINY = {"sa_npoints": [32, 8], "sa_nsamples": [8, 8], "sa_mlps": [[16], [32]], "global_mlp": [32],
        "head_hidden": [32], "cond_dim": 8, "n_points": 64}  # fmt: skip


def _quat_to_R(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])  # fmt: skip


def _policy(extra_features=None, **kw) -> FlatLabExecutorPolicy:
    feats = {**(extra_features or {}),
        C.OBS_POINTCLOUD: PolicyFeature(FeatureType.STATE, (128, 3)),
        C.OBS_PRIMITIVE: PolicyFeature(FeatureType.STATE, (C.PRIMITIVE_DIM,)),
        C.OBS_TCP_STATE: PolicyFeature(FeatureType.STATE, (C.TCP_STATE_DIM,)),
        OBS_ENV: PolicyFeature(FeatureType.ENV, (14,)),
    }
    cfg = C.FlatLabExecutorConfig(
        device="cpu", input_features=feats, output_features={"action": PolicyFeature(FeatureType.ACTION, (C.ACTION_DIM,))},
        **{**TINY, **kw},
    )  # fmt: skip
    torch.manual_seed(0)
    return FlatLabExecutorPolicy(cfg)


def _rand_quat(g, n):
    q = torch.as_tensor(g.normal(size=(n, 4)), dtype=torch.float32)
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[:, :1] < 0, -q, q)


def _batch(B=6, seed=0):
    g = np.random.default_rng(seed)
    cloud = torch.as_tensor(g.uniform([-0.3, -0.4, 0.75], [0.3, 0.4, 0.95], size=(B, 128, 3)), dtype=torch.float32)
    prims = [("A", 14, "grasp"), ("B", 2, "squeeze"), ("C", 6, "grasp"), ("A", 0, "touch"), ("B", 3, "lift"), ("C", 0, "touch")]
    prim = torch.tensor([C.encode_primitive(*prims[i % len(prims)]) for i in range(B)])
    tcp = torch.cat([torch.as_tensor(g.normal(size=(B, 3)) * 0.2, dtype=torch.float32), _rand_quat(g, B),
                     torch.full((B, 1), 0.04), torch.as_tensor(g.normal(size=(B, 3)) * 0.2, dtype=torch.float32),
                     _rand_quat(g, B), torch.full((B, 1), 0.04)], 1)  # fmt: skip
    act = torch.zeros(B, C.ACTION_DIM)
    for i in range(2):
        sl = C.arm_slices(i)
        act[:, sl["active"]] = 1.0
        for end in ("start", "end"):
            act[:, sl[f"{end}_pos"]] = cloud[:, :1, :][:, 0] + torch.as_tensor(g.normal(size=(B, 3)) * 0.02, dtype=torch.float32)
            act[:, sl[f"{end}_quat"]] = _rand_quat(g, B)
        act[:, sl["gripper_start"]] = 0.08
    return {C.OBS_POINTCLOUD: cloud, C.OBS_PRIMITIVE: prim, C.OBS_TCP_STATE: tcp, "action": act,
            OBS_ENV: torch.as_tensor(g.normal(size=(B, 14)), dtype=torch.float32)}  # fmt: skip


def _translated(b: dict, shift: torch.Tensor) -> dict:
    """The batch with the whole scene moved by ``shift``: scene cloud, the object cloud's seen rows
    (unseen ones stay zero) and both arms' TCP positions."""
    out = dict(b)
    out[C.OBS_POINTCLOUD] = b[C.OBS_POINTCLOUD] + shift
    obj = b[C.OBS_OBJECT_CLOUD].clone()
    obj[obj.abs().sum(-1) > 0] += shift
    out[C.OBS_OBJECT_CLOUD] = obj
    tcp = b[C.OBS_TCP_STATE].clone()
    for i in range(2):
        tcp[:, 8 * i : 8 * i + 3] += shift
    out[C.OBS_TCP_STATE] = tcp
    return out


# ------------------------------------------------------------------------------ loss and geometry
def test_geodesic_loss_is_zero_for_q_and_minus_q_and_the_angle_otherwise():
    q = _rand_quat(np.random.default_rng(1), 64)
    assert geodesic_loss(q, q).item() == 0.0
    assert geodesic_loss(-q, q).item() == 0.0
    assert torch.all(geodesic_angle(-q, q) == 0)
    # 90 deg about z against identity: theta = pi/2 (both signs)
    ident = torch.tensor([[1.0, 0, 0, 0]])
    qz = torch.tensor([[math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)]])
    assert geodesic_angle(qz, ident).item() == pytest.approx(math.pi / 2, abs=1e-5)
    assert geodesic_angle(-qz, ident).item() == pytest.approx(math.pi / 2, abs=1e-5)
    assert geodesic_loss(qz, ident).item() == pytest.approx((math.pi / 2) ** 2, abs=1e-4)
    # finite gradients, also at q_hat = +-q
    qh = torch.cat([q[:4], -q[4:8], qz.expand(4, 4)]).requires_grad_(True)
    geodesic_loss(qh, torch.cat([q[:8], ident.expand(4, 4)])).backward()
    assert torch.isfinite(qh.grad).all() and qh.grad[8:].abs().sum() > 0


def test_rotating_the_cloud_and_the_poses_together_is_consistent():
    g = np.random.default_rng(2)
    B = 5
    cloud = torch.as_tensor(g.uniform(-0.5, 0.5, size=(B, 200, 3)), dtype=torch.float32)
    pos = torch.as_tensor(g.uniform(-0.5, 0.5, size=(B, 3)), dtype=torch.float32)
    q = _rand_quat(g, B)
    s = torch.tensor([0.9, 1.1, 1.0, 0.95, 1.05])
    phi = torch.tensor([0.3, -2.0, math.pi, 1.0, 0.0])
    fr = SceneFrame(cloud.mean(1), s, phi)
    c2, p2, q2 = fr.pos_in(cloud), fr.pos_in(pos), fr.quat_in(q)
    for b in range(B):
        # the pose keeps its place relative to the cloud: every distance scales by s
        d1 = torch.cdist(pos[b : b + 1], cloud[b])[0]
        d2 = torch.cdist(p2[b : b + 1], c2[b])[0]
        torch.testing.assert_close(d2, d1 * s[b], atol=1e-5, rtol=1e-5)
        # a rotation about z: the cloud's z spread only scales, the pose's z relative to the cloud too
        Rz = np.array([[math.cos(phi[b]), -math.sin(phi[b]), 0], [math.sin(phi[b]), math.cos(phi[b]), 0], [0, 0, 1]])
        np.testing.assert_allclose(c2[b].numpy(), (s[b].item() * (cloud[b] - cloud[b].mean(0)).numpy() @ Rz.T), atol=1e-5)
        # the orientation turns with the scene: R(q') = Rz R(q)
        np.testing.assert_allclose(_quat_to_R(q2[b].numpy()), Rz @ _quat_to_R(q[b].numpy()), atol=1e-5)
    # back to the world frame exactly
    torch.testing.assert_close(fr.pos_out(p2), pos, atol=1e-5, rtol=0)
    torch.testing.assert_close(fr.quat_out(q2), q, atol=1e-5, rtol=0)
    # and quat_in composes like rotations do
    torch.testing.assert_close(quat_mul(fr.qz, q), q2)


def test_training_augmentation_moves_targets_with_the_cloud():
    """With augmentation on, a prediction that is perfect in the world frame, mapped through the
    batch's own random frame, has zero position / rotation loss: the targets went through the same
    scale + z-rotation as the cloud."""
    pol = _policy(augment=True, lambda_grip=0.0)
    batch = _batch()
    captured = {}
    orig = pol._frame

    def frame(cloud, c=None):
        captured["f"] = orig(cloud, c)
        return captured["f"]

    def perfect(b, frame=None):
        fr = pol._frame(pol._cloud(b[C.OBS_POINTCLOUD]))
        out = []
        for i in range(2):
            sl = C.arm_slices(i)
            t = b["action"]
            out.append({f"{e}_pos": fr.pos_in(t[:, sl[f"{e}_pos"]]) for e in ("start", "end")}
                       | {f"{e}_quat": fr.quat_in(t[:, sl[f"{e}_quat"]]) for e in ("start", "end")}
                       | {g: t[:, sl[g]] for g in ("gripper_start", "gripper_end")}
                       | {"active_logit": torch.full((len(t),), 30.0)})  # fmt: skip
        return fr, out

    pol._frame = frame
    pol.train()
    pol._run = perfect
    loss, info = pol.forward(batch)
    f = captured["f"]
    assert not torch.allclose(f.s, torch.ones_like(f.s)) and not torch.allclose(f.phi, torch.zeros_like(f.phi))
    assert info["pos_loss"] < 1e-9 and info["rot_loss"] < 1e-6 and info["active_loss"] < 1e-9 and loss.item() < 1e-5


# ------------------------------------------------------------------------------ rules
def test_output_ignores_environment_state():
    pol = _policy()
    pol.eval()
    batch = _batch()
    a = pol.select_action(batch)
    zeroed = dict(batch, **{OBS_ENV: torch.zeros_like(batch[OBS_ENV])})
    absent = {k: v for k, v in batch.items() if k != OBS_ENV}
    torch.testing.assert_close(pol.select_action(zeroed), a, atol=0, rtol=0)
    torch.testing.assert_close(pol.select_action(absent), a, atol=0, rtol=0)
    # ... but it does read the cloud and the primitive
    moved = dict(batch, **{C.OBS_POINTCLOUD: batch[C.OBS_POINTCLOUD] * 1.2})
    assert not torch.allclose(pol.select_action(moved), a)
    other = dict(batch, **{C.OBS_PRIMITIVE: batch[C.OBS_PRIMITIVE].roll(1, 0)})
    assert not torch.allclose(pol.select_action(other), a)
    # the active flags are probabilities; the world-frame outputs are unit quaternions with w >= 0
    assert ((a[:, 0] > 0) & (a[:, 0] < 1)).all() and ((a[:, C.ARM_DIM] > 0) & (a[:, C.ARM_DIM] < 1)).all()
    for i in range(2):
        sl = C.arm_slices(i)
        for e in ("start", "end"):
            qq = a[:, sl[f"{e}_quat"]]
            torch.testing.assert_close(qq.norm(dim=-1), torch.ones(len(qq)))
            assert (qq[:, 0] >= 0).all()


def test_ablation_switches():
    batch = _batch()
    assert _policy().config.ablation == "full"
    # no rotation loss -> the rotation targets do not change the loss
    a4 = _policy(rotation_loss=False, augment=False)
    a4.eval()
    assert a4.config.ablation == "A-4"
    b2 = {k: v.clone() for k, v in batch.items()}
    for i in range(2):
        b2["action"][:, C.arm_slices(i)["start_quat"]] = torch.tensor([0.0, 1.0, 0.0, 0.0])
    assert a4.forward(batch)[0].item() == pytest.approx(a4.forward(b2)[0].item(), abs=0)
    full = _policy(augment=False)
    full.eval()
    assert full.forward(batch)[0].item() != full.forward(b2)[0].item()
    # one network scene (+ strategy) -> grasp pose: the primitive does not condition it, and
    # only the grasp samples (A 14, B 2, C 6) are learned
    a5 = _policy(decompose_primitives=False, augment=False)
    a5.eval()
    assert a5.config.ablation == "A-5" and _policy(decompose_primitives=False, rotation_loss=False).config.ablation == "A-6"
    grasp = a5.grasp_mask(batch[C.OBS_PRIMITIVE])
    assert grasp.tolist() == [True, True, True, False, False, False]
    b3 = {k: v.clone() for k, v in batch.items()}
    b3["action"][~grasp, 1:] += 0.5  # perturb only non-grasp targets
    assert a5.forward(batch)[0].item() == pytest.approx(a5.forward(b3)[0].item(), abs=0)
    assert full.forward(batch)[0].item() != full.forward(b3)[0].item()
    b4 = dict(batch, **{C.OBS_PRIMITIVE: torch.tensor([C.encode_primitive("A", 3, "release")] * 6)})
    b5 = dict(batch, **{C.OBS_PRIMITIVE: torch.tensor([C.encode_primitive("A", 14, "grasp")] * 6)})
    torch.testing.assert_close(a5.select_action(b4), a5.select_action(b5), atol=0, rtol=0)


def test_primitive_encoding_matches_the_expert_strategies():
    from flatlab_lerobot.primitives import PRIMITIVE_NAMES
    from flatlab_lerobot.strategies import STRATEGIES

    assert tuple(PRIMITIVE_NAMES) == C.PRIMITIVE_NAMES
    assert max(len(s) for s in STRATEGIES.values()) == C.MAX_STAGES
    grasp_fn = {"A": "a_grasp", "B": "b_squeeze", "C": "c_pinch"}
    for s, k in C.GRASP_STAGE.items():
        assert STRATEGIES[s][k].__name__ == grasp_fn[s]
    with pytest.raises(ValueError, match="stage_index"):
        C.encode_primitive("A", 17, "grasp")


def test_bad_config_names_the_flag():
    with pytest.raises(ValueError, match="--policy.sa_npoints"):
        _policy(sa_npoints=[32, 64])
    with pytest.raises(ValueError, match="--policy.aug_scale"):
        _policy(aug_scale=[1.1, 0.9])
    with pytest.raises(ValueError, match="'observation.tcp_state' missing.*use_proprio=false"):
        C.FlatLabExecutorConfig(device="cpu", input_features={
            C.OBS_POINTCLOUD: PolicyFeature(FeatureType.STATE, (128, 3)),
            C.OBS_PRIMITIVE: PolicyFeature(FeatureType.STATE, (C.PRIMITIVE_DIM,))},
            output_features={"action": PolicyFeature(FeatureType.ACTION, (C.ACTION_DIM,))}).validate_features()  # fmt: skip


# ------------------------------------------------------------------------------ data + lerobot-train
@pytest.fixture(scope="module")
def tiny_set(tmp_path_factory):
    from flatlab_lerobot.learning import primitive_set as ps

    out = tmp_path_factory.mktemp("pset")
    cfg = ps.PrimitiveSetConfig(objects=("box_gift", "disk_compact_disc"), demos=1, n_points=256, n_object_points=32, image_size=48)
    ps.build(cfg, out, progress=False, log=lambda *a: None)
    return out


def test_export_is_train_only(tiny_set, tmp_path):
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.learning import primitive_export as pe

    summary = pe.export(tiny_set, tmp_path / "ds", log=lambda *a: None)
    assert summary["objects"] == ["box_gift", "disk_compact_disc"]
    assert all(get_object(o).split == "train" for o in summary["objects"])
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata("local/x", root=tmp_path / "ds")
    pe.check_training_tasks(meta)  # passes
    objs = {pe.TASK_RE.match(t)["object"] for t in meta.tasks.index}
    assert objs == set(summary["objects"]) and all(get_object(o).split == "train" for o in objs)
    # a set that holds a Test-alpha object is refused for training ...
    bad = tmp_path / "bad"
    bad.mkdir()
    for f in ("scene_clouds.npy", "object_clouds.npy", "meta.json"):
        (bad / f).symlink_to(tiny_set / f)
    df = pd.read_parquet(tiny_set / "samples.parquet")
    df.loc[df.object_id == "box_gift", "split"] = "test_alpha"
    df.to_parquet(bad / "samples.parquet")
    with pytest.raises(pe.PrimitiveExportError, match=r"column 'split'.*\['box_gift'\]"):
        pe.export(bad, tmp_path / "ds2", log=lambda *a: None)
    # ... exported for metrics only, and then the policy refuses to train on it
    pe.export(bad, tmp_path / "ds3", eval_only=True, log=lambda *a: None)
    meta3 = LeRobotDatasetMetadata("local/y", root=tmp_path / "ds3")
    with pytest.raises(pe.PrimitiveExportError, match=r"outside the Train split.*box_gift \(test_alpha\)"):
        pe.check_training_tasks(meta3)
    with pytest.raises(pe.PrimitiveExportError, match="not `flatlab primitive-export` tasks"):
        pe.check_training_tasks(SimpleNamespace(tasks=pd.DataFrame(index=["pick the cube"]), root="r"))


@pytest.mark.slow
def test_lerobot_train_trains_and_checkpoint_reloads(tiny_set, tmp_path):
    from flatlab_lerobot.learning import primitive_export as pe

    ds = tmp_path / "ds"
    pe.export(tiny_set, ds, log=lambda *a: None)
    out = tmp_path / "train"
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=f"{root}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    exe = Path(sys.executable).with_name("lerobot-train")
    cmd = [str(exe), f"--config_path={root / 'policies/flatlab_executor/cpu.json'}", f"--dataset.root={ds}",
           "--steps=3", "--batch_size=4", "--log_freq=1", "--save_freq=3", f"--output_dir={out}",
           "--policy.n_points=128", "--policy.sa_npoints=[32,8]", "--policy.sa_nsamples=[8,8]"]  # fmt: skip
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "step:3" in r.stdout + r.stderr and "rot_loss" in r.stdout + r.stderr
    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    cfg_json = json.loads((ckpt / "config.json").read_text())
    assert cfg_json["type"] == "flatlab_executor" and cfg_json["n_points"] == 128
    # reload through lerobot's factory (what --policy.path does) and predict
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy

    cfg = PreTrainedConfig.from_pretrained(ckpt)
    cfg.pretrained_path = ckpt
    pol = make_policy(cfg, ds_meta=LeRobotDatasetMetadata("local/flatlab_primitives", root=ds))
    assert isinstance(pol, FlatLabExecutorPolicy)
    direct = FlatLabExecutorPolicy.from_pretrained(ckpt)
    for (k, v), (k2, v2) in zip(pol.state_dict().items(), direct.state_dict().items()):
        assert k == k2 and torch.equal(v, v2)
    from flatlab_lerobot.learning import primitive_set as ps

    df, scene, objs = ps.load(tiny_set)
    row = df[(df.strategy == "A") & (df.primitive == "grasp")].iloc[0]
    tcp = np.concatenate([np.r_[row[f"{a}_tcp_pos"], row[f"{a}_tcp_quat"], row[f"{a}_gripper_measured"]] for a in C.ARMS])
    poses = pol.predict_poses(scene[int(row.sample_index)], "A", int(row.primitive_index), "grasp", tcp,
                              object_cloud=objs[int(row.sample_index)])
    assert set(poses) == {"left", "right"}
    p, q = poses["left"]["start"]
    assert p.shape == (1, 3) and q.shape == (1, 4) and np.isfinite(p).all()
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-5)
    # near the scene (the model predicts offsets from the cloud centre)
    assert np.linalg.norm(p[0] - scene[int(row.sample_index)].mean(0)) < 2.0

    # the pose-error report agrees with predict_poses on the grasp samples
    from flatlab_lerobot.learning import executor_metrics as em

    mfile = tmp_path / "m.json"
    assert em.main(["--policy.path", str(ckpt), "--dataset", str(ds), "--out", str(mfile)]) == 0
    rep = json.loads(mfile.read_text())["splits"]
    assert set(rep) == {"train"} and {"grasp", "grasp/A", "grasp/B", "all"} <= set(rep["train"])
    se, dz = [], []
    for _, r in df[df.demo_success & df.apply(lambda r: r.primitive_index == C.GRASP_STAGE[r.strategy], axis=1)].iterrows():
        tcp = np.concatenate([np.r_[r[f"{a}_tcp_pos"], r[f"{a}_tcp_quat"], r[f"{a}_gripper_measured"]] for a in C.ARMS])
        pp = pol.predict_poses(scene[int(r.sample_index)], r.strategy, int(r.primitive_index), r.primitive, tcp,
                               object_cloud=objs[int(r.sample_index), : pol.config.input_features[C.OBS_OBJECT_CLOUD].shape[0]])
        se += [float(((pp[a]["start"][0][0] - r[f"{a}_start_pos"]) ** 2).sum()) for a in C.ARMS if r[f"{a}_active"]]
        dz += [float(pp[a]["start"][0][0][2] - r[f"{a}_start_pos"][2]) for a in C.ARMS if r[f"{a}_active"]]
    assert rep["train"]["grasp"]["n_arm_samples"] == len(se)
    assert rep["train"]["grasp"]["p_mse_start_m2"] == pytest.approx(np.mean(se), rel=1e-4)
    # the signed height error: its sign survives (an untrained model is off by cm, so 0 would be a bug)
    assert rep["train"]["grasp"]["z_bias_start_m"] == pytest.approx(np.mean(dz), rel=1e-3, abs=1e-6)
    assert em.main(["--policy.path", str(tmp_path), "--dataset", str(ds)]) == 2


@pytest.mark.parametrize("name,ablation", [("cpu", "full"), ("paper", "full"), ("ablation_A4", "A-4"),
                                           ("ablation_A5", "A-5"), ("ablation_A6", "A-6"), ("object_encoder", "full"),
                                           ("object_relative", "full"),
                                           ("object_encoder_cosine", "full")])  # fmt: skip
def test_recipes_parse_into_the_config(name, ablation):
    import draccus

    d = json.loads((Path(__file__).resolve().parents[1] / f"policies/flatlab_executor/{name}.json").read_text())
    pol = {k: v for k, v in d["policy"].items() if k != "type"}
    assert d["policy"]["type"] == "flatlab_executor"
    cfg = draccus.decode(C.FlatLabExecutorConfig, pol)
    assert cfg.ablation == ablation and cfg.n_points == pol["n_points"]
    assert cfg.object_mlp == pol.get("object_mlp", []) and cfg.relative_starts == pol.get("relative_starts", False)
    assert d["dataset"]["root"] and d["steps"] > 0


def test_ablation_recipes_are_the_cpu_recipe_but_their_switches():
    """Table 2's A-4 / A-5 / A-6 compare against the cpu recipe: same data, steps, optimizer and model,
    only rotation_loss / decompose_primitives differ."""
    root = Path(__file__).resolve().parents[1] / "policies/flatlab_executor"
    cpu = json.loads((root / "cpu.json").read_text())
    for name, switches in (("ablation_A4", {"rotation_loss"}), ("ablation_A5", {"decompose_primitives"}),
                           ("ablation_A6", {"rotation_loss", "decompose_primitives"})):  # fmt: skip
        d = json.loads((root / f"{name}.json").read_text())
        assert {k: v for k, v in d.items() if k != "policy"} == {k: v for k, v in cpu.items() if k != "policy"}, name
        differ = {k for k in set(d["policy"]) | set(cpu["policy"]) if d["policy"].get(k) != cpu["policy"].get(k)}
        assert differ == switches, (name, differ)


def test_object_frame_centres_on_the_seen_object_points():
    """frame_center="object": the model frame's origin is the mean of the object cloud's seen
    (non-zero) points, the scene mean when none is seen; a translation of the whole scene (clouds,
    proprioception) moves the predicted poses by the same amount, and predict_poses asks for it."""
    pol = _policy({C.OBS_OBJECT_CLOUD: PolicyFeature(FeatureType.STATE, (32, 3))}, frame_center="object")
    pol.eval()
    b = _batch(B=2)
    obj = b[C.OBS_POINTCLOUD][:, :32].clone()
    obj[:, 20:] = 0.0  # unseen rows
    obj[1] = 0.0  # nothing seen
    b[C.OBS_OBJECT_CLOUD] = obj
    c = pol._center(b, pol._cloud(b[C.OBS_POINTCLOUD]))
    torch.testing.assert_close(c[0], obj[0, :20].mean(0))
    torch.testing.assert_close(c[1], pol._cloud(b[C.OBS_POINTCLOUD])[1].mean(0))
    shift = torch.tensor([0.05, -0.03, 0.0])
    p1, p2 = pol.predict_world(b)[0], pol.predict_world(_translated(b, shift))[0]
    torch.testing.assert_close(p2["start_pos"][0], p1["start_pos"][0] + shift, atol=1e-4, rtol=0)
    with pytest.raises(ValueError, match="object_cloud"):
        pol.predict_poses(b[C.OBS_POINTCLOUD][0], "A", 0, "touch", b[C.OBS_TCP_STATE][0])
    out = pol.predict_poses(b[C.OBS_POINTCLOUD][0], "A", 0, "touch", b[C.OBS_TCP_STATE][0], object_cloud=obj[0])
    assert out["left"]["start"][0].shape == (1, 3)


def test_object_table_frame_sits_on_the_table_under_the_object():
    """frame_center="object_table": x, y from the object cloud's seen points, z the table plane (the
    scene cloud's low height quantile): a raised table (the whole scene shifted up, as the scenes'
    0.65-0.78 m tables) moves the origin and the predicted poses by the same amount."""
    feats = {C.OBS_OBJECT_CLOUD: PolicyFeature(FeatureType.STATE, (32, 3))}
    pol = _policy(feats, frame_center="object_table", table_quantile=0.05)
    pol.eval()
    b = _batch(B=2)
    cloud = b[C.OBS_POINTCLOUD].clone()
    cloud[:, :100, 2] = 0.75  # a table under 100 of the 128 points
    b[C.OBS_POINTCLOUD] = cloud
    obj = cloud[:, 100:].clone()
    obj[:, 20:] = 0.0
    b[C.OBS_OBJECT_CLOUD] = obj
    c = pol._center(b, pol._cloud(cloud))
    torch.testing.assert_close(c[:, :2], obj[:, :20, :2].mean(1))
    torch.testing.assert_close(c[:, 2], torch.full((2,), 0.75))
    shift = torch.tensor([0.02, 0.01, -0.1])
    p1, p2 = pol.predict_world(b)[1], pol.predict_world(_translated(b, shift))[1]
    torch.testing.assert_close(p2["end_pos"], p1["end_pos"] + shift, atol=1e-4, rtol=0)
    with pytest.raises(ValueError, match="object_cloud"):
        pol.predict_poses(cloud[0], "B", 2, "squeeze", b[C.OBS_TCP_STATE][0])
    with pytest.raises(ValueError, match="table_quantile"):
        _policy(feats, frame_center="object_table", table_quantile=0.7)


def test_object_top_frame_sits_on_the_seen_top_of_the_object():
    """frame_center="object_top": x, y from the object cloud's seen points, z their ``top_quantile``
    height (the highest with 1.0), never an unseen row's 0; the scene mean with none seen; a whole-scene
    translation moves the origin and the predicted poses by the same amount; a thicker object (its top
    raised, the table where it was) raises the origin by the same amount."""
    feats = {C.OBS_OBJECT_CLOUD: PolicyFeature(FeatureType.STATE, (32, 3))}
    pol = _policy(feats, frame_center="object_top", top_quantile=1.0)
    pol.eval()
    b = _batch(B=3)
    cloud = b[C.OBS_POINTCLOUD].clone()
    cloud[:, :100, 2] = 0.75  # the table
    cloud[:, 100:, 2] = 0.75 + torch.linspace(0.0, 0.012, 28)  # the object, its top 12 mm above the table
    b[C.OBS_POINTCLOUD] = cloud
    obj = cloud[:, 100:].clone()
    obj[:, 20:] = 0.0  # unseen rows (their 0 would be the highest otherwise: below the table is negative)
    obj[:, :, 2] -= 1.0 * (obj[:, :, 2] != 0)  # a table below z = 0, so an unseen row's 0 is above every point
    obj[2] = 0.0  # nothing seen
    b[C.OBS_OBJECT_CLOUD] = obj
    c = pol._center(b, pol._cloud(cloud))
    torch.testing.assert_close(c[:2, :2], obj[:2, :20, :2].mean(1))
    torch.testing.assert_close(c[:2, 2], obj[:2, :20, 2].max(1).values)
    torch.testing.assert_close(c[2], pol._cloud(cloud)[2].mean(0))
    med = _policy(feats, frame_center="object_top", top_quantile=0.51)._center(b, pol._cloud(cloud))
    assert (med[:2, 2] < c[:2, 2] - 0.004).all()  # about the middle of the 0-12 mm ramp
    shift = torch.tensor([0.02, 0.01, -0.1])
    p1, p2 = pol.predict_world(b)[1], pol.predict_world(_translated(b, shift))[1]
    torch.testing.assert_close(p2["end_pos"], p1["end_pos"] + shift, atol=1e-4, rtol=0)
    thick = dict(b)
    thick[C.OBS_OBJECT_CLOUD] = obj + torch.tensor([0.0, 0.0, 0.02]) * (obj.abs().sum(-1, keepdim=True) > 0)
    torch.testing.assert_close(pol._center(thick, pol._cloud(cloud))[:2, 2], c[:2, 2] + 0.02)
    with pytest.raises(ValueError, match="top_quantile"):
        _policy(feats, frame_center="object_top", top_quantile=0.4)


def test_object_encoder_reads_the_object_cloud_shape_in_the_model_frame():
    """object_mlp: a PointNet on the object cloud's seen points joins F_env.  Turning the object cloud
    about its own centre (same frame origin, same scene cloud) changes the prediction only with the
    encoder; a whole-scene translation still moves the poses with it; unseen rows never count (a cloud
    with none seen gives a zero feature); training trains it."""
    feats = {C.OBS_OBJECT_CLOUD: PolicyFeature(FeatureType.STATE, (32, 3))}
    plain = _policy(feats, frame_center="object_table")
    enc = _policy(feats, frame_center="object_table", object_mlp=[16, 32], n_object_points=24)
    b = _batch(B=2)
    cloud = b[C.OBS_POINTCLOUD].clone()
    cloud[:, :100, 2] = 0.75
    b[C.OBS_POINTCLOUD] = cloud
    obj = cloud[:, 100:].clone()
    obj[:, 20:] = 0.0
    b[C.OBS_OBJECT_CLOUD] = obj
    turned = obj.clone()
    m = obj[:, :20].mean(1, keepdim=True)
    d = obj[:, :20] - m
    turned[:, :20] = m + torch.stack([-d[..., 1], d[..., 0], d[..., 2]], -1)  # 90 degrees about z
    bt = {**b, C.OBS_OBJECT_CLOUD: turned}
    for pol in (plain, enc):
        pol.eval()
    same = lambda pol: torch.allclose(pol.predict_world(b)[0]["start_pos"], pol.predict_world(bt)[0]["start_pos"])  # noqa: E731
    assert same(plain) and not same(enc)
    shift = torch.tensor([0.03, -0.02, 0.0])
    torch.testing.assert_close(enc.predict_world(_translated(b, shift))[1]["end_pos"],
                               enc.predict_world(b)[1]["end_pos"] + shift, atol=1e-4, rtol=0)  # fmt: skip
    frame = enc._frame(cloud, enc._center(b, enc._cloud(cloud)))
    interleaved = torch.zeros(2, 32, 3)  # the same 20 seen points (all fit in 24 slots) between unseen rows
    interleaved[:, 1::2][:, :16] = obj[:, :16]
    interleaved[:, 0::2][:, 12:16] = obj[:, 16:20]
    assert torch.count_nonzero(interleaved.abs().sum(-1)) == 40
    torch.testing.assert_close(enc._object_feature(frame, interleaved), enc._object_feature(frame, obj))
    none = enc._object_feature(frame, torch.zeros(2, 32, 3))
    assert torch.count_nonzero(none) == 0
    enc.train()
    loss, _ = enc.forward(b)
    loss.backward()
    assert enc.object_encoder.net[0].weight.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="object_mlp"):
        _policy(frame_center="scene", object_mlp=[16])


def test_relative_starts_continue_from_the_measured_tcp():
    """relative_starts: a stage that starts where the arm is (StageSpec.start == "current": B's squeeze)
    is the TCP + d_start, then start + d_end (rotations composed on the TCP's); an approach (A's touch)
    stays in the model frame.  With the heads' outputs zero / identity the squeeze is the arm's
    measured TCP pose (through the augmented training frame and back) and the touch the frame origin."""
    pol = _policy(relative_starts=True)
    with pytest.raises(ValueError, match="relative_starts"):
        _policy(relative_starts=True, use_proprio=False)
    b = _batch(B=6)  # samples 1 and 4: B squeeze / lift (from the current pose); 0: A grasp; 3: A touch
    rel = pol.relative_mask(b[C.OBS_PRIMITIVE])
    assert rel.tolist() == [True, True, True, False, True, False]  # A grasp, B squeeze, C pinch, A touch, B lift, C touch
    assert not _policy(relative_starts=True, decompose_primitives=False).relative_mask(b[C.OBS_PRIMITIVE]).any()
    last_pos, last_rot = pol.pos_head[-1], pol.rot_head[-1]
    with torch.no_grad():
        for lin in (last_pos, last_rot):
            lin.weight.zero_()
            lin.bias.zero_()
        last_rot.bias.view(2, 2, 4)[:, :, 0] = 1.0  # every quaternion output = identity (w = 1)
    pol.eval()
    out = pol.predict_world(b)
    centre = pol._center(b, pol._cloud(b[C.OBS_POINTCLOUD]))
    for i in range(2):
        tcp = b[C.OBS_TCP_STATE][:, 8 * i : 8 * i + 8]
        for end in ("start", "end"):
            torch.testing.assert_close(out[i][f"{end}_pos"][rel], tcp[rel, :3], atol=1e-5, rtol=0)
            dots = (out[i][f"{end}_quat"][rel] * tcp[rel, 3:7]).sum(-1).abs()
            torch.testing.assert_close(dots, torch.ones(int(rel.sum())), atol=1e-5, rtol=0)
            torch.testing.assert_close(out[i][f"{end}_pos"][~rel], centre[~rel], atol=1e-5, rtol=0)
    pol.train()  # the same through a random scale / rotation of the training frame
    frame, pred = pol._run(b)
    torch.testing.assert_close(frame.pos_out(pred[1]["end_pos"])[rel], b[C.OBS_TCP_STATE][rel, 8:11], atol=1e-5, rtol=0)
    torch.testing.assert_close(frame.pos_out(pred[1]["end_pos"])[~rel], frame.c[~rel], atol=1e-5, rtol=0)
    pol = _policy(relative_starts=True)
    pol.train()
    loss, _ = pol.forward(b)
    loss.backward()
    assert pol.pos_head[-1].weight.grad.abs().sum() > 0


def test_object_frame_needs_the_object_cloud_feature():
    with pytest.raises(ValueError, match="object_pointcloud"):
        _policy(frame_center="object")
    with pytest.raises(ValueError, match="object_pointcloud"):
        _policy(frame_center="object_table")
    with pytest.raises(ValueError, match="frame_center"):
        _policy(frame_center="table")


# ------------------------------------------------------------------------------ test-time augmentation
def test_tta_one_pass_is_the_plain_prediction_and_k_passes_average_rotated_frames():
    pol = _policy(n_points=32)
    batch = _batch(B=3)
    plain = pol.predict_world(batch, tta=1)
    assert pol.config.tta == 1
    for a, b in zip(plain, pol.predict_world(batch)):
        for k in a:
            torch.testing.assert_close(a[k], b[k])
    # a position head that says "b" in the model frame: pass j (frame rotated by 2*pi*j/k about z through
    # the frame centre c) says c + Rz(-phi_j) b in the world; k >= 2 even turns cancel b's horizontal part
    last = [m for m in pol.pos_head.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.zero_()
        bias = torch.tensor([0.1, -0.05, 0.02, 0.04, 0.0, -0.03, 0.01, 0.01]).repeat(2)
        last.bias.copy_(bias)
    pol.eval()  # _cloud: the first n_points (training: a random subset)
    c = pol._center(batch, pol._cloud(batch[C.OBS_POINTCLOUD].float()))
    one = pol.predict_world(batch, tta=1)
    torch.testing.assert_close(one[0]["start_pos"], c + bias[:3], atol=1e-5, rtol=0)
    # pass j also reads another subset of the points (the cloud rolled by j * n_points): its own centre
    full = batch[C.OBS_POINTCLOUD].float()
    cj = [pol._center(batch, pol._cloud(torch.roll(full, -j * 32, dims=1))) for j in range(4)]
    assert not torch.allclose(cj[0], cj[1])
    # pass 1 of 4: 90 degrees; model (x, y) = Rz(90)(world - c): world = c + Rz(-90)(0.1, -0.05) = c + (-0.05, -0.1)
    p1 = pol._world(batch, 1, 4)
    torch.testing.assert_close(p1[0]["start_pos"] - cj[1], torch.tensor([-0.05, -0.1, 0.02]).expand(3, 3), atol=1e-5, rtol=0)
    four = pol.predict_world(batch, tta=4)
    torch.testing.assert_close(four[0]["start_pos"], torch.stack(cj).mean(0) + torch.tensor([0.0, 0.0, 0.02]), atol=1e-5, rtol=0)
    for arm in four:  # quaternions stay unit, with w >= 0; the "active" probability stays in [0, 1]
        for e in ("start_quat", "end_quat"):
            torch.testing.assert_close(arm[e].norm(dim=-1), torch.ones(3), atol=1e-5, rtol=0)
            assert (arm[e][:, 0] >= 0).all()
        assert ((arm["active"] >= 0) & (arm["active"] <= 1)).all()
    with pytest.raises(ValueError, match="--policy.tta"):
        _policy(tta=0)


def test_tta_turns_stay_within_the_trained_rotations():
    """A model trained with rotations of at most x degrees about z is averaged over turns in [-x, x]
    (a turn it never saw would be out of its training distribution); 180: the full circle as before."""
    full = _policy(n_points=32)
    assert [full.tta_turn(j, 4) for j in range(4)] == pytest.approx([0, math.pi / 2, math.pi, 3 * math.pi / 2])
    small = _policy(n_points=32, aug_rot_z_deg=15.0)
    assert small.tta_turn(0, 1) == 0.0
    assert [math.degrees(small.tta_turn(j, 3)) for j in range(3)] == pytest.approx([-15.0, 0.0, 15.0])
    assert max(abs(math.degrees(small.tta_turn(j, 8))) for j in range(8)) == pytest.approx(15.0)
    assert _policy(n_points=32, aug_rot_z_deg=15.0, augment=False).tta_turn(2, 3) == 0.0

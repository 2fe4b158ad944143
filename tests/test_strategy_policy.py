"""``flatlab_strategy``: the learned strategy generator as a LeRobot policy, its export, loss,
recipes, and training through the real ``lerobot-train`` CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

import flatlab_lerobot.lerobot_plugin  # noqa: F401  registers the policy type
from flatlab_lerobot.catalog import load_objects
from flatlab_lerobot.learning import strategy_eval as E
from flatlab_lerobot.learning import strategy_export as X
from flatlab_lerobot.learning import strategy_set as S
from flatlab_lerobot.policies.strategy.configuration_flatlab_strategy import FlatLabStrategyConfig
from flatlab_lerobot.policies.strategy.modeling_flatlab_strategy import FlatLabStrategyPolicy, nt_xent

REPO = Path(__file__).resolve().parents[1]
RECIPES = sorted((REPO / "policies" / "flatlab_strategy").glob("*.json"))
OBJECTS = load_objects()
CLOUD_KEY = "observation.object_pointcloud"


# ------------------------------------------------------------------------------ a synthetic set
def _cloud(strategy: str, rng, n: int, scale: float) -> np.ndarray:
    """A: a thin plate, B: a thick box, C: a wavy sheet (unit-sphere normalized)."""
    p = rng.uniform(-1, 1, (n, 3)) * [scale, 0.7 * scale, 0.0]
    if strategy == "B":
        p[:, 2] = rng.uniform(0, 0.6 * scale, n)
    elif strategy == "C":
        p[:, 2] = 0.15 * scale * np.sin(4 * p[:, 0] / scale)
    else:
        p[:, 2] = rng.uniform(0, 0.02 * scale, n)
    return S.normalize(p)[0]


def synthetic_set(out: Path, objects=None, views: int = 3, n: int = 128, split_override=None, seed: int = 0) -> Path:
    """A strategy set in the real file format with real catalog ids, without simulation: per
    object 2 variants per view (the original and one 'scale' variant whose strategy differs for
    the cloth: its rigid counterpart)."""
    objects = objects or ["book_a5_notebook", "box_gift", "mousepad_standard", "fabric_cotton"]
    rng = np.random.default_rng(seed)
    clouds, rows = [], []
    for oid in objects:
        o = OBJECTS[oid]
        for view in range(views):
            for variant, strat in (("original", o.strategy), ("rigid" if o.deformable else "scale", "A" if o.deformable else o.strategy)):
                clouds.append(_cloud(strat, rng, n, 1.0 if variant == "original" else 0.7))
                rows.append({"label": "ABC".index(strat), "strategy": strat, "label_source": "catalog",
                             "catalog_strategy": o.strategy, "object_id": oid if variant == "original" else f"{oid}@{variant}",
                             "base_object_id": oid, "category": o.category, "split": split_override or o.split,
                             "material": "rigid" if variant == "rigid" else o.material, "transform": variant,
                             "rigid_counterpart": variant == "rigid", "view": view, "seed": view,
                             "radius": 0.2 if variant == "original" else 0.14})  # fmt: skip
    clouds = np.stack(clouds).astype(np.float32)
    extras = {"scene": clouds[:, ::-1].copy(), "rgb": rng.integers(0, 255, (len(clouds), 16, 16, 3), dtype=np.uint8)}
    meta = {"n_clouds": len(clouds), "seed": 0, "settings": {"views": views}}
    S._write_atomic(out, clouds, pd.DataFrame(rows), meta, extras)
    return out


def _policy(**kw) -> FlatLabStrategyPolicy:
    from lerobot.configs.types import FeatureType, PolicyFeature

    cfg = FlatLabStrategyConfig(device="cpu", n_points=64, encoder_channels=[16, 32], **kw)
    cfg.input_features = {
        CLOUD_KEY: PolicyFeature(FeatureType.STATE, (128, 3)),
        "observation.environment_state": PolicyFeature(FeatureType.ENV, (14,)),
        "observation.state": PolicyFeature(FeatureType.STATE, (16,)),
    }
    cfg.output_features = {"action": PolicyFeature(FeatureType.ACTION, (3,))}
    torch.manual_seed(0)
    return FlatLabStrategyPolicy(cfg).eval()


# ------------------------------------------------------------------------------ fast tests
def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="input_key"):
        FlatLabStrategyConfig(input_key="observation.environment_state")
    with pytest.raises(ValueError, match="contrast_negatives"):
        FlatLabStrategyConfig(contrast_negatives="nope")
    with pytest.raises(ValueError, match="temperature"):
        FlatLabStrategyConfig(temperature=0)
    with pytest.raises(ValueError, match="encoder_channels"):
        FlatLabStrategyConfig(encoder_channels=[])


def test_policy_never_reads_environment_state():
    """Only input_key survives validate_features, and the logits do not change when the
    privileged state (or the robot state) is random, zeroed or absent."""
    policy = _policy()
    assert set(policy.config.input_features) == {CLOUD_KEY}
    g = torch.Generator().manual_seed(1)
    cloud = torch.randn(5, 128, 3, generator=g)
    ref = policy.predict_logits({CLOUD_KEY: cloud})
    for env in (torch.randn(5, 14, generator=g), torch.zeros(5, 14)):
        batch = {CLOUD_KEY: cloud, "observation.environment_state": env, "observation.state": torch.randn(5, 16)}
        assert torch.equal(policy.predict_logits(batch), ref)
    probs = policy.select_action({CLOUD_KEY: cloud, "observation.environment_state": torch.ones(5, 14)})
    assert torch.allclose(probs, ref.softmax(1)) and len(policy.strategies) == 5
    assert set(policy.strategies) <= {"A", "B", "C"}
    # sanity: the output does depend on its input
    assert not torch.equal(policy.predict_logits({CLOUD_KEY: cloud * torch.tensor([1.0, 1.0, 5.0])}), ref)
    with pytest.raises(KeyError, match="object_pointcloud"):
        policy.predict_logits({"observation.environment_state": torch.zeros(1, 14)})


def test_cloud_normalization_invariance():
    """The placement (translation) never matters; the size does only through use_scale (the
    unit-sphere normalization happens inside the model, as for the env's raw clouds)."""
    cloud = torch.randn(2, 128, 3)
    shift = torch.tensor([0.1, -0.2, 0.75])
    for use_scale in (True, False):
        policy = _policy(use_scale=use_scale)
        a = policy.predict_logits({CLOUD_KEY: cloud})
        assert torch.allclose(a, policy.predict_logits({CLOUD_KEY: cloud + shift}), atol=1e-4)
        scaled = policy.predict_logits({CLOUD_KEY: cloud * 0.3 + shift})
        assert torch.allclose(a, scaled, atol=1e-4) != use_scale


def test_cloud_extents_measure_thickness_and_footprint_and_use_extent_feeds_them():
    """cloud_extents: thickness (z range), then the footprint's long and short sides along its principal
    axes, whatever the placement and the turn about z; with use_extent (and without use_scale) a uniform
    rescaling changes the logits, which it cannot without it, and the extents' embedding reaches the head."""
    import math

    from flatlab_lerobot.policies.strategy.modeling_flatlab_strategy import cloud_extents

    rng = np.random.default_rng(0)
    box = rng.uniform(0, 1, (1, 2000, 3)) * np.array([0.30, 0.20, 0.02])
    box[0, :4] = [[0, 0, 0], [0.3, 0.2, 0.02], [0.3, 0, 0], [0, 0.2, 0.02]]  # the corners bound the ranges
    box = torch.tensor(box, dtype=torch.float32)
    ext = cloud_extents(box)[0]
    assert torch.allclose(ext, torch.tensor([0.02, 0.30, 0.20]), atol=0.01), ext
    c, s = math.cos(0.7), math.sin(0.7)
    turn = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    moved = box @ turn.T + torch.tensor([0.1, -0.3, 0.75])
    assert torch.allclose(cloud_extents(moved)[0], ext, atol=1e-3)
    # the policy: placement-free; with use_extent a uniform rescaling moves the logits even without
    # use_scale (the extents are metric), and the embedding reaches the head
    for use_extent in (True, False):
        policy = _policy(use_extent=use_extent, use_scale=False)
        assert (policy.extent_embed is not None) == use_extent
        a = policy.predict_logits({CLOUD_KEY: box})
        assert torch.allclose(a, policy.predict_logits({CLOUD_KEY: box + torch.tensor([0.1, -0.3, 0.75])}), atol=1e-4)
        assert torch.allclose(a, policy.predict_logits({CLOUD_KEY: box * 0.5}), atol=1e-4) != use_extent
    with torch.no_grad():
        policy = _policy(use_extent=True)
        a = policy.predict_logits({CLOUD_KEY: box})
        policy.extent_embed[0].bias += 1.0
        assert not torch.allclose(a, policy.predict_logits({CLOUD_KEY: box}))


def test_tta_averages_turned_subsets_and_one_pass_is_unchanged():
    """tta=1 is the single pass the checkpoints were selected with; tta=k averages the class probabilities
    of k passes, pass j on fixed subset j turned by 2*pi*j/k about z; a bad value names the flag."""
    import math

    from flatlab_lerobot.policies.strategy.modeling_flatlab_strategy import normalize_cloud

    policy = _policy()
    cloud = torch.randn(3, 128, 3, generator=torch.Generator().manual_seed(2))
    one = policy.predict_logits({CLOUD_KEY: cloud})
    assert torch.equal(one, policy.head(policy.features(cloud)))
    policy.config.tta = 4
    four = policy.predict_logits({CLOUD_KEY: cloud})
    probs = []
    for j in range(4):
        idx = torch.randperm(128, generator=torch.Generator().manual_seed(j))[:64]
        x, r = normalize_cloud(cloud[:, idx], return_radius=True)
        a = 2 * math.pi * j / 4
        xy = torch.stack([math.cos(a) * x[..., 0] - math.sin(a) * x[..., 1],
                          math.sin(a) * x[..., 0] + math.cos(a) * x[..., 1]], -1)  # fmt: skip
        f = policy.encoder(torch.cat([xy, x[..., 2:]], -1))
        f = torch.cat([f, policy.scale_embed(torch.log(r)[:, None])], 1)
        probs.append(policy.head(f).softmax(1))
    assert torch.allclose(four.exp(), torch.stack(probs).mean(0), atol=1e-5)
    assert not torch.allclose(four, one, atol=1e-4)  # the passes differ
    policy.config.tta = 1
    with pytest.raises(ValueError, match="--policy.tta"):
        FlatLabStrategyConfig(tta=0)
    with pytest.raises(ValueError, match="augment_yaw"):
        FlatLabStrategyConfig(tta=4, augment_yaw=False)


def test_nt_xent_matches_formula():
    z = torch.nn.functional.normalize(torch.randn(6, 4, generator=torch.Generator().manual_seed(0)), dim=1)
    labels = torch.tensor([0, 2, 0, 2, 1, 0])
    objects = torch.tensor([0, 0, 1, 1, 2, 3])
    tau = 0.5
    got = nt_xent(z, labels, objects, tau)
    s = (z @ z.T / tau).numpy()
    terms = []
    for i in range(6):
        pos = [j for j in range(6) if labels[j] == labels[i] and objects[j] != objects[i]]
        neg = [j for j in range(6) if labels[j] != labels[i] and objects[j] == objects[i]]
        if pos and neg:
            terms += [-s[i, p] + np.log(np.exp(s[i, p]) + np.exp(s[i, neg]).sum()) for p in pos]
    assert len(terms) == 6 and np.isclose(float(got), np.mean(terms), atol=1e-5)
    # no same-object negatives: the paper's term vanishes; "other_strategy" negatives do not
    assert float(nt_xent(z, labels, torch.arange(6), tau)) == 0.0
    assert float(nt_xent(z, labels, torch.arange(6), tau, "other_strategy")) > 0.0


def test_forward_masks_padding_and_learns_groups():
    policy = _policy(group_size=2).train()
    b = {CLOUD_KEY: torch.randn(4, 2, 128, 3), "action": torch.eye(3)[torch.tensor([[0, 2], [1, 1], [2, 0], [0, 0]])],
         f"{CLOUD_KEY}_is_pad": torch.tensor([[False, False], [False, True], [False, False], [False, False]]),
         "object_index": torch.tensor([0, 1, 2, 3])}  # fmt: skip
    loss, info = policy.forward(b)
    assert torch.isfinite(loss) and {"ce", "acc", "nt_xent"} <= set(info)
    loss.backward()
    assert all(p.grad is not None for p in policy.encoder.parameters())


def test_one_frame_episodes_train_the_same_with_group_size_1():
    """The paper preset's A-2 / A-3 train on originals-only exports (one cloud per episode) with
    ``group_size=1``: a group of 4 there is the cloud plus 3 pads the loss drops, so both load paths
    give the same loss and gradients, and size 1 loads a quarter of the clouds."""
    torch.manual_seed(1)
    x, labels = torch.randn(6, 128, 3), torch.tensor([0, 1, 2, 0, 1, 2])
    objects = torch.arange(6)
    pad = torch.tensor([[False, True, True, True]] * 6)
    grouped = {CLOUD_KEY: x[:, None].expand(6, 4, 128, 3).clone(), "action": torch.eye(3)[labels][:, None].expand(6, 4, 3),
               f"{CLOUD_KEY}_is_pad": pad, "object_index": objects[:, None]}  # fmt: skip
    single = {CLOUD_KEY: x.clone(), "action": torch.eye(3)[labels], "object_index": objects[:, None]}
    results = []
    for kw, batch in (({"group_size": 4}, grouped), ({"group_size": 1}, single)):
        policy = _policy(**kw).train()
        torch.manual_seed(2)  # the same augmentation draws
        loss, info = policy.forward(batch)
        loss.backward()
        results.append((loss.detach(), info["nt_xent"], [p.grad.clone() for p in policy.encoder.parameters()]))
    (l4, c4, g4), (l1, c1, g1) = results
    assert torch.allclose(l4, l1) and c4 == c1
    assert all(torch.allclose(a, b, atol=1e-6) for a, b in zip(g4, g1, strict=True))


@pytest.mark.parametrize("recipe", RECIPES, ids=lambda p: p.stem)
def test_recipes_parse_as_lerobot_train_configs(recipe):
    import draccus
    from lerobot.configs.train import TrainPipelineConfig

    cfg = draccus.parse(TrainPipelineConfig, config_path=str(recipe), args=["--output_dir=/tmp/never_written"])
    assert cfg.policy.type == "flatlab_strategy" and cfg.dataset.eval_split > 0 and cfg.num_workers == 0
    p = cfg.policy
    assert p.get_optimizer_preset().lr == p.optimizer_lr and p.get_scheduler_preset().gamma == 0.5
    raw = json.loads(recipe.read_text())
    for k, v in raw["policy"].items():
        if k != "type":
            assert getattr(p, k) == v, (recipe.name, k)
    if recipe.stem == "paper":  # App. B: 2048 points, Adam 5e-4 / wd 1e-4, batch 32, x0.5 every 30 of 150 epochs
        assert (p.n_points, p.optimizer_lr, p.optimizer_weight_decay, cfg.batch_size) == (2048, 5e-4, 1e-4, 32)
        assert cfg.steps == 5 * p.scheduler_step_size
    names = {r.stem for r in RECIPES}
    assert {"cpu", "paper", "ablation_A1", "ablation_A2", "ablation_A3", "ablation_A7", "ablation_A8"} <= names


def test_ablation_recipes_differ_from_cpu_only_as_the_paper_says():
    cpu = json.loads((REPO / "policies/flatlab_strategy/cpu.json").read_text())

    def diff(name):
        r = json.loads((REPO / f"policies/flatlab_strategy/ablation_{name}.json").read_text())
        d = {f"policy.{k}": v for k, v in r["policy"].items() if cpu["policy"].get(k) != v}
        d.update({f"dataset.{k}": v for k, v in r["dataset"].items() if cpu["dataset"].get(k) != v})
        d.update({k: v for k, v in r.items() if k not in ("policy", "dataset") and cpu.get(k) != v})
        return d

    assert diff("A1") == {"policy.contrast_weight": 0.0}
    assert set(diff("A2")) == {"dataset.root"} and diff("A2")["dataset.root"].endswith("_orig")
    assert set(diff("A3")) == {"dataset.root", "policy.contrast_weight"}
    assert diff("A7")["policy.input_key"] == "observation.images.object"
    assert diff("A8")["policy.input_key"] == "observation.scene_pointcloud"
    ext = json.loads((REPO / "policies/flatlab_strategy/extra_a2_extent.json").read_text())
    assert ext["policy"].pop("use_extent") is True  # A-2 plus the extents, nothing else
    assert ext == json.loads((REPO / "policies/flatlab_strategy/ablation_A2.json").read_text())


def test_export_refuses_test_objects(tmp_path):
    s = synthetic_set(tmp_path / "set", objects=["book_a5_notebook", next(o for o in OBJECTS if OBJECTS[o].split == "test_alpha")])
    with pytest.raises(ValueError, match="non-train"):
        X.export(s, tmp_path / "lr")
    # a lying 'split' column does not help: the catalog's split is checked too
    s2 = synthetic_set(tmp_path / "set2", objects=[next(o for o in OBJECTS if OBJECTS[o].split == "test_beta")],
                       split_override="train")  # fmt: skip
    with pytest.raises(ValueError, match="non-train"):
        X.export(s2, tmp_path / "lr2")
    with pytest.raises(SystemExit):
        X.main(["--set", str(tmp_path / "set"), "--inputs", "depth"])


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    d = tmp_path_factory.mktemp("strat")
    s = synthetic_set(d / "set")
    summary = X.export(s, d / "lr", inputs=("object", "scene", "rgb"))
    return s, d / "lr", summary


def test_export_is_a_train_only_lerobot_dataset(exported):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    _, root, summary = exported
    frames = pd.read_parquet(root / X.FRAMES_FILE)
    assert (frames.split == "train").all() and all(OBJECTS[b].split == "train" for b in frames.base_object_id)
    ds = LeRobotDataset("local/x", root=root, delta_timestamps={CLOUD_KEY: [0, 0.1], "action": [0, 0.1]})
    assert ds.num_episodes == summary["n_episodes"] == 4 * 3 and len(ds) == summary["n_frames"] == 24
    item = ds[0]
    assert item[CLOUD_KEY].shape == (2, 128, 3) and item["action"].shape == (2, 3)
    assert tuple(item["observation.images.object"].shape) == (3, 16, 16)
    # the cloth's episode interleaves strategies: a 2-frame window holds a C and an A
    ep = frames[(frames.base_object_id == "fabric_cotton") & (frames.view == 0)].sort_values("frame_index")
    assert set(ep.strategy) == {"A", "C"} and ep.strategy.iloc[0] != ep.strategy.iloc[1]
    # validation = lerobot's hold-out: per object (task), the last ceil(3 * 0.3) = 1 view
    val = E.validation_episodes(root, 0.3)
    assert sorted(frames[frames.episode_index.isin(val)].view.unique()) == [2] and len(val) == 4


def test_export_originals_only_and_points(exported, tmp_path):
    set_dir, _, _ = exported
    s = X.export(set_dir, tmp_path / "orig", originals_only=True, points=32)
    frames = pd.read_parquet(tmp_path / "orig" / X.FRAMES_FILE)
    assert s["n_frames"] == 12 and (frames["transform"] == "original").all()
    info = json.loads((tmp_path / "orig" / "meta" / "info.json").read_text())
    assert info["features"][CLOUD_KEY]["shape"] == [32, 3]
    with pytest.raises(ValueError, match="--points"):
        X.export(set_dir, tmp_path / "big", points=10_000)


# ------------------------------------------------------------------------------ the real CLI
@pytest.mark.slow
def test_lerobot_train_cli_trains_and_checkpoint_reloads(exported, tmp_path):
    """`lerobot-train --policy.type=flatlab_strategy` on an exported set writes a standard
    pretrained_model; it reloads through lerobot's make_policy (what --policy.path does) and
    predicts; strategy-eval selects a checkpoint on validation episodes only and scores a set."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy

    set_dir, root, _ = exported
    out = tmp_path / "train"
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    exe = Path(sys.executable).with_name("lerobot-train")
    cmd = [str(exe), "--policy.type=flatlab_strategy", "--dataset.repo_id=local/x", f"--dataset.root={root}",
           "--dataset.eval_split=0.3", "--eval_steps=4", "--policy.n_points=64", "--policy.encoder_channels=[16,32]",
           "--policy.group_size=2", "--steps=8", "--batch_size=4", "--num_workers=0", "--save_freq=4", "--log_freq=4",
           "--policy.device=cpu", "--policy.push_to_hub=false", f"--output_dir={out}"]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "eval_loss=" in r.stdout + r.stderr and "Train/eval split" in r.stdout + r.stderr
    pm = out / "checkpoints" / "last" / "pretrained_model"
    assert {"config.json", "model.safetensors", "policy_preprocessor.json", "train_config.json"} <= {p.name for p in pm.iterdir()}
    cfg = PreTrainedConfig.from_pretrained(pm)
    cfg.pretrained_path = pm
    policy = make_policy(cfg, ds_meta=LeRobotDatasetMetadata("local/x", root=root))
    assert type(policy).__name__ == "FlatLabStrategyPolicy" and set(policy.config.input_features) == {CLOUD_KEY}
    clouds = np.load(set_dir / "clouds.npy")
    probs = policy.select_action({CLOUD_KEY: torch.as_tensor(clouds[:3])})
    assert probs.shape == (3, 3) and torch.allclose(probs.sum(1), torch.ones(3))
    # selection over the saved checkpoints uses the held-out TRAIN views only
    best, sel = E.select_checkpoint(out)
    assert sel["n_val"] == 8 and set(sel["scores"]) == {"000004", "000008"} and best.name == "pretrained_model"
    res = tmp_path / "res.json"
    assert E.main(["--policy", str(out), "--set", str(set_dir), "--out", str(res)]) == 0
    d = json.loads(res.read_text())
    assert d["per_split"]["train"]["n"] == 24 and np.sum(d["confusion_catalog"]) == 24
    assert d["machine"] == "2 CPU cores, no GPU" and d["selection"]["selected"] in {"000004", "000008"}
    # --average-last: the mean of the last K checkpoints' weights, scored on validation too, loadable by lerobot
    assert E.main(["--policy", str(out), "--set", str(set_dir), "--average-last", "2", "--out", str(res)]) == 0
    d = json.loads(res.read_text())
    assert d["selection"]["averaged_steps"] == ["000004", "000008"] and d["selection"]["selected"] == "average_last2"
    assert set(d["selection"]["average_score"]) == {"val_acc", "val_ce"} and Path(d["policy"]).name == "pretrained_model"
    cfg = PreTrainedConfig.from_pretrained(d["policy"])
    cfg.pretrained_path = Path(d["policy"])
    assert type(make_policy(cfg, ds_meta=LeRobotDatasetMetadata("local/x", root=root))).__name__ == "FlatLabStrategyPolicy"


def test_sheet_neighbours_finds_each_sheets_own_views_and_refuses_test_objects_in_training(tmp_path):
    train = synthetic_set(tmp_path / "train")
    fresh = synthetic_set(tmp_path / "fresh", seed=1)
    res = E.sheet_neighbours(train, fresh, n_points=64)
    assert res["n_train_clouds"] == 6 and res["n_query_clouds"] == 6  # 2 sheets x 3 views; no rigid counterpart
    po = res["per_object"]
    assert set(po) == {"mousepad_standard", "fabric_cotton"}
    assert po["mousepad_standard"]["nn"] == "AAA" and po["fabric_cotton"]["nn"] == "CCC"
    for o in po.values():
        assert o["own_mm_median"] < o["other_label_mm_median"]
    assert po["fabric_cotton"]["other_label_object"] == "mousepad_standard"
    tr = res["per_split"]["train"]
    assert (tr["n"], tr["nn_label_right"], tr["own_nearer_than_other_label"]) == (6, 6, 6)
    with pytest.raises(ValueError, match="TRAIN only"):
        E.sheet_neighbours(synthetic_set(tmp_path / "alpha", split_override="test_alpha"), fresh, n_points=64)
    with pytest.raises(SystemExit):
        E.main(["--sheet-neighbours", str(train)])  # needs --set
    out = tmp_path / "nb.json"
    assert E.main(["--sheet-neighbours", str(train), "--set", str(fresh), "--out", str(out)]) == 0
    assert json.loads(out.read_text())["sheet_neighbours"]["per_split"]["train"]["nn_label_right"] == 6


def test_chamfer_yaw_ignores_placement_yaw_not_shape():
    rng = np.random.default_rng(3)
    plate = _cloud("A", rng, 200, 1.0)
    t = np.deg2rad(40.0)  # a multiple of the 10-degree yaw grid
    rot = plate @ np.array([[np.cos(t), np.sin(t), 0], [-np.sin(t), np.cos(t), 0], [0, 0, 1]])
    assert E.chamfer_yaw(plate, rot) < 1e-6
    assert E.chamfer_yaw(plate, _cloud("B", rng, 200, 1.0)) > 0.05


def test_summarize_puts_results_beside_the_paper(tmp_path):
    res = {"per_split": {s: {"acc_catalog": 90.0, "acc_paper": 91.0} for s in E.SPLITS},
           "selection": {"selected": "000100", "scores": {"000100": {"val_acc": 95.0}}}, "training": {"train_wall_s": 12}}
    p = tmp_path / "strategy_ablation_A1.json"
    p.write_text(json.dumps(res))
    row = E.summarize([p]).splitlines()[2]
    assert row.startswith("| ablation_A1 | 12 | 000100 | 95.0 | 90.0 / 91.0 |") and row.endswith("| 97.1 / 88.0 / 77.3 |")


def test_strategy_set_extras_for_ablations(tmp_path):
    """``--extras scene,rgb``: per cloud, a unit-sphere scene cloud (A-8) and the object's RGB crop (A-7)."""
    cfg = S.SetConfig(objects=("box_gift",), n_scales=0, views=2, image_size=128, settle=0.2, n_points=256,
                      extras=("scene", "rgb"))  # fmt: skip
    S.build(cfg, tmp_path / "set", workers=1, progress=False)
    clouds = np.load(tmp_path / "set" / "clouds.npy")
    scene, rgb = np.load(tmp_path / "set" / "scene_clouds.npy"), np.load(tmp_path / "set" / "rgb.npy")
    assert scene.shape == clouds.shape == (2, 256, 3) and rgb.shape == (2, S.RGB_SIZE, S.RGB_SIZE, 3)
    assert np.allclose(np.linalg.norm(scene, axis=2).max(1), 1.0, atol=1e-5)
    assert rgb.dtype == np.uint8 and 0.2 < (rgb.max(-1) > 0).mean() < 1.0  # the object, on black
    with pytest.raises(SystemExit):
        S.main(["--extras", "depth"])


def test_average_checkpoints_means_float_tensors_keeps_the_last_of_the_rest(tmp_path):
    from safetensors.torch import load_file

    from flatlab_lerobot.learning.checkpoint_average import average_checkpoints

    run = tmp_path / "run"
    states = []
    for i, step in enumerate(["000010", "000020", "000030"]):
        pol = _policy()
        with torch.no_grad():
            for j, prm in enumerate(pol.parameters()):
                prm.fill_(float(i + j))
        for name, buf in pol.named_buffers():
            if not buf.is_floating_point():
                buf.fill_(10 * (i + 1))  # BatchNorm's num_batches_tracked
        pol.save_pretrained(run / "checkpoints" / step / "pretrained_model")
        (run / "checkpoints" / step / "pretrained_model" / "train_config.json").write_text(json.dumps({"step": step}))
        states.append(load_file(str(run / "checkpoints" / step / "pretrained_model" / "model.safetensors")))
    out, steps = average_checkpoints(run, 2)
    assert steps == ["000020", "000030"] and out == run / "checkpoints" / "average_last2" / "pretrained_model"
    avg = load_file(str(out / "model.safetensors"))
    for k, t in avg.items():
        if t.is_floating_point():
            assert torch.allclose(t, (states[1][k] + states[2][k]) / 2), k
        else:
            assert torch.equal(t, states[2][k]), k
    assert any(not t.is_floating_point() for t in avg.values())
    assert json.loads((out / "train_config.json").read_text()) == {"step": "000030"}  # the last one's files
    assert not (run / "checkpoints" / "average_last2" / "pretrained_model.tmp").exists()
    reloaded = FlatLabStrategyPolicy.from_pretrained(str(out))
    assert torch.allclose(next(reloaded.parameters()), torch.full_like(next(reloaded.parameters()), 1.5))
    with pytest.raises(ValueError, match="holds 3 saved step"):
        average_checkpoints(run, 4)
    with pytest.raises(FileNotFoundError, match="no checkpoints/ folder"):
        average_checkpoints(tmp_path / "nothing", 2)
    with pytest.raises(SystemExit):
        E.main(["--policy", str(run), "--set", str(tmp_path), "--average-last", "0"])
    from flatlab_lerobot.cli import main as flatlab_main

    dest = tmp_path / "avg3"
    assert flatlab_main(["average-checkpoints", str(run), "--last", "3", "--out", str(dest)]) == 0
    assert json.loads((dest / "average.json").read_text())["steps"] == ["000010", "000020", "000030"]
    with pytest.raises(SystemExit):  # a clear error naming the flag, not a traceback
        flatlab_main(["average-checkpoints", str(run), "--last", "9"])

"""``flatlab_dp3`` (3D Diffusion Policy as a LeRobot policy type) and the end-to-end baseline recipes:
the encoder's shapes are the DP3 paper's, the privileged state never reaches the action, the cloud
is cropped / FPS-sampled / scaled in the model, and the real ``lerobot-train`` trains it on a
collected dataset whose checkpoint then runs an episode through the real ``lerobot-eval``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from torch import nn

import flatlab_lerobot.lerobot_plugin  # noqa: F401  registers the policy type
from flatlab_lerobot.policies.dp3.configuration_flatlab_dp3 import PRESETS, FlatLabDP3Config
from flatlab_lerobot.policies.dp3.modeling_flatlab_dp3 import FlatLabDP3Policy, prepare_clouds

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PC, STATE, ENV = "observation.pointcloud", "observation.state", "observation.environment_state"
BASELINE_RECIPES = sorted(
    p for d in ("flatlab_dp3", "act", "diffusion", "pi0", "pi05") for p in (REPO / "policies" / d).glob("*.json")
    if p.stem in ("cpu", "paper", "finetune")  # (act/tiny_rigid.json: the README's smoke recipe)
)


def _config(**kw) -> FlatLabDP3Config:
    from lerobot.configs.types import FeatureType, PolicyFeature

    kw = {"device": "cpu", "preset": "simple", "down_dims": [16, 32, 64], "diffusion_step_embed_dim": 16,
          "n_points": 64, **kw}  # fmt: skip
    cfg = FlatLabDP3Config(**kw)
    cfg.input_features = {
        PC: PolicyFeature(FeatureType.STATE, (256, 3)),
        STATE: PolicyFeature(FeatureType.STATE, (16,)),
        "observation.ee_pose": PolicyFeature(FeatureType.STATE, (14,)),
        ENV: PolicyFeature(FeatureType.ENV, (14,)),
        "observation.images.front": PolicyFeature(FeatureType.VISUAL, (3, 32, 32)),
    }
    cfg.output_features = {"action": PolicyFeature(FeatureType.ACTION, (16,))}
    return cfg


def _policy(**kw) -> FlatLabDP3Policy:
    torch.manual_seed(0)
    return FlatLabDP3Policy(_config(**kw)).eval()


def _clouds(*lead, n=256, seed=0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    lo, hi = torch.tensor([-0.3, -0.4, 0.75]), torch.tensor([0.4, 0.4, 1.1])
    return lo + (hi - lo) * torch.rand(*lead, n, 3, generator=g)


# ------------------------------------------------------------------------------ the model
def test_encoder_shapes_are_the_dp3_papers():
    """Per point 3 -> 64 -> 128 -> 256 with LayerNorm, a max-pool, a 64-d projection (+ LayerNorm);
    the state MLP 16 -> 64 -> 64; 128 features per observation step, 2 steps into the U-Net."""
    policy = FlatLabDP3Policy(_config(preset="dp3", down_dims=None, diffusion_step_embed_dim=128))
    enc = policy.encoder
    lin = [m for m in enc.point_encoder.mlp if isinstance(m, nn.Linear)]
    assert [(m.in_features, m.out_features) for m in lin] == [(3, 64), (64, 128), (128, 256)]
    assert [m.normalized_shape for m in enc.point_encoder.mlp if isinstance(m, nn.LayerNorm)] == [(64,), (128,), (256,)]
    proj = enc.point_encoder.projection
    assert (proj[0].in_features, proj[0].out_features) == (256, 64) and isinstance(proj[1], nn.LayerNorm)
    st = [(m.in_features, m.out_features) for m in enc.state_mlp if isinstance(m, nn.Linear)]
    assert st == [(16, 64), (64, 64)] and enc.out_dim == 128
    x = torch.randn(5, 512, 3)
    assert enc.point_encoder(x).shape == (5, 64)
    assert torch.equal(enc.point_encoder(x), enc.point_encoder(x[:, torch.randperm(512)]))  # order-free (max-pool)
    # the U-Net is lerobot's, conditioned on 2 steps x 128 features (+ the timestep embedding)
    assert type(policy.unet).__name__ == "DiffusionConditionalUnet1d"
    assert policy.unet.down_modules[0][0].cond_encoder[1].in_features == 128 + 2 * 128
    assert policy.config.down_dims == list(PRESETS["dp3"])
    assert FlatLabDP3Config(preset="simple").down_dims == [128, 256, 384]
    c = policy.config
    assert (c.horizon, c.n_obs_steps, c.n_action_steps, c.num_train_timesteps, c.num_inference_steps) == (4, 2, 3, 100, 10)
    assert type(policy.noise_scheduler).__name__ == "DDIMScheduler" and c.prediction_type == "sample"


def test_only_cloud_and_state_are_inputs():
    cfg = _config()
    FlatLabDP3Policy(cfg)
    assert set(cfg.input_features) == {PC, STATE}
    cfg = _config(use_ee_pose=True)
    FlatLabDP3Policy(cfg)
    assert set(cfg.input_features) == {PC, STATE, "observation.ee_pose"}
    with pytest.raises(ValueError, match="pointcloud_key"):
        FlatLabDP3Config(pointcloud_key=ENV)
    with pytest.raises(ValueError, match="n_action_steps"):
        FlatLabDP3Config(n_action_steps=4)
    with pytest.raises(ValueError, match="preset"):
        FlatLabDP3Config(preset="huge")


def test_action_never_depends_on_environment_state():
    """Same cloud, state and noise -> the same action whether the privileged state is random,
    zeroed or absent (and whatever other extra keys the env gives); a different cloud changes it."""
    policy = _policy()
    cloud, state = _clouds(3), torch.randn(3, 16)
    noise = torch.randn(3, 4, 16, generator=torch.Generator().manual_seed(2))

    def act(**extra):
        policy.reset()
        return policy.select_action({PC: cloud, STATE: state, **extra}, noise=noise)

    ref = act()
    assert ref.shape == (3, 16)
    for extra in ({ENV: torch.randn(3, 14)}, {ENV: torch.zeros(3, 14)},
                  {ENV: torch.ones(3, 14), "observation.images.front": torch.rand(3, 3, 32, 32)}):  # fmt: skip
        assert torch.equal(act(**extra), ref)
    assert not torch.equal(act(**{PC: _clouds(3, seed=5)}), ref)
    assert not torch.equal(act(**{STATE: state + 1.0}), ref)


def test_queues_run_n_action_steps_per_inference():
    policy = _policy()
    calls = []
    orig = policy.conditional_sample
    policy.conditional_sample = lambda *a, **k: calls.append(1) or orig(*a, **k)
    policy.reset()
    for _ in range(7):
        a = policy.select_action({PC: _clouds(1), STATE: torch.randn(1, 16)})
        assert a.shape == (1, 16) and torch.all(a.abs() <= 1.0 + 1e-5)  # normalized, clipped sample
    assert len(calls) == 3  # steps 0, 3, 6


def test_cloud_crop_fps_and_scaling():
    lo, hi = [-0.5, -0.5, 0.7], [0.5, 0.5, 1.2]
    inside = _clouds(2, n=300)
    outside = torch.tensor([[0.0, 0.0, 0.0], [5.0, 0.0, 1.0]]).expand(2, 2, 3)  # the env's zero padding, far points
    out = prepare_clouds(torch.cat([inside, outside], dim=1), 64, lo, hi)
    assert out.shape == (2, 64, 3) and out.abs().max() <= 1.0
    assert torch.equal(out, prepare_clouds(torch.cat([inside, outside], dim=1), 64, lo, hi))  # deterministic
    # farthest-point sampling spreads out: larger extent than the first 64 points
    span = (out.amax(1) - out.amin(1)).mean()
    first = 2 * (inside[:, :64] - torch.tensor(lo)) / (torch.tensor(hi) - torch.tensor(lo)) - 1
    assert span >= (first.amax(1) - first.amin(1)).mean()
    # fewer points than asked: all of them, repeated; none in the box: zeros
    few = prepare_clouds(inside[:, :10], 64, lo, hi)
    assert few.shape == (2, 64, 3) and len(torch.unique(few[0], dim=0)) == 10
    assert torch.equal(prepare_clouds(outside, 8, lo, hi), torch.zeros(2, 8, 3))
    # (B, T, N, 3) batches keep their leading dims
    assert prepare_clouds(_clouds(2, 2), 32, lo, hi).shape == (2, 2, 32, 3)
    # a cloud the env padded by repeating its points (the cameras saw 40) is sampled as those 40: each once,
    # then cycled -- not the 40 and then 24 copies of one of them
    repeated = torch.cat([inside[:, :40]] * 8, dim=1)
    out = prepare_clouds(repeated, 64, lo, hi)
    assert torch.equal(out, prepare_clouds(inside[:, :40], 64, lo, hi))
    _, counts = torch.unique(out[0], dim=0, return_counts=True)
    assert len(counts) == 40 and counts.max() == 2


def test_forward_trains():
    policy = _policy().train()
    batch = {PC: _clouds(4, 2), STATE: torch.randn(4, 2, 16), "action": torch.rand(4, 4, 16) * 2 - 1,
             "action_is_pad": torch.zeros(4, 4, dtype=torch.bool), ENV: torch.randn(4, 2, 14)}  # fmt: skip
    loss, info = policy.forward(batch)
    assert torch.isfinite(loss) and "loss" in info
    loss.backward()
    assert all(p.grad is not None for p in policy.encoder.parameters())


def test_processor_leaves_the_cloud_to_the_model():
    from flatlab_lerobot.policies.dp3.processor_flatlab_dp3 import make_flatlab_dp3_pre_post_processors

    cfg = _config()
    FlatLabDP3Policy(cfg)
    stats = {STATE: {"min": torch.zeros(16), "max": torch.ones(16) * 2},
             "action": {"min": torch.zeros(16), "max": torch.ones(16) * 2},
             PC: {"min": torch.zeros(256, 3), "max": torch.ones(256, 3)}}  # fmt: skip
    pre, post = make_flatlab_dp3_pre_post_processors(cfg, stats)
    cloud = _clouds(n=256)
    out = pre({PC: cloud, STATE: torch.ones(16)})
    assert torch.equal(out[PC].reshape(cloud.shape), cloud) and torch.allclose(out[STATE], torch.zeros(1, 16))
    assert torch.allclose(post(torch.zeros(1, 16)), torch.ones(1, 16))


# ------------------------------------------------------------------------------ recipes
@pytest.mark.parametrize("recipe", BASELINE_RECIPES, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_baseline_recipes_are_offline_and_never_read_privileged_state(recipe):
    import draccus
    from lerobot.configs.train import TrainPipelineConfig

    cfg = draccus.parse(TrainPipelineConfig, config_path=str(recipe), args=["--output_dir=/tmp/never_written"])
    raw = json.loads(recipe.read_text())
    feats = raw["policy"]["input_features"]
    assert ENV not in feats and not any(k.startswith("observation.depth") for k in feats)
    assert cfg.policy.push_to_hub is False and "baselines_" in cfg.dataset.root
    if cfg.policy.type in ("act", "diffusion"):
        assert cfg.policy.pretrained_backbone_weights is None  # offline: no torchvision download
    if cfg.policy.type in ("pi0", "pi05"):  # fine-tunes the released weights (not fetched here)
        assert str(cfg.policy.pretrained_path) == f"lerobot/{cfg.policy.type}_base"
    if cfg.policy.type == "flatlab_dp3":
        p = cfg.policy
        assert (p.horizon, p.n_obs_steps, p.n_action_steps, p.num_inference_steps) == (4, 2, 3, 10)
        assert p.preset == ("simple" if recipe.stem == "cpu" else "dp3") and 512 <= p.n_points <= 1024
    if recipe.stem == "cpu":
        assert cfg.policy.device == "cpu" and cfg.num_workers <= 1 and cfg.dataset.root.endswith("baselines_cpu")


@pytest.mark.parametrize("name", ["overfit_box_shoe", "overfit_box_shoe_half_turn"])
@pytest.mark.parametrize("baseline", ["flatlab_dp3", "act"])
def test_overfit_recipes_are_the_cpu_recipes_on_one_object(baseline, name):
    """The overfit check (docs/baselines.md) changes only the data (box_shoe's demos), the length and
    the loader: the model, its inputs and the optimizer are the cpu recipe's, so its result speaks
    for the cpu rows.  The half-turn pair differs from the first only in the expert's option."""
    import dataclasses

    import draccus
    from lerobot.configs.train import TrainPipelineConfig

    from flatlab_lerobot.collect.recipe import load_recipe

    path = REPO / "policies" / baseline / f"{name}.json"
    cfg = draccus.parse(TrainPipelineConfig, config_path=str(path), args=["--output_dir=/tmp/never_written"])
    assert cfg.policy.type == baseline and cfg.policy.push_to_hub is False
    cpu = json.loads((REPO / "policies" / baseline / "cpu.json").read_text())
    over = json.loads(path.read_text())
    assert over["policy"] == cpu["policy"] and over["batch_size"] == cpu["batch_size"]
    assert over["dataset"]["root"] == f"outputs/datasets/{name}"
    changed = {k for k in {*cpu, *over} if k not in ("dataset", "policy") and cpu.get(k) != over.get(k)}
    assert changed <= {"steps", "num_workers", "output_dir"}, changed
    first = json.loads((REPO / "policies" / baseline / "overfit_box_shoe.json").read_text())
    assert {k: v for k, v in over.items() if k not in ("dataset", "output_dir")} == {
        k: v for k, v in first.items() if k not in ("dataset", "output_dir")
    }
    demos, base = load_recipe(name), load_recipe("baselines_cpu")
    assert demos.objects == ("box_shoe",) and "box_shoe" in base.objects
    for field in ("cameras", "image_size", "n_points", "modalities", "randomization", "max_steps", "fps"):
        assert getattr(demos, field) == getattr(base, field), field
    assert demos.expert.b_right_half_turn == name.endswith("half_turn")
    plain = load_recipe("overfit_box_shoe")
    assert dataclasses.replace(demos, name=plain.name, description=plain.description, source=plain.source,
                               repo_id=plain.repo_id, expert=plain.expert) == plain  # fmt: skip


@pytest.mark.parametrize("baseline", ["flatlab_dp3", "act", "diffusion"])
def test_cpu_half_turn_recipes_change_only_the_experts_option(baseline):
    """policies/<id>/cpu_half_turn.json is cpu.json on baselines_cpu_half_turn's demos, and those demos
    are baselines_cpu's (same seed, so the same placements) with only ``b_right_half_turn`` on: the
    pair of rows measures the expert option and nothing else."""
    import dataclasses

    import draccus
    from lerobot.configs.train import TrainPipelineConfig

    from flatlab_lerobot.collect.recipe import load_recipe

    path = REPO / "policies" / baseline / "cpu_half_turn.json"
    cfg = draccus.parse(TrainPipelineConfig, config_path=str(path), args=["--output_dir=/tmp/never_written"])
    assert cfg.policy.type == baseline and cfg.policy.push_to_hub is False
    cpu, turned = (json.loads((REPO / "policies" / baseline / f"{n}.json").read_text()) for n in ("cpu", "cpu_half_turn"))
    assert turned["dataset"] == {**cpu["dataset"], "repo_id": "local/flatlab_baselines_cpu_half_turn",
                                 "root": "outputs/datasets/baselines_cpu_half_turn"}  # fmt: skip
    assert turned["output_dir"] == f"outputs/train/{baseline}_cpu_half_turn"
    assert {k: v for k, v in turned.items() if k not in ("dataset", "output_dir")} == {
        k: v for k, v in cpu.items() if k not in ("dataset", "output_dir")
    }
    demos, plain = load_recipe("baselines_cpu_half_turn"), load_recipe("baselines_cpu")
    assert demos.expert.b_right_half_turn and not plain.expert.b_right_half_turn
    assert dataclasses.replace(demos, name=plain.name, description=plain.description, source=plain.source,
                               repo_id=plain.repo_id, expert=plain.expert) == plain  # fmt: skip


def test_demo_recipes_record_no_privileged_state_and_fit_the_horizons():
    from flatlab_lerobot.catalog import load_objects
    from flatlab_lerobot.collect.recipe import load_recipe

    train = {o for o, s in load_objects().items() if s.split == "train"}
    for name, per_object, size in (("baselines_cpu", 5, 64), ("baselines_paper", 50, 84)):
        r = load_recipe(name)
        assert set(r.objects) == train and r.episodes == per_object * len(train)
        assert not r.has("environment_state") and not r.has("depth") and r.has("pointcloud") and r.has("rgb")
        assert r.image_size == size and r.cameras == ("front", "top") and r.n_points == 1024
        for recipe in BASELINE_RECIPES:
            raw = json.loads(recipe.read_text())
            if raw["dataset"]["root"].endswith(name):
                p = raw["policy"]
                assert p["input_features"].get(PC, {"shape": [1024, 3]})["shape"] == [1024, 3]
                for k, f in p["input_features"].items():
                    if k.startswith("observation.images."):
                        assert f["shape"] == [3, size, size], (recipe, k)
                assert max(p.get("horizon", 0), p.get("chunk_size", 0)) <= 64 < r.max_steps


# ------------------------------------------------------------------------------ the real CLIs
@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    """1 episode of the box (strategy B), 40 frames, the baselines' modalities (scene cloud of 256)."""
    from flatlab_lerobot.collect.collector import collect, successful_episodes
    from flatlab_lerobot.collect.recipe import recipe_from_dict

    out = tmp_path_factory.mktemp("dp3_ds")
    recipe = recipe_from_dict({"name": "tiny_dp3", "episodes": 1, "objects": ["ref_box"], "max_steps": 40,
                               "cameras": ["front", "top"], "image_size": 32, "modalities": ["pointcloud", "ee_pose"],
                               "n_points": 256, "seed": 3})  # fmt: skip
    summary = collect(recipe, out, progress=False, log=lambda *a: None)
    assert summary["episodes_total"] == 1
    assert successful_episodes(out / "tiny_dp3") == []  # 40 frames: too short to finish the hold
    return out / "tiny_dp3"


@pytest.mark.slow
def test_lerobot_train_then_lerobot_eval(tiny_dataset, tmp_path):
    """`lerobot-train --policy.type=flatlab_dp3` for 3 steps on a collected dataset, then the
    checkpoint runs one episode through `lerobot-eval --env.type=flatlab`."""
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""), "MUJOCO_GL": "egl"}
    out = tmp_path / "train"
    cmd = [str(BIN / "lerobot-train"), "--policy.type=flatlab_dp3", "--dataset.repo_id=local/tiny_dp3",
           f"--dataset.root={tiny_dataset}", "--dataset.video_backend=pyav", "--policy.preset=simple",
           "--policy.down_dims=[16,32,64]", "--policy.diffusion_step_embed_dim=16", "--policy.n_points=64",
           "--policy.device=cpu", "--policy.push_to_hub=false", "--steps=3", "--batch_size=2", "--num_workers=0",
           "--save_freq=3", "--log_freq=1", "--wandb.enable=false", f"--output_dir={out}"]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300, check=False)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    pm = out / "checkpoints" / "last" / "pretrained_model"
    saved = json.loads((pm / "config.json").read_text())
    assert saved["type"] == "flatlab_dp3" and set(saved["input_features"]) == {PC, STATE}
    assert {"model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json"} <= {p.name for p in pm.iterdir()}
    ev = tmp_path / "eval"
    cmd = [str(BIN / "lerobot-eval"), f"--policy.path={pm}", "--policy.device=cpu", "--env.type=flatlab",
           "--env.object_id=ref_box", "--env.n_points=256", "--env.obs_pixels=false", "--env.image_size=32",
           "--env.render_size=32", "--env.episode_length=6", "--eval.n_episodes=1", "--eval.batch_size=1",
           f"--output_dir={ev}"]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300, check=False)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    info = json.loads((ev / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1 and info["overall"]["pc_success"] == 0.0


@pytest.mark.slow
def test_copy_without_videos_gives_dp3_the_same_samples(tmp_path):
    """lerobot's own `lerobot-edit-dataset --operation.type=remove_feature` (the cpu preset's
    ``demos_cpu_half_turn_cloud`` stage) drops the camera videos and keeps every sample DP3 reads: same frames, same
    clouds, states and actions over DP3's time windows, same statistics."""
    import numpy as np
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from flatlab_lerobot.collect.collector import collect
    from flatlab_lerobot.collect.recipe import recipe_from_dict

    recipe = recipe_from_dict({"name": "tiny_dp3", "episodes": 1, "objects": ["ref_box"], "max_steps": 24,
                               "cameras": ["front", "top"], "image_size": 32, "modalities": ["rgb", "pointcloud"],
                               "n_points": 256, "seed": 3})  # fmt: skip
    collect(recipe, tmp_path / "demos", progress=False, log=lambda *a: None)
    tiny_dataset = tmp_path / "demos" / "tiny_dp3"
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    videos = ["observation.images.front", "observation.images.top"]
    new = tmp_path / "cloud" / "tiny_dp3"
    cmd = [str(BIN / "lerobot-edit-dataset"), "--repo_id=tiny_dp3", f"--root={tiny_dataset}", "--new_repo_id=tiny_dp3",
           f"--new_root={new}", "--operation.type=remove_feature", f"--operation.feature_names={videos}"]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300, check=False)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    fps = json.loads((tiny_dataset / "meta" / "info.json").read_text())["fps"]
    window = {PC: [-1 / fps, 0.0], STATE: [-1 / fps, 0.0], "action": [i / fps for i in range(-1, 3)]}
    a = LeRobotDataset("tiny_dp3", root=tiny_dataset, delta_timestamps={**window, **{k: window[PC] for k in videos}},
                       video_backend="pyav")
    b = LeRobotDataset("tiny_dp3", root=new, delta_timestamps=window)
    assert set(a.meta.video_keys) == set(videos) and b.meta.video_keys == []
    assert len(a) == len(b) == 24
    for i in (0, 1, 11, 23):
        x, y = a[i], b[i]
        assert not set(videos) & set(y)
        for k in (PC, STATE, "action", "action_is_pad", "frame_index", "episode_index"):
            assert torch.equal(x[k], y[k]), (i, k)
    for k in (PC, STATE, "action"):
        for s in ("min", "max", "mean", "std"):
            np.testing.assert_allclose(a.meta.stats[k][s], b.meta.stats[k][s], rtol=1e-6, err_msg=f"{k} {s}")

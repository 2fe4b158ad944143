"""The ``flatlab`` EnvConfig as LeRobot users meet it: bad ``--env.*`` values fail at once naming the
flag, ``--help`` describes every field, a checkpoint whose features the env does not give is one named
error, async vector envs (lerobot-eval's default on machines with >= 3 cores) give the sync results,
and the scripted policy plans in the cell of the scene it is evaluated in."""

import json
import os
import subprocess
import sys
from dataclasses import fields
from pathlib import Path
from types import SimpleNamespace
from unittest import mock

import numpy as np
import pytest
from lerobot.configs import FeatureType, PolicyFeature

import flatlab_lerobot  # noqa: F401  registers the env and policy types
from flatlab_lerobot.evaluation.protocol import EvalError
from flatlab_lerobot.evaluation.protocol import main as flatlab_eval
from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.lerobot_env import (
    EnvConfigError,
    FlatLabEnvConfig,
    PolicyEnvMismatch,
    check_policy_features,
)
from flatlab_lerobot.sim.scene import CellConfig
from flatlab_lerobot.strategies import Expert

BIN = Path(sys.executable).parent
ENV = {**os.environ, "MUJOCO_GL": "egl"}
REPO = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------ field validation
@pytest.mark.parametrize(
    "field, value, says",
    [
        ("object_id", "ref_boxx", "did you mean ref_box"),
        ("task", "grap", "did you mean grasp"),
        ("scene", "kitchen", "kitchen_counter"),
        ("action_mode", "eef", "valid: joint, ee"),
        ("cameras", ["front", "side"], "valid: front, top, left, right"),
        ("pointcloud_cameras", ["ceiling"], "valid: front, top, left, right"),
        ("render_camera", "rigth", "did you mean right"),
        ("image_size", 0, "positive integer"),
        ("n_points", -5, "positive integer"),
        ("n_object_points", 0, "positive integer"),
        ("episode_length", 0, "positive integer"),
        ("fps", 0, "positive integer"),
        ("xy_range", 0.5, "[0, 0.2]"),
        ("yaw_range_deg", 400.0, "[0, 180]"),
    ],
)
def test_bad_env_value_names_the_flag(field, value, says):
    with pytest.raises(EnvConfigError) as e:
        FlatLabEnvConfig(**{field: value})
    msg = str(e.value)
    assert f"--env.{field}" in msg and says in msg, msg


def test_good_values_build_and_every_scene_validates():
    from flatlab_lerobot.catalog import load_scenes

    for sid in load_scenes():
        cfg = FlatLabEnvConfig(scene=sid, task="touch_dual", object_id="ref_box", action_mode="ee")
        assert cfg.features["action"].shape == (14,)
    cfg = FlatLabEnvConfig()
    assert cfg.features["ee_pose"].shape == (14,) and cfg.features["cell"].shape == (7,)
    assert cfg.features_map["ee_pose"] == "observation.ee_pose" and cfg.features_map["cell"] == "observation.cell"


@pytest.mark.slow
def test_lerobot_eval_cli_bad_value_fails_before_building_an_env_and_help_describes_every_field():
    r = subprocess.run(
        [str(BIN / "lerobot-eval"), "--env.type=flatlab", "--env.object_id=ref_boxx", "--policy.type=flatlab_scripted"],
        capture_output=True, text=True, env=ENV, timeout=300,
    )  # fmt: skip
    out = r.stdout + r.stderr
    assert r.returncode != 0
    assert "--env.object_id='ref_boxx' is not valid (did you mean ref_box" in out, out[-3000:]
    assert "Making environment" not in out  # lerobot-eval's eval_main never started
    h = subprocess.run(
        [str(BIN / "lerobot-eval"), "--env.type=flatlab", "--help"], capture_output=True, text=True, env=ENV, timeout=300
    )
    assert h.returncode == 0, h.stderr[-2000:]
    text = h.stdout
    blocks = text[text.index("FlatLabEnvConfig ['env']:") :].split("\n  --env.")[1:]
    described = {b.split()[0]: " ".join(b.split("\n", 1)[0].split()[2:] + b.split("\n")[1:]).strip() for b in blocks}
    for f in fields(FlatLabEnvConfig):
        assert f.name in described, f"--env.{f.name} missing from --help"
        assert len(described[f.name].replace("(default:", "").split()) > 3, f"--env.{f.name} has no description"


# ------------------------------------------------------------------------- policy/env features
def _policy(**inputs) -> SimpleNamespace:
    feats = {k: PolicyFeature(t, tuple(s)) for k, (t, s) in inputs.items()}
    return SimpleNamespace(input_features=feats, output_features={"action": PolicyFeature(FeatureType.ACTION, (16,))})


S, V = FeatureType.STATE, FeatureType.VISUAL


@pytest.mark.parametrize(
    "env_kw, feature, shape, fix",
    [
        ({}, "observation.images.front", (3, 64, 64), "--env.image_size=64"),
        ({}, "observation.images.left", (3, 96, 96), "--env.cameras=[front,top,left]"),
        ({"obs_pixels": False}, "observation.images.top", (3, 96, 96), "--env.obs_pixels=true"),
        ({}, "observation.pointcloud", (512, 3), "--env.n_points=512"),
        ({"obs_pointcloud": False}, "observation.object_pointcloud", (128, 3),
         "--env.obs_pointcloud=true --env.n_object_points=128"),
        ({}, "observation.depth.front", (1, 96, 96), "no --env flag can fix this"),
        ({}, "observation.state", (14,), "no --env flag can fix this"),
        ({}, "observation.images.ceiling", (3, 96, 96), "no --env flag can fix this"),
    ],
)  # fmt: skip
def test_feature_mismatch_names_feature_shapes_and_flag(env_kw, feature, shape, fix):
    env = FlatLabEnvConfig(**env_kw)
    pol = _policy(**{"observation.state": (S, (16,)), feature: (V if "images" in feature else S, shape)})
    with pytest.raises(PolicyEnvMismatch) as e:
        check_policy_features(pol, env)
    msg = str(e.value)
    assert feature in msg and str(shape) in msg and fix in msg, msg


def test_matching_features_pass_and_action_mode_is_checked():
    env = FlatLabEnvConfig(image_size=64, n_points=512, n_object_points=128)
    pol = _policy(**{
        "observation.state": (S, (16,)), "observation.ee_pose": (S, (14,)), "observation.images.front": (V, (3, 64, 64)),
        "observation.pointcloud": (S, (512, 3)), "observation.object_pointcloud": (S, (128, 3)),
    })  # fmt: skip
    check_policy_features(pol, env)
    pol.output_features = {"action": PolicyFeature(FeatureType.ACTION, (14,))}
    with pytest.raises(PolicyEnvMismatch, match="--env.action_mode=ee"):
        check_policy_features(pol, env)
    # a rename map (lerobot-eval --rename_map) is applied before the check
    pol = _policy(**{"observation.images.cam0": (V, (3, 64, 64))})
    check_policy_features(pol, env, rename_map={"observation.images.front": "observation.images.cam0"})


@pytest.mark.slow
def test_checkpoint_env_mismatch_is_one_named_error_in_both_clis(tmp_path):
    from test_protocol import _tiny_act_checkpoint  # a 32 px ACT saved as lerobot-train saves it

    ckpt = _tiny_act_checkpoint(tmp_path / "pretrained_model")
    with pytest.raises(EvalError) as e:
        flatlab_eval(["--policy", str(ckpt), "--objects", "ref_box", "--trials", "1", "--out", str(tmp_path / "fe")])
    msg = str(e.value)
    assert "observation.images.front: the checkpoint has shape (3, 32, 32), the env gives (3, 96, 96)" in msg, msg
    assert "--env.image_size=32" in msg
    r = subprocess.run(
        [str(BIN / "lerobot-eval"), f"--policy.path={ckpt}", "--env.type=flatlab", "--env.object_id=ref_box",
         "--eval.n_episodes=1", f"--output_dir={tmp_path / 'le'}"],
        capture_output=True, text=True, env=ENV, timeout=300,
    )  # fmt: skip
    out = r.stdout + r.stderr
    assert r.returncode != 0
    assert "PolicyEnvMismatch" in out and "use --env.image_size=32" in out, out[-3000:]
    assert "(3, 32, 32)" in out and "(3, 96, 96)" in out


# ---------------------------------------------------------------------------------- async envs
def test_default_batch_size_on_a_4_core_machine_is_2_async():
    """lerobot-eval's default (--eval.batch_size=0) on 4 cores: floor(0.7 * 4) = 2 envs in an
    AsyncVectorEnv, the setting the next test runs."""
    from lerobot.configs.default import EvalConfig

    with mock.patch("os.cpu_count", return_value=4):
        cfg = EvalConfig(n_episodes=2)
    assert cfg.batch_size == 2 and cfg.use_async_envs


@pytest.mark.slow
def test_lerobot_eval_async_batch_of_2_matches_sync(tmp_path):
    """The real lerobot-eval with two AsyncVectorEnv (forkserver) workers gives, episode for episode,
    the success and length that ``flatlab eval`` (one SyncVectorEnv, in-process) gives for the same seeds."""
    n, steps = 2, 90
    out = tmp_path / "async"
    cmd = [
        str(BIN / "lerobot-eval"), "--policy.type=flatlab_scripted", "--policy.device=cpu", "--env.type=flatlab",
        "--env.object_id=ref_box", "--env.obs_pixels=false", "--env.obs_pointcloud=false", "--env.render_size=32",
        f"--env.episode_length={steps}", f"--eval.n_episodes={n}", "--eval.batch_size=2", "--eval.use_async_envs=true",
        f"--output_dir={out}",
    ]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    metrics = json.loads((out / "eval_info.json").read_text())["per_task"][0]["metrics"]
    from test_protocol import _video_frames

    async_eps = [(bool(s), _video_frames(out / "videos" / "flatlab_0" / f"eval_episode_{i}.mp4"))
                 for i, s in enumerate(metrics["successes"])]  # fmt: skip
    ref = tmp_path / "sync"
    assert flatlab_eval(["--policy", "flatlab_scripted", "--objects", "ref_box", "--trials", str(n), "--workers", "1",
                         "--quiet", "--no-plot", "--out", str(ref), f"--env.episode_length={steps}"]) == 0  # fmt: skip
    recs = sorted((json.loads(x) for x in (ref / "results.jsonl").read_text().splitlines()), key=lambda r: r["trial"])
    assert async_eps == [(bool(r["G"]), r["steps"]) for r in recs]
    assert all(s for s, _ in async_eps)  # the box is lifted in both episodes (a check that can fail)


# ------------------------------------------------------------------------ scripted policy in scenes
SCENES = ("living_coffee", "study_desk", "kitchen_counter")  # table tops at 0.65, 0.75 and 0.90 m


def test_scripted_policy_builds_the_observed_cell():
    """``observation.cell`` -> ``CellConfig.from_calibration`` gives the expert the env's kinematics:
    the same TCP poses as an expert built on the scene's full cell, for random postures."""
    from flatlab_lerobot.policies.scripted import FlatLabScriptedConfig
    from flatlab_lerobot.policies.scripted.modeling_flatlab_scripted import FlatLabScriptedPolicy

    policy = FlatLabScriptedPolicy(FlatLabScriptedConfig(device="cpu"))
    rng = np.random.default_rng(0)
    for sid in SCENES:
        env = FlatLabEnv(object_id="ref_box", scene=sid, obs_pixels=False, obs_pointcloud=False)
        obs, _ = env.reset(seed=0)
        assert np.allclose(obs["cell"], env.cell.calibration())
        mine, theirs = policy._expert(0, obs["cell"]), Expert(env.cell)
        assert mine.cell.table_height == pytest.approx(env.cell.table_height, abs=1e-6)
        for _ in range(3):
            q = np.asarray(obs["agent_pos"], float)[[*range(7), *range(8, 15)]] + rng.normal(0, 0.3, 14)
            for arm, (p, R) in theirs.fk(q).items():
                p2, R2 = mine.fk(q)[arm]
                np.testing.assert_allclose(p2, p, atol=1e-5)
                np.testing.assert_allclose(R2, R, atol=1e-5)
        env.close()
    default = CellConfig()
    assert CellConfig.from_calibration(default.calibration()).calibration().tolist() == default.calibration().tolist()


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_scripted_policy_succeeds_in_scenes_like_the_env_expert(scene, tmp_path):
    """flatlab_scripted through ``flatlab eval`` (lerobot's make_policy / processors / eval_policy) in
    a scene, against the expert driving the same env episode directly with the scene's cell."""
    seed = 1000
    env = FlatLabEnv(object_id="ref_box", scene=scene, obs_pixels=False, obs_pointcloud=False, episode_length=150)
    obs, _ = env.reset(seed=seed)
    last = {"obs": obs}
    gen = Expert(env.cell, env.control_dt).episode(
        "B", lambda: tuple(last["obs"][k].astype(np.float64) for k in ("agent_pos", "environment_state"))
    )
    for t in range(150):
        last["obs"], _, term, trunc, info = env.step(next(gen)[2].astype(np.float32))
        if term or trunc:
            break
    env.close()
    out = tmp_path / "eval"
    assert flatlab_eval(["--policy", "flatlab_scripted", "--objects", "ref_box", "--trials", "1", "--workers", "1",
                         "--quiet", "--no-plot", "--out", str(out), f"--seed={seed}", f"--env.scene={scene}",
                         "--env.episode_length=150"]) == 0  # fmt: skip
    rec = json.loads((out / "results.jsonl").read_text().splitlines()[0])
    assert info["is_success"] and rec["G"] == 1
    assert rec["steps"] == t + 1  # the same episode, step for step


def test_readme_act_recipe_runs_with_the_readme_env_flags():
    """The README trains ACT with ``policies/act/tiny_rigid.json`` and evaluates it with
    ``--env.image_size=64 --env.obs_pointcloud=false``: the recipe's inputs are exactly what the env
    then gives (and no privileged state), so neither flatlab eval nor lerobot-eval refuses it."""
    spec = json.loads((REPO / "policies" / "act" / "tiny_rigid.json").read_text())
    feats = {k: PolicyFeature(FeatureType[v["type"]], tuple(v["shape"])) for k, v in spec["policy"]["input_features"].items()}
    assert "observation.environment_state" not in feats
    pol = SimpleNamespace(input_features=feats, output_features={"action": PolicyFeature(FeatureType.ACTION, (16,))})
    check_policy_features(pol, FlatLabEnvConfig(image_size=64, obs_pointcloud=False))
    with pytest.raises(PolicyEnvMismatch, match="--env.image_size=64"):
        check_policy_features(pol, FlatLabEnvConfig())
    readme = (REPO / "README.md").read_text()
    assert "--config_path=policies/act/tiny_rigid.json" in readme
    assert readme.count("--env.image_size=64 --env.obs_pointcloud=false") >= 2  # flatlab eval and lerobot-eval lines

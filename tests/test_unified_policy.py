"""``flatlab_unified``: a tiny artifact (untrained tiny sub-models, built by ``flatlab unified-build``)
runs episodes through the real ``lerobot-eval`` and ``flatlab eval``; its actions never depend on
``observation.environment_state``; the strategy can be fixed (learned Slide / Lift baselines); it
reloads to identical weights and actions; the builder refuses sub-models trained on Test objects; the
executor is conditioned exactly as the primitive set recorded the expert's stages."""

import collections
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.utils import preprocess_observation
from lerobot.utils.constants import OBS_ENV_STATE

import flatlab_lerobot.lerobot_plugin  # noqa: F401  registers the policy types
from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.learning import unified_build
from flatlab_lerobot.policies.executor import configuration_flatlab_executor as C
from flatlab_lerobot.policies.executor.modeling_flatlab_executor import FlatLabExecutorPolicy
from flatlab_lerobot.policies.strategy.configuration_flatlab_strategy import FlatLabStrategyConfig
from flatlab_lerobot.policies.strategy.modeling_flatlab_strategy import FlatLabStrategyPolicy
from flatlab_lerobot.policies.unified.configuration_flatlab_unified import INPUTS, FlatLabUnifiedConfig
from flatlab_lerobot.policies.unified.modeling_flatlab_unified import FlatLabUnifiedPolicy, Observed, _Episode
from flatlab_lerobot.sim.robot import ARMS
from flatlab_lerobot.strategies import STAGE_SPECS, STRATEGIES, World

BIN = Path(sys.executable).parent
N, K = 128, 32  # scene / object cloud points of the tiny artifact
CAMS = ["front", "top", "left", "right"]
ENV_FLAGS = [f"--env.pointcloud_cameras=[{','.join(CAMS)}]", "--env.image_size=32", f"--env.n_points={N}",
             f"--env.n_object_points={K}", "--env.obs_pixels=false"]  # fmt: skip
OBJECT = "ref_box"


def _tiny_submodels(root: Path) -> tuple[Path, Path]:
    torch.manual_seed(0)
    ex = C.FlatLabExecutorConfig(
        device="cpu", push_to_hub=False, n_points=64, sa_npoints=[32, 8], sa_nsamples=[8, 8], sa_mlps=[[16], [32]],
        global_mlp=[32], head_hidden=[32], cond_dim=8, frame_center="object",
        input_features={C.OBS_POINTCLOUD: PolicyFeature(FeatureType.STATE, (N, 3)),
                        C.OBS_PRIMITIVE: PolicyFeature(FeatureType.STATE, (C.PRIMITIVE_DIM,)),
                        C.OBS_TCP_STATE: PolicyFeature(FeatureType.STATE, (C.TCP_STATE_DIM,)),
                        C.OBS_OBJECT_CLOUD: PolicyFeature(FeatureType.STATE, (K, 3))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (C.ACTION_DIM,))},
    )  # fmt: skip
    gen = FlatLabStrategyConfig(
        device="cpu", push_to_hub=False, n_points=64, encoder_channels=[16, 32], head_hidden=16, proj_hidden=16,
        proj_dim=8, input_features={"observation.object_pointcloud": PolicyFeature(FeatureType.STATE, (K, 3))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (3,))},
    )  # fmt: skip
    FlatLabExecutorPolicy(ex).save_pretrained(root / "executor")
    FlatLabStrategyPolicy(gen).save_pretrained(root / "generator")
    return root / "generator", root / "executor"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("unified")
    gen, ex = _tiny_submodels(root)
    record = unified_build.build(gen, ex, root / "unified", allow_unverified=True, log=lambda *a: None)
    return {"root": root, "generator": gen, "executor": ex, "artifact": root / "unified", "record": record}


def _load(path, **overrides) -> FlatLabUnifiedPolicy:
    cfg = PreTrainedConfig.from_pretrained(path, cli_overrides=[f"--{k}={v}" for k, v in overrides.items()])
    pol = FlatLabUnifiedPolicy.from_pretrained(path, config=cfg)
    pol.eval()
    return pol


def _env(object_id=OBJECT, **kw) -> FlatLabEnv:
    return FlatLabEnv(object_id=object_id, obs_pixels=False, n_points=N, n_object_points=K, image_size=32,
                      pointcloud_cameras=CAMS, **kw)  # fmt: skip


def _batch(obs: dict) -> dict:
    """The env observation as lerobot-eval hands it to the policy (batched tensors, policy keys)."""
    return preprocess_observation({k: np.asarray(v)[None] for k, v in obs.items()})


# ------------------------------------------------------------------------------ the artifact
def test_artifact_is_a_pretrained_model_folder_holding_both_submodels(tiny):
    from safetensors.torch import load_file

    art = tiny["artifact"]
    for name in ("config.json", "model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json",
                 unified_build.BUILD_RECORD):  # fmt: skip
        assert (art / name).is_file(), name
    cfg = json.loads((art / "config.json").read_text())
    assert cfg["type"] == "flatlab_unified" and cfg["strategy"] == "learned"
    assert set(cfg["input_features"]) == set(INPUTS) and OBS_ENV_STATE not in cfg["input_features"]
    weights = load_file(str(art / "model.safetensors"))
    for sub in ("generator", "executor"):
        own = load_file(str(tiny[sub] / "model.safetensors"))
        assert {k for k in weights if k.startswith(f"{sub}.")} == {f"{sub}.{k}" for k in own}
        for k, v in own.items():
            torch.testing.assert_close(weights[f"{sub}.{k}"], v, atol=0, rtol=0)
    rec = tiny["record"]
    assert rec["allow_unverified"] and not rec["train_only_check"]["executor"]["verified"]
    assert f"--env.n_points={N}" in rec["env_flags"] and f"--env.n_object_points={K}" in rec["env_flags"]


def test_plugin_registers_the_type_and_lerobot_finds_its_classes():
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    assert "flatlab_unified" in PreTrainedConfig.get_known_choices()
    assert get_policy_class("flatlab_unified") is FlatLabUnifiedPolicy
    pre, post = make_pre_post_processors(FlatLabUnifiedConfig(device="cpu"))
    assert [type(s).__name__ for s in pre.steps][-1] == "DeviceProcessorStep"


def _rollout(policies, steps: int, object_id=OBJECT, seed=0, batch_fns=None):
    """One env episode driven by ``policies[0]``; every policy sees the same observation (through its
    ``batch_fns`` entry) at every step.  Returns the actions (policies x steps x 16)."""
    env = _env(object_id)
    obs, _ = env.reset(seed=seed)
    for p in policies:
        p.reset()
    fns = batch_fns or [_batch] * len(policies)
    out = [[] for _ in policies]
    for _ in range(steps):
        acts = [p.select_action(fn(obs))[0].numpy() for p, fn in zip(policies, fns)]
        for o, a in zip(out, acts):
            o.append(a)
        obs, _, term, trunc, _ = env.step(acts[0])
        if term or trunc:
            break
    env.close()
    return np.array(out)


def _run_until_stage(pol, last: int, steps: int) -> list[tuple[int, str | None]]:
    """One env episode (the default object, seed 0) driven by ``pol`` until its stage index passes ``last``, the
    episode ends or ``steps`` steps ran.  Returns (stage index, stage) after each step's action."""
    env = _env()
    obs, _ = env.reset(seed=0)
    pol.reset()
    seq = []
    for _ in range(steps):
        action = pol.select_action(_batch(obs))[0].numpy()
        seq.append((pol.stage_indices[0], pol.stages[0]))
        obs, _, term, trunc, _ = env.step(action)
        if term or trunc or pol.stage_indices[0] > last:
            break
    env.close()
    return seq


def test_reload_round_trip_gives_identical_weights_and_actions(tiny, tmp_path):
    a = _load(tiny["artifact"])
    a.save_pretrained(tmp_path / "again")
    b = _load(tmp_path / "again")
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys()
    for k in sa:
        torch.testing.assert_close(sa[k], sb[k], atol=0, rtol=0)
    acts = _rollout([a, b], steps=25)
    np.testing.assert_array_equal(acts[0], acts[1])
    assert a.stage_indices[0] >= 1  # the actions covered more than one predicted stage


@pytest.mark.parametrize(
    "overrides",
    [{}, {"strategy": "A", "contact": "observed"}, {"strategy": "A", "contact": "observed", "contact_from_hand": "true"},
     {"strategy": "B", "contact": "observed", "contact_from_hand": "true", "contact_b_face": "true"},
     {"strategy": "B", "contact": "observed", "contact_from_hand": "true", "contact_b_face": "true",
      "contact_b_steady": "true", "contact_b_align": "true", "contact_b_centred": "true"},
     {"strategy": "C", "contact": "observed"},
     {"strategy": "C", "contact": "observed", "contact_grip_closed": "true"},
     {"strategy": "A", "contact": "observed", "contact_from_hand": "true", "contact_a_grasp": "true", "max_push_passes": "1"},
     {"strategy": "A", "contact": "observed", "contact_from_hand": "true", "contact_a_slide_full": "true",
      "contact_a_touch": "true", "clear_all": "true", "quick_retry": "true", "contact_a_pusher_side": "true",
      "retry_next_strategy": "true", "retry_switch_after": "2", "retry_track": "true", "reach_check": "true"},
     {"strategy": "A", "contact": "observed", "contact_from_hand": "true", "contact_a_grasp": "true",
      "contact_a_backoff": "true", "contact_a_sheet_lift": "true", "max_push_passes": "1"},
     {"strategy": "A", "continue_from_hand": "AC", "continue_level_slide": "true", "continue_press_deeper": "0.004",
      "max_push_passes": "1"},
     {"strategy": "C", "continue_from_hand": "AC", "continue_level_squeeze": "true"},
     {"strategy": "C", "continue_from_hand": "AC", "continue_c_heights": "all"},
     {"strategy": "A", "continue_from_hand": "AC", "continue_a_grasp_heights": "true", "continue_a_sheet_lift": "true",
      "a_passes_as_first": "true", "continue_slide_cap": "true", "max_push_passes": "1"},
     {"strategy": "A", "continue_from_hand": "AC", "continue_press_stalled": "0.006", "continue_a_preapproach_line": "true",
      "max_push_passes": "1", "continue_press_floor": "0.003"},
     {"strategy": "A", "continue_from_hand": "AC", "a_side_arms": "true", "continue_a_preapproach_line": "true"},
     {"strategy": "C", "continue_from_hand": "AC", "continue_c_heights": "all", "continue_c_squeeze_end": "true",
      "continue_c_pinch_centre": "true"},
     {"retry_failed": "true", "retry_switch_after": "2", "continue_from_hand": "AC", "continue_press_stalled": "0.006"},
     {"retry_failed": "true", "retry_switch_after": "2", "retry_on_response": "AC", "first_attempt": "C",
      "retry_rank": "first_sight"},
     {"retry_failed": "true", "retry_switch_after": "2", "retry_rank": "first_sight", "b_min_width": "0.3"}],
)
def test_actions_never_depend_on_environment_state(tiny, overrides):
    """Three instances see each observation with the privileged state as is, zeroed, and absent (also
    with the contact heights, A's slide length and C's squeeze and pinch from the observed clouds and
    the calibration, observed_contact.py)."""
    pols = [_load(tiny["artifact"], **overrides) for _ in range(3)]

    def zeroed(obs):
        b = _batch(obs)
        b[OBS_ENV_STATE] = torch.zeros_like(b[OBS_ENV_STATE])
        return b

    def absent(obs):
        return {k: v for k, v in _batch(obs).items() if k != OBS_ENV_STATE}

    c, a_arm = overrides.get("strategy") == "C", bool(overrides.get("contact_a_grasp"))
    stalled = bool(overrides.get("continue_press_stalled"))  # into A's second push pass, decided from the clouds
    steps = 140 if c else 150 if a_arm or stalled else 30  # C: up to its pinch; A's grasp arm: into the grasp stages
    acts = _rollout(pols, steps=steps, batch_fns=[_batch, zeroed, absent])
    np.testing.assert_array_equal(acts[0], acts[1])
    np.testing.assert_array_equal(acts[0], acts[2])
    assert len({p.strategies[0] for p in pols}) == 1 and pols[0].stage_indices[0] >= 1
    if overrides.get("contact") == "observed":  # the touch's heights were set from the object cloud
        posed = [d for d in pols[0].decisions[0] if "heights" in d]
        touch = [d for d in posed if d["primitive"] == "touch"]
        assert touch and all(h["observed"][1] is not None for h in touch[0]["heights"].values())
    if a_arm:  # A's grasp stages were commanded to the seen side's arm, the pre-approach a line from the hand
        chosen = [d for d in pols[0].decisions[0] if "a_arm" in d]
        assert chosen and all(d["a_arm"]["side"] in ("left", "right") for d in chosen), pols[0].decisions[0]
        assert all(d["arms"] == [d["a_arm"]["side"]] for d in chosen[1:])  # after the pre-approach: that arm only
        side, pre = chosen[0]["a_arm"]["side"], chosen[0]["heights"]
        assert pre[side].get("line")
        if overrides.get("contact_a_backoff"):  # the other arm backed off from its hand, as the expert's pusher
            other = next(a for a in pre if a != side)
            assert chosen[0]["arms"] == ["left", "right"] and "backoff" in pre[other], chosen[0]
        else:
            assert all(h.get("line") for h in pre.values())
    if overrides.get("contact_b_face"):  # B's touch was moved to the seen faces
        assert all("b_face" in h for h in touch[0]["heights"].values())
    if overrides.get("continue_level_squeeze"):  # C's squeeze continued from the hand, level
        squeeze = [d for d in pols[0].decisions[0] if d.get("primitive") == "squeeze" and d.get("arms")]
        assert squeeze and all(h == {"from_hand": True, "level": True} for h in squeeze[0]["heights"].values())
    if stalled:  # the second pass was decided (and, stalled or not, counted) from the object cloud
        assert any(d.get("pass") == 1 for d in pols[0].decisions[0]), pols[0].decisions[0]
    if overrides.get("continue_c_pinch_centre"):  # the straddle moved over the seen centre, the squeeze lengthened
        heights = [h for d in pols[0].decisions[0] for h in d.get("heights", {}).values()]
        assert any("pinch_centre" in h for h in heights) and any("squeeze_end" in h for h in heights), heights
    if c and overrides.get("contact") == "observed":  # the squeeze stretched to the seen centre, the pinch at the table
        assert any("squeeze" in h for d in posed for h in d["heights"].values())
        press = [d for d in posed if d["primitive"] == "press"]
        assert press, [d.get("primitive") for d in pols[0].decisions[0]]
        assert any(h["observed"][1] is not None for h in press[0]["heights"].values())


def _posed_stages(monkeypatch) -> list:
    """Every stage the unified state machine poses from now on, as ``(Primitive, its stage-log entry, the
    observation it was posed from)``, in order."""
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M

    posed, real = [], M._Episode._primitive

    def spy(self, obs):
        prim = real(self, obs)
        posed.append((prim, self.log[-1], obs))
        return prim

    monkeypatch.setattr(M._Episode, "_primitive", spy)
    return posed


@pytest.mark.parametrize("steady", [False, True])
def test_contact_b_steady_keeps_the_clamping_hands_orientation(tiny, monkeypatch, steady):
    """With contact_b_steady, B's squeeze and lift end in the orientation they start in, the commanded hand's
    (contact_from_hand); without it the tiny untrained executor's learned turn is applied."""
    posed = _posed_stages(monkeypatch)
    pol = _load(tiny["artifact"], strategy="B", contact="observed", contact_from_hand="true",
                contact_b_steady=str(steady).lower())  # fmt: skip
    _rollout([pol], steps=60)
    clamped = [p for p, _, _ in posed if p.name in ("squeeze", "lift")]
    assert [p.name for p in clamped] == ["squeeze", "lift"], [p.name for p, _, _ in posed]
    turns = [float(np.abs(m.end[1] - m.start[1]).max()) for p in clamped for m in p.motions.values()]
    if steady:
        assert max(turns) == 0.0
    else:
        assert max(turns) > 1e-3  # the learned change of orientation


@pytest.mark.parametrize("align", [False, True])
def test_contact_b_align_turns_the_touch_onto_the_seen_side(tiny, monkeypatch, align):
    """With contact_b_align, B's touch ends with its fingers along a side of the seen object's outline (the
    reference box), turned by the logged angle; without it the learned orientation stays."""
    from flatlab_lerobot.policies.unified.observed_contact import seen_sides

    posed = _posed_stages(monkeypatch)
    pol = _load(tiny["artifact"], strategy="B", contact="observed", contact_b_align=str(align).lower())
    _rollout([pol], steps=25)
    prim, log, obs = next(p for p in posed if p[0].name == "touch")
    sides = seen_sides(obs.object_points)
    for arm, m in prim.motions.items():
        y = m.end[1][:2, 1] / np.linalg.norm(m.end[1][:2, 1])
        along = max(abs(float(y @ s)) for s in sides)
        if align:
            assert along == pytest.approx(1.0, abs=1e-6) and "b_align_deg" in log["heights"][arm], log
        else:
            assert along < 1.0 - 1e-6 and "b_align_deg" not in log["heights"][arm]


B_RULES = {"contact": "observed", "contact_from_hand": "true", "contact_b_face": "true", "contact_b_steady": "true",
           "contact_b_align": "true", "contact_b_centred": "true"}


def test_contact_strategies_leaves_b_to_the_executor(tiny):
    """With contact_strategies=AC, B's stages are posed as with contact=learned (every action the same, no stage
    posed by a rule) although every B rule is switched on; with the default ABC the same rules change B's actions.
    A's stages are still posed by the rules (the touch's heights from the object cloud)."""
    learned = _load(tiny["artifact"], strategy="B")
    ac = _load(tiny["artifact"], strategy="B", contact_strategies="AC", **B_RULES)
    abc = _load(tiny["artifact"], strategy="B", **B_RULES)
    acts = _rollout([learned, ac, abc], steps=60)
    np.testing.assert_array_equal(acts[0], acts[1])
    assert not any("heights" in d for d in ac.decisions[0]) and ac.stage_indices[0] >= 2
    assert np.abs(acts[0] - acts[2]).max() > 1e-3  # the rules move B's hands
    a = _load(tiny["artifact"], strategy="A", contact_strategies="AC", contact="observed")
    _rollout([a], steps=30)
    touch = [d for d in a.decisions[0] if d.get("primitive") == "touch"]
    assert touch and all(h["observed"][1] is not None for h in touch[0]["heights"].values())
    with pytest.raises(ValueError, match="contact_strategies=AC needs --policy.contact=observed"):
        FlatLabUnifiedConfig(contact_strategies="AC")
    with pytest.raises(ValueError, match="--policy.contact_strategies: distinct letters"):
        FlatLabUnifiedConfig(contact="observed", contact_strategies="AA")


@pytest.mark.parametrize("closed", [False, True])
def test_contact_grip_closed_keeps_the_pinch_closed_through_the_lift(tiny, monkeypatch, closed):
    """With contact_grip_closed, C's pinching hand closes to 0 in the grasp and its lift holds 0, as the expert's;
    without it the tiny untrained executor's widths stay (not all 0)."""
    posed = _posed_stages(monkeypatch)
    pol = _load(tiny["artifact"], strategy="C", contact="observed", contact_grip_closed=str(closed).lower())
    _rollout([pol], steps=200)
    staged = {p.name: (p, log) for p, log, _ in posed if p.name in ("grasp", "lift")}
    assert set(staged) == {"grasp", "lift"}, [p.name for p, _, _ in posed]
    widths = []
    for name, (prim, log) in staged.items():
        pinch = [a for a, h in log["heights"].items() if h.get("closed")]
        if closed:
            assert len(pinch) == 1, log
            g = prim.motions[pinch[0]].gripper
            assert g[1] == 0.0 and (name == "grasp" or g[0] == 0.0)
        else:
            assert not pinch
        widths += [w for m in prim.motions.values() for w in (m.gripper if name == "lift" else m.gripper[1:])]
    if not closed:
        assert max(widths) > 0.0


@pytest.mark.parametrize("from_hand", [False, True, "learned", "learned_for_B_C", "learned_level_deeper"])
def test_contact_from_hand_moves_the_pressing_hand_only_along_its_motion(tiny, from_hand):
    """With contact_from_hand, A's press, slide and release start where the hand is: no joint-space transit
    ("move") runs between the touch and the end of the release, so nothing but the capped slide pushes the
    object.  The untrained tiny executor's learned starts lie elsewhere, so without it they do.  "learned":
    continue_from_hand, the same with every pose learned (contact=learned), for A; not when it names B and C only."""
    if from_hand == "learned":
        pol = _load(tiny["artifact"], strategy="A", continue_from_hand="A")
    elif from_hand == "learned_level_deeper":
        pol = _load(tiny["artifact"], strategy="A", continue_from_hand="A", continue_level_slide="true",
                    continue_press_deeper="0.004")
    elif from_hand == "learned_for_B_C":
        pol, from_hand = _load(tiny["artifact"], strategy="A", continue_from_hand="BC"), False
    else:
        pol = _load(tiny["artifact"], strategy="A", contact="observed", contact_from_hand=str(from_hand).lower())
    seq = _run_until_stage(pol, 3, 200)
    during = [stage for index, stage in seq if 1 <= index <= 3]  # press, slide, release of the first pass
    assert {"press", "slide", "release"} <= set(during), seq
    assert ("move" in during) is (not from_hand), during
    if from_hand == "learned":  # each moving arm of press, slide, release logged as started at the hand
        logged = [e for e in pol.decisions[0] if 1 <= e.get("index", -1) <= 3 and e.get("arms")]
        assert logged and all(e["heights"][a] == {"from_hand": True} for e in logged for a in e["arms"]), logged
    if from_hand == "learned_level_deeper":  # the slide kept level, the press 4 mm deeper, the release as learned
        want = {1: {"from_hand": True, "deeper": 0.004}, 2: {"from_hand": True, "level": True}, 3: {"from_hand": True}}
        logged = [e for e in pol.decisions[0] if 1 <= e.get("index", -1) <= 3 and e.get("arms")]
        assert {e["index"] for e in logged} == {1, 2, 3}, logged
        assert all(e["heights"][a] == want[e["index"]] for e in logged for a in e["arms"]), logged


def test_continue_level_squeeze_keeps_cs_continued_squeeze_at_the_hands_height(tiny):
    """continue_level_squeeze: C's squeeze, continued from the hand, is logged level (the learned descent dropped);
    the release after it continues from the hand as learned."""
    pol = _load(tiny["artifact"], strategy="C", continue_from_hand="C", continue_level_squeeze="true")
    seq = _run_until_stage(pol, 2, 200)
    assert {"squeeze", "release"} <= {stage for _, stage in seq}, seq
    logged = {e["index"]: e for e in pol.decisions[0] if e.get("arms") and e.get("index") in (1, 2)}
    assert logged[1]["primitive"] == "squeeze" and logged[2]["primitive"] == "release", logged
    assert all(logged[1]["heights"][a] == {"from_hand": True, "level": True} for a in logged[1]["arms"]), logged
    assert all(logged[2]["heights"][a] == {"from_hand": True} for a in logged[2]["arms"]), logged


@pytest.mark.parametrize("repeat", [False, True])
def test_continue_press_repeat_presses_later_passes_as_deep_as_the_first(tiny, monkeypatch, repeat):
    """continue_press_repeat: A's press of a later push pass ends no higher than the same arm's first press (the
    commanded end, world z); the amount it was lowered is logged.  Without it the learned height stands."""
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M

    posed = _posed_stages(monkeypatch)
    monkeypatch.setattr(M, "pass_needed", lambda missing: True)  # the untrained executor's push: every pass runs
    real_repeat = M._Episode._repeat_press

    def learned_higher(self, arm, p1, log):  # a later pass's press as if learned 2 cm above the first's (where the
        if self.index >= M.PASS_STAGES and arm in self.first_press_z:  # tiny executor's own ends is chance)
            p1[2] = self.first_press_z[arm] + 0.02
        real_repeat(self, arm, p1, log)

    monkeypatch.setattr(M._Episode, "_repeat_press", learned_higher)
    pol = _load(tiny["artifact"], strategy="A", continue_from_hand="A", continue_press_repeat=str(repeat).lower())
    _run_until_stage(pol, 5, 250)
    presses = [(log["index"], arm, float(prim.motions[arm].end[0][2]), log["heights"][arm])
               for prim, log, _ in posed if prim.name == "press" for arm in prim.motions]  # fmt: skip
    first = {arm: z for index, arm, z, _ in presses if index < M.PASS_STAGES}
    later = [(arm, z, h) for index, arm, z, h in presses if index >= M.PASS_STAGES and arm in first]
    assert first and later, presses
    for arm, z, h in later:
        if repeat:  # lowered to the first press, by the 2 cm it was above, and logged
            assert z == pytest.approx(first[arm]) and h.get("repeat") == pytest.approx(0.02), (z, first, h)
        else:
            assert "repeat" not in h
    with pytest.raises(ValueError, match="continue_press_repeat=true needs A"):
        FlatLabUnifiedConfig(continue_from_hand="C", continue_press_repeat=True)


@pytest.mark.parametrize("stalled", [0.0, 0.006])
def test_continue_press_stalled_presses_deeper_after_a_pass_that_moved_nothing(tiny, monkeypatch, stalled):
    """continue_press_stalled: a later push pass that finds the object cloud's missing overhang within 1 cm of what the
    previous pass found (its press slid over the object) presses that much deeper than the learned press (and
    continue_press_deeper), once more per such pass in a row; the log counts the stalled passes.  Without it, or
    when the object moved, the learned depth stands."""
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M

    posed = _posed_stages(monkeypatch)
    monkeypatch.setattr(M, "pass_needed", lambda missing: True)  # every pass runs
    monkeypatch.setattr(M, "object_footprint_x", lambda cloud: (0.10, 0.30))  # the object seen where it lay: stalled
    overrides = dict(strategy="A", continue_from_hand="A", continue_press_deeper=0.004)
    pol = _load(tiny["artifact"], **overrides, **({"continue_press_stalled": stalled} if stalled else {}))
    _run_until_stage(pol, 9, 300)
    presses = [(log["index"], log["heights"][arm]["deeper"]) for _, log, _ in posed if log.get("primitive") == "press"
               for arm in log["arms"]]  # fmt: skip
    passes = [log for log in pol._episodes[0].log if "pass" in log]
    assert {i for i, _ in presses} == {1, 5, 9} and len(passes) == 2, (presses, passes)
    for index, deeper in presses:
        k = index // M.PASS_STAGES  # passes in a row that moved nothing before this one
        assert deeper == pytest.approx(0.004 + k * stalled), (index, deeper)
    assert [log.get("stalled") for log in passes] == [1, 2]  # counted (and logged) with the switch off too

    # moved: the count starts again
    from flatlab_lerobot.sim.scene import CellConfig

    ep = M._Episode(pol, None, "A")
    monkeypatch.setattr(M, "object_footprint_x", lambda cloud: (float(cloud[:, 0].max()), 0.2))
    obs = lambda x1: M.Observed(np.zeros(16), np.asarray(CellConfig().calibration()), np.zeros((N, 3)),  # noqa: E731
                                _cloud_x(x1 - 0.2, x1))
    for index, x1, want in [(0, 0.0, 0), (4, 0.005, 1), (8, 0.10, 0)]:
        ep.index = index
        ep._skip_pass(obs(x1))
        assert ep.stalled == want, (index, x1, ep.stalled)
    with pytest.raises(ValueError, match="continue_press_stalled needs A"):
        FlatLabUnifiedConfig(continue_from_hand="C", continue_press_stalled=0.006)
    with pytest.raises(ValueError, match="continue_press_stalled: must be in"):
        FlatLabUnifiedConfig(continue_from_hand="A", continue_press_stalled=0.05)


@pytest.mark.parametrize("as_first", [False, True])
def test_a_passes_as_first_poses_later_passes_with_the_first_pass_stages(tiny, monkeypatch, as_first):
    """a_passes_as_first: the executor poses stage k of A's later push pass p as stage k - 4p of the first pass (same
    primitive), from the observation of that stage's start; the log says so.  Without it each stage is its own."""
    from flatlab_lerobot.policies.executor.modeling_flatlab_executor import FlatLabExecutorPolicy
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M

    posed, asked, real = _posed_stages(monkeypatch), [], FlatLabExecutorPolicy.predict_poses

    def spy(self, cloud, strategy, stage_index, primitive, *args, **kwargs):
        asked.append((int(stage_index), primitive))
        return real(self, cloud, strategy, stage_index, primitive, *args, **kwargs)

    monkeypatch.setattr(FlatLabExecutorPolicy, "predict_poses", spy)
    monkeypatch.setattr(M, "pass_needed", lambda missing: True)  # the untrained executor's push: every pass runs
    pol = _load(tiny["artifact"], strategy="A", a_passes_as_first=str(as_first).lower())
    _run_until_stage(pol, 5, 250)
    logs = [log for _, log, _ in posed]
    assert [log["index"] for log in logs][:6] == list(range(6)), logs
    for (k, primitive), log in zip(asked, logs):
        i = log["index"]
        want = i % M.PASS_STAGES if as_first and i < M.A_PASSES * M.PASS_STAGES else i
        assert (k, primitive) == (want, log["primitive"]) and log.get("posed_as", i) == want, (k, primitive, log)
    assert any("posed_as" in log for log in logs) == as_first


@pytest.mark.parametrize("mode", ["", "press", "all"])
def test_continue_c_heights_sets_c_heights_from_the_observed_table(tiny, monkeypatch, mode):
    """continue_c_heights: C's touch ends, and its squeeze (continued from the hand) ends, at the expert's pressing
    height above the table top of observation.cell; with "all" the pinching hand's straddle and grasp end at the
    expert's pinching height too.  Without the switch the learned heights stand."""
    from flatlab_lerobot.strategies.c_fold_pinch import pinch_tcp_z, press_tcp_z

    posed = _posed_stages(monkeypatch)
    pol = _load(tiny["artifact"], strategy="C", continue_from_hand="C", continue_c_heights=mode)
    _run_until_stage(pol, 6, 300)
    assert {"touch", "squeeze", "press", "grasp"} <= {log["primitive"] for _, log, _ in posed}, posed
    set_by_rule = collections.Counter()
    for prim, log, obs in posed:
        table = float(obs.cell[0])
        want = {"touch": press_tcp_z(table), "squeeze": press_tcp_z(table), "press": pinch_tcp_z(table),
                "grasp": pinch_tcp_z(table)}.get(prim.name)
        for arm, motion in prim.motions.items():
            ruled = "rule_heights" in log.get("heights", {}).get(arm, {})
            set_by_rule[prim.name] += ruled
            if ruled:
                assert float(motion.end[0][2]) == pytest.approx(want, abs=1e-9), (prim.name, arm, log)
            elif want is not None and prim.name in ("touch", "squeeze"):  # the learned end: not the rule's height
                assert abs(float(motion.end[0][2]) - want) > 1e-5, (prim.name, arm, log)
    ruled_stages = {name for name, n in set_by_rule.items() if n}
    assert ruled_stages == {"": set(), "press": {"touch", "squeeze"}, "all": {"touch", "squeeze", "press", "grasp"}}[mode]
    with pytest.raises(ValueError, match="continue_c_heights needs C"):
        FlatLabUnifiedConfig(continue_from_hand="A", continue_c_heights="press")
    with pytest.raises(ValueError, match="continue_c_heights: one of"):
        FlatLabUnifiedConfig(continue_from_hand="C", continue_c_heights="pinch")


@pytest.mark.parametrize("on", [False, True])
def test_continue_a_grasp_heights_sets_the_approach_and_grasp_from_the_seen_overhang(tiny, monkeypatch, on):
    """continue_a_grasp_heights: A's approach (its grasp-side 'touch') and grasp end at the height contact=observed's A
    rule gives for the object cloud they were posed from (the seen overhang's mid height); the lift keeps its learned
    rise; the push passes are not touched, and without the switch the rule is never asked."""
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M

    posed, asked, real = _posed_stages(monkeypatch), [], M.contact_heights

    def rule(strategy, index, primitive, points, xy, table, edge_x, pinching=True):
        asked.append((strategy, index, primitive))
        return (0.9, 0.9) if strategy == "A" and primitive in ("touch", "grasp") else real(
            strategy, index, primitive, points, xy, table, edge_x, pinching=pinching)

    monkeypatch.setattr(M, "pass_needed", lambda missing: False)  # one push pass, then the grasp
    monkeypatch.setattr(M, "contact_heights", rule)
    pol = _load(tiny["artifact"], strategy="A", continue_from_hand="A", continue_a_grasp_heights=str(on).lower())
    _run_until_stage(pol, M.A_PREAPPROACH + 3, 400)
    late = [(prim, log) for prim, log, _ in posed if log["index"] >= M.A_PREAPPROACH + 1 and prim.motions]
    assert {log["primitive"] for _, log in late} >= {"touch", "grasp", "lift"}, late
    assert all(i >= M.A_PREAPPROACH for _, i, _ in asked), asked
    assert bool(asked) == on, asked
    for prim, log in late:
        for arm, motion in prim.motions.items():
            if on and prim.name in ("touch", "grasp"):
                assert motion.end[0][2] == pytest.approx(0.9) and log["heights"][arm]["rule_heights"][1] == 0.9, log
                if prim.name == "touch":  # not started at the hand: the whole approach at that height
                    assert motion.start[0][2] == pytest.approx(0.9), log
            else:
                assert motion.end[0][2] != pytest.approx(0.9), (prim.name, log)
    with pytest.raises(ValueError, match="continue_a_grasp_heights=true needs A"):
        FlatLabUnifiedConfig(continue_from_hand="C", continue_a_grasp_heights=True)


@pytest.mark.parametrize("on", [False, True])
def test_continue_a_preapproach_line_moves_from_the_hand_in_a_straight_line(tiny, monkeypatch, on):
    """continue_a_preapproach_line: A's pre-approach starts exactly at each commanded hand (position and orientation,
    so the runner makes no joint-space transit) and ends at the learned pose, over the stage's transit time; without
    the switch it starts at the learned pose (the runner's transit gets there)."""
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M

    posed, real = [], M._Episode._primitive

    def spy(self, obs):  # the primitive, its log entry and the commanded hands as it was posed
        hands = self.expert.fk(self.q)
        prim = real(self, obs)
        posed.append((prim, self.log[-1], hands))
        return prim

    monkeypatch.setattr(M._Episode, "_primitive", spy)
    monkeypatch.setattr(M, "pass_needed", lambda missing: False)  # one push pass, then the grasp
    pol = _load(tiny["artifact"], strategy="A", continue_from_hand="A", continue_a_preapproach_line=str(on).lower())
    _run_until_stage(pol, M.A_PREAPPROACH + 1, 400)
    pre = [(prim, log, hands) for prim, log, hands in posed if log["index"] == M.A_PREAPPROACH and prim.motions]
    assert len(pre) == 1, [log for _, log, _ in posed]
    prim, log, hands = pre[0]
    spec = M.STAGE_SPECS["A"][M.A_PREAPPROACH]
    for arm, motion in prim.motions.items():
        at_hand = np.allclose(motion.start[0], hands[arm][0]) and np.allclose(motion.start[1], hands[arm][1])
        assert at_hand == on, (arm, motion.start, hands[arm])
        assert (log.get("heights", {}).get(arm) == {"line": True}) == on, log
    assert (prim.duration == pytest.approx(spec.transit)) == on, prim.duration
    with pytest.raises(ValueError, match="continue_a_preapproach_line=true needs A"):
        FlatLabUnifiedConfig(continue_from_hand="C", continue_a_preapproach_line=True)


@pytest.mark.parametrize("on", [False, True])
def test_continue_a_sheet_lift_raises_a_continued_lift_by_the_sheet_rule(tiny, monkeypatch, on):
    """continue_a_sheet_lift: A's lift, continued from the hand, ends where the sheet rule (sheet_lift_end, on the object
    cloud and cell the lift was posed from) puts it; only the lift asks the rule, and without the switch nothing does."""
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M

    posed, calls = _posed_stages(monkeypatch), []

    def rule(p0, p1, points, table, edge_x):  # a sheet seen: rise 30 cm more than learned
        calls.append(np.array(p1, float))
        return np.asarray(p1, float) + [0.0, 0.0, 0.3], {"droop": 0.05, "rise": 0.3}

    monkeypatch.setattr(M, "pass_needed", lambda missing: False)  # one push pass, then the grasp
    monkeypatch.setattr(M, "sheet_lift_end", rule)
    pol = _load(tiny["artifact"], strategy="A", continue_from_hand="A", continue_a_sheet_lift=str(on).lower())
    _run_until_stage(pol, M.A_PREAPPROACH + 3, 400)
    lifts = [(prim.motions[arm], log["heights"][arm]) for prim, log, _ in posed if prim.name == "lift" for arm in prim.motions]
    assert lifts, [log["primitive"] for _, log, _ in posed]
    assert len(calls) == (len(lifts) if on else 0), (calls, lifts)
    for (motion, h), learned in zip(lifts, calls):
        assert np.allclose(motion.end[0], learned + [0.0, 0.0, 0.3]) and h["sheet_lift"]["rise"] == 0.3, (motion, h)
    with pytest.raises(ValueError, match="continue_a_sheet_lift=true needs A"):
        FlatLabUnifiedConfig(continue_from_hand="C", continue_a_sheet_lift=True)


@pytest.mark.parametrize("cap", [False, True])
def test_continue_slide_cap_stops_a_slide_at_the_seen_missing_overhang(tiny, monkeypatch, cap):
    """continue_slide_cap: A's slide continued from the hand advances along +x no further than the expert's
    slide_distance for the overhang still missing on the object cloud it was posed from (logged: how much shorter
    than learned).  The tiny untrained executor's slide is made to run 60 cm along +x, past any cap; without the
    switch that learned slide stands."""
    from flatlab_lerobot.policies.executor.modeling_flatlab_executor import FlatLabExecutorPolicy
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M
    from flatlab_lerobot.policies.unified.observed_contact import slide_cap

    posed, caps, real = _posed_stages(monkeypatch), [], FlatLabExecutorPolicy.predict_poses

    def long_slide(self, *args, **kwargs):
        out = real(self, *args, **kwargs)
        if args[3] == "slide":
            for pose in out.values():
                pose["end"] = (pose["start"][0] + np.array([0.6, 0.0, 0.0], np.float32), pose["end"][1])
        return out

    monkeypatch.setattr(FlatLabExecutorPolicy, "predict_poses", long_slide)
    monkeypatch.setattr(M, "slide_cap", lambda pts, edge_x: caps.append(slide_cap(pts, edge_x)) or caps[-1])
    pol = _load(tiny["artifact"], strategy="A", continue_from_hand="A", continue_slide_cap=str(cap).lower())
    _run_until_stage(pol, 2, 120)
    slides = [(prim.motions[arm], log["heights"][arm]) for prim, log, _ in posed if prim.name == "slide"
              for arm in prim.motions]  # fmt: skip
    assert slides and len(caps) == (len(slides) if cap else 0), (slides, caps)
    for (motion, h), c in zip(slides, caps if cap else [None] * len(slides)):
        advance = float(motion.end[0][0] - motion.start[0][0])
        if cap:
            assert c is not None and 0.0 <= advance <= c + 1e-6 < 0.6, (advance, c, h)
            assert h["cap"] == pytest.approx(0.6 - advance, abs=1e-4), h
        else:
            assert advance == pytest.approx(0.6, abs=1e-4) and "cap" not in h, (advance, h)
    with pytest.raises(ValueError, match="continue_slide_cap=true needs A"):
        FlatLabUnifiedConfig(continue_from_hand="C", continue_slide_cap=True)


@pytest.mark.parametrize("on", [False, True])
def test_continue_c_squeeze_end_ends_cs_squeeze_short_of_the_seen_centre(tiny, monkeypatch, on):
    """continue_c_squeeze_end: C's squeeze, continued from the hand, keeps its learned direction and ends 2.5 cm short
    of the seen cloth's centre (observed_contact.squeeze_end on the object cloud it was posed from; logged: how far
    the end moved).  The tiny executor's touch is made to end 8 cm either side of the seen centre and its squeeze to
    move each hand 1 cm towards it, so the rule lengthens it; without the switch it stands."""
    from flatlab_lerobot.policies.executor.modeling_flatlab_executor import FlatLabExecutorPolicy
    from flatlab_lerobot.policies import seen_points
    from flatlab_lerobot.policies.unified.observed_contact import C_END_HALF_GAP, seen_centre

    posed, real = _posed_stages(monkeypatch), FlatLabExecutorPolicy.predict_poses

    dirs = {}  # per arm, the direction of its learned squeeze

    def short_squeeze(self, *args, **kwargs):
        out = real(self, *args, **kwargs)
        centre = seen_centre(seen_points(kwargs["object_cloud"]))
        if args[3] == "touch":  # both hands come down 8 cm either side of the seen centre
            for arm, pose in out.items():
                end = np.r_[centre + [0.0, 0.08 if arm == "left" else -0.08], 0.80].astype(np.float32)[None]
                pose["start"], pose["end"] = (end + [0.0, 0.0, 0.05], pose["start"][1]), (end, pose["end"][1])
                pose["active"] = np.ones_like(pose["active"])
        if args[3] == "squeeze":
            for arm, pose in out.items():
                dirs[arm] = np.array([0.0, -1.0 if arm == "left" else 1.0])  # from its side towards the centre
                pose["end"] = (pose["start"][0] + np.r_[0.01 * dirs[arm], 0.0].astype(np.float32), pose["end"][1])
        return out

    monkeypatch.setattr(FlatLabExecutorPolicy, "predict_poses", short_squeeze)
    pol = _load(tiny["artifact"], strategy="C", continue_from_hand="C", continue_c_squeeze_end=str(on).lower())
    _run_until_stage(pol, 1, 120)
    squeezes = [(arm, prim.motions[arm], log["heights"][arm], obs) for prim, log, obs in posed if prim.name == "squeeze"
                for arm in prim.motions]  # fmt: skip
    assert squeezes, posed
    for arm, motion, h, obs in squeezes:
        p0, p1, d = motion.start[0], motion.end[0], dirs[arm]
        along = float((p1[:2] - p0[:2]) @ d)
        assert np.allclose(p1[:2] - p0[:2], along * d, atol=1e-5), (p0, p1, d)  # along its own direction only
        if on:  # to 2.5 cm short of the seen centre (never behind its start)
            want = float((seen_centre(obs.object_points) - p0[:2]) @ d) - C_END_HALF_GAP
            assert want > 0.02 and along == pytest.approx(want, abs=1e-4), (arm, along, want)  # longer than learned
            assert h["squeeze_end"] == pytest.approx(want - 0.01, abs=1e-4), h
        else:
            assert along == pytest.approx(0.01, abs=1e-4) and "squeeze_end" not in h, (along, h)
    with pytest.raises(ValueError, match="continue_c_squeeze_end=true needs C"):
        FlatLabUnifiedConfig(continue_from_hand="A", continue_c_squeeze_end=True)


@pytest.mark.parametrize("on", [False, True])
def test_continue_c_pinch_centre_straddles_the_seen_cloths_centre(tiny, monkeypatch, on):
    """continue_c_pinch_centre: C's straddle (the press of the arm whose learned gripper closes most) is the learned
    motion shifted to start over the seen cloth's centre, on the object cloud it was posed from (its heights kept;
    logged: how far it moved); the other arm's motion and every other stage stay learned.  Without it the learned
    straddle stands."""
    from flatlab_lerobot.policies.unified.observed_contact import seen_centre

    posed = _posed_stages(monkeypatch)
    pol = _load(tiny["artifact"], strategy="C", continue_c_pinch_centre=str(on).lower())
    _run_until_stage(pol, 5, 300)
    straddle = [(prim, log, obs) for prim, log, obs in posed if log["index"] == 5]
    assert straddle and straddle[0][0].name == "press", posed
    prim, log, obs = straddle[0]
    shifted = {a: h for a, h in log.get("heights", {}).items() if "pinch_centre" in h}
    if on:
        assert len(shifted) == 1, log  # the pinching hand only
        (arm, h), = shifted.items()
        start = prim.motions[arm].start[0]
        assert np.allclose(start[:2], seen_centre(obs.object_points), atol=1e-6), (start, obs.object_points.mean(0))
        assert h["pinch_centre"] > 0.0, h
    else:
        assert not shifted, log
    assert all("pinch_centre" not in h for _, lg, _ in posed if lg["index"] != 5 for h in lg.get("heights", {}).values())


def test_each_stage_is_posed_from_the_observation_of_its_start(tiny):
    """The executor is called once per stage, with the scene and object clouds observed when the stage
    starts, (strategy, stage index, the stage's primitive name) and the TCP poses of the observed
    joints (= the env's measured ee_pose)."""
    pol = _load(tiny["artifact"], strategy="B")
    calls = []
    orig = pol.executor.predict_poses

    def spy(cloud, strategy, index, primitive, proprio, object_cloud=None, tta=None, members=()):
        calls.append({"cloud": np.array(cloud), "obj": np.array(object_cloud), "strategy": strategy, "index": index,
                      "primitive": primitive, "proprio": np.array(proprio), "tta": tta, "members": members})  # fmt: skip
        return orig(cloud, strategy, index, primitive, proprio, object_cloud=object_cloud, tta=tta, members=members)

    pol.executor.predict_poses = spy
    env = _env()
    obs, _ = env.reset(seed=1)
    pol.reset()
    for _ in range(30):
        n = len(calls)
        action = pol.select_action(_batch(obs))[0].numpy()
        if len(calls) > n:
            c = calls[-1]
            np.testing.assert_array_equal(c["cloud"], obs["pointcloud"].astype(np.float64))
            np.testing.assert_array_equal(c["obj"], obs["object_pointcloud"].astype(np.float64))
            ee = obs["ee_pose"].reshape(2, 7)
            tcp = c["proprio"].reshape(2, 8)
            # (ee_pose is the TCP site from the last physics substep's kinematics: up to ~1 mm behind the
            # joints while an arm moves; at rest they agree to float precision)
            tol = 1e-4 if len(calls) == 1 else 3e-3
            np.testing.assert_allclose(tcp[:, :3], ee[:, :3], atol=tol)
            dots = np.abs((tcp[:, 3:7] * ee[:, 3:7]).sum(1))
            np.testing.assert_allclose(dots, 1.0, atol=tol)  # same rotation (q or -q)
            np.testing.assert_allclose(tcp[:, 7], obs["agent_pos"][[7, 15]], atol=1e-6)
        obs, *_ = env.step(action)
    env.close()
    assert [c["index"] for c in calls] == list(range(len(calls))) and len(calls) >= 2
    assert all(c["strategy"] == "B" and c["primitive"] == STAGE_SPECS["B"][c["index"]].primitive for c in calls)
    assert all(c["tta"] is None for c in calls)  # executor_tta=0: the executor's own config (1 pass)
    assert all(c["members"] == () for c in calls)  # one executor, no ensemble


def test_executor_tta_reaches_every_stage_call(tiny):
    pol = _load(tiny["artifact"], strategy="B", executor_tta=3)
    seen = []
    orig = pol.executor.predict_world
    pol.executor.predict_world = lambda batch, tta=None: (seen.append(tta), orig(batch, tta))[1]
    _rollout([pol], steps=20)
    assert seen and all(t == 3 for t in seen)


def test_generator_tta_reaches_the_strategy_choice_and_leaves_the_generator_config(tiny):
    pol = _load(tiny["artifact"], generator_tta=4)
    seen = []
    orig = pol.generator.predict_logits
    pol.generator.predict_logits = lambda batch, tta=None: (seen.append(tta), orig(batch, tta))[1]
    _rollout([pol], steps=2)
    assert seen == [4] and pol.generator.config.tta == 1  # passed per call; the generator's own value untouched


def test_generator_reads_each_seen_object_point_once(tiny):
    """The env pads an object cloud it sees fewer points of by repeating them (zeros: unseen).  The generator
    gets the distinct seen points: FPS of the padded cloud once took every distinct point and then copies of
    one of them, which moved the cloud's mean (the generator's centre; Train S 73 % against 97 %)."""
    pol = _load(tiny["artifact"], generator_cloud_points=48)
    fed = []
    orig = pol.generator.predict_logits
    pol.generator.predict_logits = lambda batch, tta=None: (fed.append(next(iter(batch.values()))[0]), orig(batch, tta))[1]
    rng = np.random.default_rng(0)
    few = rng.normal(size=(20, 3)) * [0.1, 0.1, 0.01] + [0.0, 0.0, 0.76]
    order = rng.permutation(20)
    padded = np.r_[few[np.resize(order, 300)], np.zeros((12, 3))]  # as sim.cameras.sample pads
    assert pol.choose_strategy(padded) == pol.choose_strategy(few[order])  # the distinct points, in cloud order
    assert torch.equal(fed[0], fed[1]) and fed[0].shape == (20, 3)
    many = rng.normal(size=(200, 3))  # more distinct points than generator_cloud_points: FPS of the distinct ones
    pol.choose_strategy(np.r_[many, many, np.zeros((5, 3))])
    assert fed[2].shape == (48, 3) and len(torch.unique(fed[2], dim=0)) == 48 and (fed[2].abs().sum(1) > 0).all()


def test_first_observation_script_gives_the_strategy_the_episode_chooses(tiny, tmp_path, monkeypatch):
    """scripts/generator_first_obs.py (column S without running the episodes) resets the env as the trial with
    that seed does and asks the policy's own rank_strategies: the episode's choice, seed by seed."""
    sys.path.insert(0, str(Path(__file__).parents[1] / "scripts"))
    import generator_first_obs

    seen = []
    orig = FlatLabUnifiedPolicy.rank_strategies
    monkeypatch.setattr(FlatLabUnifiedPolicy, "rank_strategies", lambda self, c: (seen.append(np.array(c)), orig(self, c))[1])
    out = tmp_path / "first.json"
    args = ["--policy", str(tiny["artifact"]), "--objects", OBJECT, "--seeds", "0-2", "--image-size", "32",
            "--n-points", str(N), "--n-object-points", str(K), "--out", str(out)]  # fmt: skip
    assert generator_first_obs.main(args) == 0
    choices = json.loads(out.read_text())["choices"]
    assert [r["seed"] for r in choices] == [0, 1, 2] and len(seen) == 3
    pol = _load(tiny["artifact"])
    for i, row in enumerate(choices):
        _rollout([pol], steps=1, seed=row["seed"])
        assert row["strategy"] == pol.strategies[0] and np.array_equal(seen[3 + i], seen[i])  # the same cloud
    assert not np.array_equal(seen[0], seen[1])  # another seed, another placement
    assert all(sorted(r["ranked"]) == ["A", "B", "C"] and r["ranked"][0] == r["strategy"] and r["seen_width_m"] > 0.05
               for r in choices)  # the whole ranking, and the width b_min_width reads
    # --policy-arg reaches the policy's config: b_min_width wider than the object puts B last
    wide = tmp_path / "wide.json"
    assert generator_first_obs.main([*args[:-1], str(wide), "--policy-arg", "b_min_width=0.3"]) == 0
    assert all(r["ranked"][-1] == "B" for r in json.loads(wide.read_text())["choices"])
    with pytest.raises(SystemExit, match="--policy-arg b_min_width=-1"):
        generator_first_obs.main([*args, "--policy-arg", "b_min_width=-1"])
    seen.clear()
    with pytest.raises(SystemExit, match="--splits"):
        generator_first_obs.main(["--policy", str(tiny["artifact"]), "--splits", "nope"])
    # the generator alone (its flatlab_strategy folder) is read as the artifact reads it: the same clouds, point
    # count and passes reach FlatLabStrategyPolicy.rank_cloud, and the same choices come out
    calls = []
    orig_rank = FlatLabStrategyPolicy.rank_cloud
    monkeypatch.setattr(FlatLabStrategyPolicy, "rank_cloud", lambda self, c, n=2048, tta=None: (calls.append((np.array(c), n, tta)), orig_rank(self, c, n, tta))[1])
    assert generator_first_obs.main(args) == 0
    gen_out = tmp_path / "gen.json"
    args[1], args[-1] = str(tiny["generator"]), str(gen_out)
    assert generator_first_obs.main(args + ["--generator-cloud-points", str(pol.config.generator_cloud_points)]) == 0
    assert len(calls) == 6 and all(np.array_equal(calls[i][0], calls[3 + i][0]) and calls[i][1:] == calls[3 + i][1:] for i in range(3))
    assert [r["strategy"] for r in json.loads(gen_out.read_text())["choices"]] == [r["strategy"] for r in choices]
    with pytest.raises(SystemExit, match="want 'flatlab_unified' or 'flatlab_strategy'"):
        generator_first_obs.main(["--policy", str(tiny["executor"])])


@pytest.mark.parametrize("strategy", ["A", "B"])
def test_fixed_strategy_is_the_learned_slide_or_lift_baseline(tiny, tmp_path, strategy):
    pol = _load(tiny["artifact"], strategy=strategy)
    _rollout([pol], steps=3)
    assert pol.strategies == [strategy] and pol.stage_indices == [0]
    # ... and the builder writes it into the artifact
    out = tmp_path / strategy
    unified_build.build(tiny["generator"], tiny["executor"], out, strategy=strategy, allow_unverified=True,
                        log=lambda *a: None)  # fmt: skip
    assert PreTrainedConfig.from_pretrained(out).strategy == strategy


def test_alt_executor_poses_its_strategies_and_the_executor_the_others(tiny, tmp_path):
    """``unified-build --alt-executor X --alt-strategies A,C``: X's weights under ``alt_executor.*``, reloaded;
    X poses every stage of A and C, the first executor every stage of B; bad flag values are refused."""
    from safetensors.torch import load_file

    torch.manual_seed(1)
    alt_dir = tmp_path / "alt_ex"
    FlatLabExecutorPolicy(PreTrainedConfig.from_pretrained(tiny["executor"])).save_pretrained(alt_dir)  # new weights
    out = tmp_path / "two"
    rec = unified_build.build(tiny["generator"], tiny["executor"], out, allow_unverified=True, alt_executor=alt_dir,
                              alt_strategies=["A", "C"], log=lambda *a: None)  # fmt: skip
    assert rec["alt_strategies"] == ["A", "C"] and "alt_executor" in rec["train_only_check"]
    weights, own = load_file(str(out / "model.safetensors")), load_file(str(alt_dir / "model.safetensors"))
    first = load_file(str(tiny["executor"] / "model.safetensors"))
    assert any(not torch.equal(v, first[k]) for k, v in own.items())  # a different executor
    for k, v in own.items():
        torch.testing.assert_close(weights[f"alt_executor.{k}"], v, atol=0, rtol=0)
    for strategy, used in (("A", "alt_executor"), ("B", "executor"), ("C", "alt_executor")):
        pol = _load(out, strategy=strategy)
        calls = {"executor": 0, "alt_executor": 0}
        for name in calls:
            sub = getattr(pol, name)
            sub.predict_poses = (lambda f, n: lambda *a, **kw: (calls.__setitem__(n, calls[n] + 1), f(*a, **kw))[1])(
                sub.predict_poses, name)
        _rollout([pol], steps=3)
        assert calls[used] >= 1 and sum(calls.values()) == calls[used], (strategy, calls)
    with pytest.raises(unified_build.UnifiedBuildError, match="--alt-strategies"):
        unified_build.build(tiny["generator"], tiny["executor"], tmp_path / "x", allow_unverified=True,
                            alt_executor=alt_dir, alt_strategies=["D"], log=lambda *a: None)  # fmt: skip
    with pytest.raises(unified_build.UnifiedBuildError, match="give both"):
        unified_build.build(tiny["generator"], tiny["executor"], tmp_path / "y", allow_unverified=True,
                            alt_executor=alt_dir, log=lambda *a: None)  # fmt: skip
    with pytest.raises(ValueError, match="alt_executor_strategies"):
        FlatLabUnifiedConfig(alt_executor_strategies=["A"])  # no alt_executor
    # alt_executor_stages=push: the second executor poses A's push passes, the first A's grasp stages
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M

    pol = _load(out, strategy="A", alt_executor_stages="push")
    posers = [pol.executor_for("A", i)[0] for i in range(len(STRATEGIES["A"]))]
    assert all(p is pol.alt_executor for p in posers[:M.A_PREAPPROACH])
    assert posers[M.A_PREAPPROACH:] and all(p is pol.executor for p in posers[M.A_PREAPPROACH:])
    assert all(pol.executor_for("C", i)[0] is pol.alt_executor for i in range(len(STRATEGIES["C"])))  # C: all stages
    with pytest.raises(ValueError, match="alt_executor_stages"):
        FlatLabUnifiedConfig(alt_executor=C.FlatLabExecutorConfig(), alt_executor_strategies=["A"], alt_executor_stages="grasp")
    with pytest.raises(ValueError, match="alt_executor_stages=push"):
        FlatLabUnifiedConfig(alt_executor=C.FlatLabExecutorConfig(), alt_executor_strategies=["C"], alt_executor_stages="push")


def test_executor_ensemble_poses_each_stage_by_the_mean_of_its_members(tiny, tmp_path):
    """``unified-build --executor X Y``: Y's weights under ``executor_members.0.*``, the list of nested configs
    reloads from config.json, every stage's poses are the mean of X's and Y's predictions (quaternions
    sign-aligned), and a member that reads other inputs is refused naming the flag and field."""
    from safetensors.torch import load_file

    from flatlab_lerobot.policies.executor.modeling_flatlab_executor import mean_predictions

    torch.manual_seed(2)
    member = tmp_path / "member"
    FlatLabExecutorPolicy(PreTrainedConfig.from_pretrained(tiny["executor"])).save_pretrained(member)  # other weights
    out = tmp_path / "ens"
    rec = unified_build.build(tiny["generator"], [tiny["executor"], member], out, allow_unverified=True,
                              log=lambda *a: None)  # fmt: skip
    assert "executor_members.0" in rec["train_only_check"] and rec["executor_members.0"] == str(member.resolve())
    weights, own = load_file(str(out / "model.safetensors")), load_file(str(member / "model.safetensors"))
    for k, v in own.items():
        torch.testing.assert_close(weights[f"executor_members.0.{k}"], v, atol=0, rtol=0)
    pol = _load(out, strategy="B")
    assert len(pol.executor_members) == 1 and pol.executor_for("B", 0) == (pol.executor, (pol.executor_members[0],))
    assert pol.executor_for("A", 0)[1] == (pol.executor_members[0],)  # no alt_executor: the ensemble poses every strategy
    env = _env()
    obs, _ = env.reset(seed=0)
    env.close()
    o = pol.observed(_batch(obs))[0]
    proprio = np.zeros(C.TCP_STATE_DIM, np.float32)
    args = (o.cloud, "B", 0, STAGE_SPECS["B"][0].primitive, proprio)
    single = pol.executor.predict_poses(*args, object_cloud=o.object_cloud)
    both = pol.executor.predict_poses(*args, object_cloud=o.object_cloud, members=(pol.executor_members[0],))
    other = pol.executor_members[0].predict_poses(*args, object_cloud=o.object_cloud)
    for arm in single:
        p_single, p_other, p_both = single[arm]["start"][0], other[arm]["start"][0], both[arm]["start"][0]
        assert not np.allclose(p_single, p_other)
        np.testing.assert_allclose(p_both, (p_single + p_other) / 2, atol=1e-5)
        np.testing.assert_allclose(both[arm]["active"], (single[arm]["active"] + other[arm]["active"]) / 2, atol=1e-6)
    # the policy's stages go through the member too
    seen = []
    orig = pol.executor_members[0].predict_world
    pol.executor_members[0].predict_world = lambda batch, tta=None: (seen.append(tta), orig(batch, tta))[1]
    _rollout([pol], steps=3)
    assert seen
    # quaternions: q and -q are one rotation, so their mean is q
    q = torch.tensor([[0.0, 0.6, 0.0, 0.8]])
    a = [{"start_quat": q, "start_pos": torch.zeros(1, 3)}]
    b = [{"start_quat": -q, "start_pos": torch.ones(1, 3)}]
    m = mean_predictions([a, b])[0]
    torch.testing.assert_close(m["start_quat"] * torch.sign(m["start_quat"][:, 1:2]), q)
    torch.testing.assert_close(m["start_pos"], torch.full((1, 3), 0.5))
    # a member that reads other inputs
    cfg = PreTrainedConfig.from_pretrained(tiny["executor"])
    cfg.use_proprio = False
    odd = tmp_path / "odd"
    FlatLabExecutorPolicy(cfg).save_pretrained(odd)
    with pytest.raises(unified_build.UnifiedBuildError, match="--executor .*use_proprio"):
        unified_build.build(tiny["generator"], [tiny["executor"], odd], tmp_path / "z", allow_unverified=True,
                            log=lambda *a: None)  # fmt: skip
    with pytest.raises(ValueError, match="alt_executor_members"):
        FlatLabUnifiedConfig(alt_executor_members=[cfg])  # no alt_executor


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="strategy"):
        FlatLabUnifiedConfig(strategy="D")
    with pytest.raises(ValueError, match="max_push_passes"):
        FlatLabUnifiedConfig(max_push_passes=4)
    with pytest.raises(ValueError, match="--policy.executor_tta"):
        FlatLabUnifiedConfig(executor_tta=-1)
    with pytest.raises(ValueError, match="--policy.generator_tta"):
        FlatLabUnifiedConfig(generator_tta=65)
    with pytest.raises(ValueError, match="--policy.b_min_width"):
        FlatLabUnifiedConfig(b_min_width=-0.01)
    with pytest.raises(ValueError, match="input_key"):
        FlatLabUnifiedConfig(generator=FlatLabStrategyConfig(input_key="observation.scene_pointcloud"))


# ------------------------------------------------------------------------------ decisions
def _cloud_x(x0, x1, y=0.0, z=0.77, n=K):
    pts = np.zeros((n, 3))
    pts[:, 0] = np.linspace(x0, x1, n)
    pts[:, 1], pts[:, 2] = y, z
    return pts


@pytest.mark.parametrize("x0,x1,max_passes,skip", [
    (-0.10, 0.20, 3, False),  # far from the edge (0.3 m): another pass
    (0.10, 0.39, 3, True),  # overhangs 9 cm >= min(8.5 cm, 0.4 * 29 cm): skipped
    (0.10, 0.378, 3, True),  # 7.8 cm: within 1 cm of the 8.5-cm target: skipped
    (0.10, 0.36, 3, False),  # 6 cm: 2.5 cm short: another pass
    (-0.10, 0.20, 1, True),  # only one pass allowed
])  # fmt: skip
def test_push_passes_are_decided_from_the_object_cloud_and_the_cell(tiny, x0, x1, max_passes, skip):
    from flatlab_lerobot.sim.scene import CellConfig

    pol = _load(tiny["artifact"], max_push_passes=max_passes)
    ep = _Episode(pol, None, "A")
    ep.index = 4  # the second pass's touch
    obs = FlatLabUnifiedPolicy.observed({
        "observation.state": torch.zeros(1, 16), "observation.cell": torch.as_tensor(CellConfig().calibration())[None],
        "observation.pointcloud": torch.zeros(1, N, 3), "observation.object_pointcloud": torch.as_tensor(_cloud_x(x0, x1))[None],
    })[0]  # fmt: skip
    assert ep._skip_pass(obs) is skip
    assert ep.index == (7 if skip else 4)  # a skipped pass: on to its release, the next stage is pass 3 / the grasp
    # the first pass never is a decision
    ep.index = 0
    assert ep._skip_pass(obs) is False


def _desk_observed(sim, cloud_shift=None) -> "Observed":
    """What the policy would observe of ``sim`` (its target's corner points standing in for the
    object cloud; ``cloud_shift`` moves them, e.g. into the bin)."""
    pts = sim.object_points().copy()
    if cloud_shift is not None:
        pts = pts + cloud_shift
    return Observed(sim.joint_positions().astype(float), sim.cell.calibration(), np.zeros((N, 3)), pts)


def _expert_b_holds(sim):
    """The scripted expert's B lifts ``sim``'s target and holds it in both hands; returns the expert and its last
    action."""
    from flatlab_lerobot.strategies import Expert

    expert = Expert(sim.cell, sim.control_dt)
    gen = expert.episode("B", lambda: (sim.joint_positions(), sim.environment_state()))
    for _ in range(200):
        stage, _, action = next(gen)
        sim.step(action)
        if sim.is_success():
            break
    assert sim.is_success() and sim.holding_arms() == ("left", "right")
    return expert, action


def _episode_after_b_hold(pol, sim, action) -> _Episode:
    """``pol``'s state machine as if its own B attempt had just reached the final hold with ``action``."""
    ep = _Episode(pol, pol._expert(0, sim.cell.calibration()), "B")
    ep.q, ep.grip, ep.last = np.r_[action[0:7], action[8:15]], {"left": float(action[7]), "right": float(action[15])}, action
    ep.index, ep.started, ep.attempts, ep.lift_arms = len(STRATEGIES["B"]) - 1, True, ["B"], ("left", "right")
    return ep


def test_clear_all_carries_what_it_lifted_off_the_table_and_starts_over(tiny):
    """clear_all (the clear_desk scenario): after the final hold, an object cloud held aloft is carried
    past the usable edge by the arms that lifted it and let go, the env's next object becomes the
    target, and a new attempt starts on it; a cloud still on the table sends the arms home instead (and
    the attempt is retried); with nothing on the table the policy holds."""
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.sim.robot import HOME_Q
    from flatlab_lerobot.tasks.clear_desk import DeskItem, DeskLayout, advance_target, make_desk_sim

    lay = DeskLayout(0, (DeskItem(get_object("chess_travel"), 0.12, 0.0, 0.1),
                         DeskItem(get_object("painting_square_modern"), -0.16, 0.0, -0.1)))  # fmt: skip
    sim = make_desk_sim(lay)
    _, action = _expert_b_holds(sim)  # the scripted expert lifts the first object (B) and holds it

    pol = _load(tiny["artifact"], strategy="B", clear_all="true", settle_s=0.5)
    ep = _episode_after_b_hold(pol, sim, action)
    for _ in range(200):  # the policy takes over after its hold, on observations only
        sim.step(ep.act(_desk_observed(sim)))
        advance_target(sim)
        if len(ep.attempts) == 2:
            break
    afters = lambda: [d["after"] for d in ep.log if "after" in d]  # noqa: E731
    assert afters() == ["carry"]
    assert sim.lifted[0] and sim.off_table(0) and sim.target_index == 1  # dropped past the edge; next object
    assert ep.attempts == ["B", "B"] and ep.index == 0  # started over: the first stage of the next attempt

    # a failed attempt (the cloud still lies on the table): home, not a carry, and a retry
    ep.actions, ep.index, ep.lift_arms = None, len(STRATEGIES["B"]) - 1, ("left",)
    settled = []
    for _ in range(100):
        a = ep.act(_desk_observed(sim))
        sim.step(a)
        if ep.stage == "hold":  # settling after the move home
            settled.append(np.r_[a[0:7], a[8:15]])
        if len(ep.attempts) == 3:
            break
    assert afters() == ["carry", "home"]
    assert len(settled) == 5  # settle_s = 0.5 s at 10 Hz, at the home posture
    np.testing.assert_allclose(settled, np.tile(np.r_[HOME_Q, HOME_Q], (5, 1)), atol=1e-6)
    assert len(ep.attempts) == 3

    # nothing on the table (the cloud lies in the bin): no new attempt starts
    ep.actions, ep.after, ep.started, ep.strategy = None, None, False, None
    bin_cloud = np.array([0.0, 0.0, -0.4])
    for _ in range(5):
        ep.act(_desk_observed(sim, bin_cloud))
    assert ep.stage == "hold" and len(ep.attempts) == 3 and ep.strategy is None


@pytest.mark.parametrize("squeeze", [None, 0.01])
def test_carry_squeeze_lets_the_wrists_keep_a_thin_heavy_board_on_the_carry(tiny, squeeze):
    """carry_squeeze (with clear_all): before a two-hand carry-off each commanded hand moves back to where the
    observed joints put it, plus carry_squeeze inward.  The expert's B lifts the thin 2.2-kg marble board
    (Test-beta desk 7's pose) and the policy carries it: with the commanded squeeze (None) the saturated wrists
    let it pitch out of the hands onto the table, re-based it leaves the table (tests/test_clear_desk.py's case
    for the expert).  The commanded hands open by about the wrists' bend; none moves inward."""
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.tasks.clear_desk import REBASE_STEPS, DeskItem, DeskLayout, make_desk_sim

    sim = make_desk_sim(DeskLayout(0, (DeskItem(get_object("cutboard_marble"), -0.013, 0.194, 0.243),)))
    expert, action = _expert_b_holds(sim)
    pol = _load(tiny["artifact"], strategy="B", clear_all="true", settle_s=0.5,
                carry_squeeze="null" if squeeze is None else squeeze)
    assert pol.config.carry_squeeze == squeeze
    ep = _episode_after_b_hold(pol, sim, action)
    def gap(a):  # the commanded distance between the hands
        return np.linalg.norm(np.subtract(*(p for p, _ in expert.fk(np.r_[a[0:7], a[8:15]]).values())))

    gaps = [gap(action)]
    for _ in range(200):
        a = ep.act(_desk_observed(sim))
        sim.step(a)
        if [d["after"] for d in ep.log if "after" in d] == ["carry"] and len(gaps) <= REBASE_STEPS:
            gaps.append(gap(a))
        if sim.off_table(0) or not sim.holding_arms():
            break
    assert len(gaps) == REBASE_STEPS + 1 and np.all(np.diff(gaps) > -1e-4)
    assert gaps[-1] - gaps[0] == (pytest.approx(0.0, abs=1e-3) if squeeze is None else pytest.approx(0.035, abs=0.01))
    back = next(d for d in ep.log if "after" in d).get("squeeze_backoff")  # logged with the carry decision
    assert back is None if squeeze is None else sum(back.values()) == pytest.approx(gaps[-1] - gaps[0], abs=2e-3)
    for _ in range(30):
        sim.step(ep.act(_desk_observed(sim)))
    assert sim.off_table(0) == (squeeze is not None)
    with pytest.raises(ValueError, match="carry_squeeze acts on the carry-off"):
        FlatLabUnifiedConfig(carry_squeeze=0.01)
    with pytest.raises(ValueError, match="carry_squeeze: 0 to 0.025 m"):
        FlatLabUnifiedConfig(carry_squeeze=0.05, clear_all=True)


@pytest.mark.parametrize("quick", [False, True])
def test_quick_retry_goes_home_at_once_when_the_lift_visibly_failed(tiny, quick):
    """quick_retry (with clear_all): when the final hold is about to begin and the object cloud still lies on the
    table, the arms go home at once (no 2.6-s hold, no settle) and the next attempt starts; without it they hold,
    go home and settle first.  An object held aloft is held either way."""
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.tasks.clear_desk import HOME_STEPS, DeskItem, DeskLayout, make_desk_sim

    sim = make_desk_sim(DeskLayout(0, (DeskItem(get_object("chess_travel"), 0.12, 0.0, 0.1),)))
    pol = _load(tiny["artifact"], strategy="B", clear_all="true", settle_s=0.5, quick_retry=str(quick).lower())
    ep = _Episode(pol, pol._expert(0, sim.cell.calibration()), "B")
    n = len(STRATEGIES["B"])
    ep.act(_desk_observed(sim))  # the first stage starts
    ep.actions, ep.index, ep.lift_arms = None, n - 2, ("left", "right")  # the lift has just ended
    steps = 0
    while len(ep.attempts) < 2:
        ep.act(_desk_observed(sim))
        steps += 1
    hold = round(STAGE_SPECS["B"][n - 1].seconds() / 0.1)
    assert steps - 1 == (HOME_STEPS if quick else hold + HOME_STEPS + 5)
    assert [d.get("quick_retry") for d in ep.log if "quick_retry" in d] == ([True] if quick else [])
    # aloft: the hold runs
    ep.actions, ep.after, ep.index, ep.started, ep.attempts = None, None, n - 2, True, ["B"]
    ep.act(_desk_observed(sim, np.array([0.0, 0.0, 0.1])))
    assert ep.index == n - 1 and ep.after is None
    with pytest.raises(ValueError, match="quick_retry=true needs --policy.clear_all=true"):
        FlatLabUnifiedConfig(quick_retry=True)


@pytest.mark.parametrize("on", [False, True])
def test_retry_failed_tries_the_next_strategy_after_a_visibly_failed_lift(tiny, monkeypatch, on):
    """retry_failed (one object per episode): nothing lifted as the final hold begins -> home at once and the next
    most probable strategy; lifted but not aloft -> the hold runs, then home and the next; aloft -> held on, no
    retry; the object off the table -> no new attempt.  Column S stays the first attempt's (the generator's
    choice).  Without the switch the policy holds after its first attempt whatever it sees."""
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.tasks.clear_desk import HOME_STEPS, DeskItem, DeskLayout, make_desk_sim

    sim = make_desk_sim(DeskLayout(0, (DeskItem(get_object("chess_travel"), 0.12, 0.0, 0.1),)))
    pol = _load(tiny["artifact"], retry_failed=str(on).lower())
    monkeypatch.setattr(pol, "rank_strategies", lambda cloud: ["B", "A", "C"])
    monkeypatch.setattr(pol, "choose_strategy", lambda cloud: "B")
    ep = _Episode(pol, pol._expert(0, sim.cell.calibration()), None)
    pol._episodes = [ep]
    flat = _desk_observed(sim)
    top = float(flat.object_points[:, 2].max())
    risen = Observed(flat.state, flat.cell, flat.cloud, np.r_[flat.object_points, [[0.0, 0.0, top + 0.06]]])
    hold = {s: round(STAGE_SPECS[s][-1].seconds() / 0.1) for s in "ABC"}  # the final hold's steps

    def after_lift(obs, limit=200):  # the lift has just ended; act until a new attempt starts (or limit steps)
        ep.actions, ep.index = None, len(STRATEGIES[ep.strategy]) - 2
        n, before = 0, len(ep.attempts)
        while len(ep.attempts) == before and n < limit:
            ep.act(obs)
            n += 1
        return n - 1

    ep.act(flat)  # the first attempt starts on the flat object: B, the generator's choice
    assert ep.attempts == ["B"]
    steps = after_lift(flat)
    if not on:
        assert steps == 199 and ep.attempts == ["B"] and ep.stage == "hold"
        with pytest.raises(ValueError, match="retry_failed=true is for one object per episode"):
            FlatLabUnifiedConfig(retry_failed=True, clear_all=True)
        return
    assert steps == HOME_STEPS and ep.attempts == ["B", "A"]  # nothing lifted: home at once, then A
    assert [d["retry_failed"] for d in ep.log if "retry_failed" in d] == ["nothing lifted"]
    assert pol.strategies == ["B"]  # column S: the generator's first choice
    assert after_lift(risen) == hold["A"] + HOME_STEPS and ep.attempts == ["B", "A", "C"]  # its hold, then home
    assert [d["retry_failed"] for d in ep.log if "retry_failed" in d][-1] == "not aloft after the hold"
    aloft = _desk_observed(sim, np.array([0.0, 0.0, 0.1]))
    assert after_lift(aloft) == 199 and ep.attempts == ["B", "A", "C"] and ep.stage == "hold"  # held on
    ep.actions, ep.after, ep.started, ep.strategy = None, None, False, None  # the object fell off the table
    for _ in range(5):
        ep.act(_desk_observed(sim, np.array([0.0, 0.0, -0.4])))
    assert ep.stage == "hold" and len(ep.attempts) == 3


def _steps_to_next_attempt(ep, index, obs, limit=60):
    """The stage before ``index`` has just ended; act on ``obs`` until a new attempt starts: the steps before it (None:
    none started in ``limit``)."""
    ep.actions, ep.index = None, index - 1
    n, before = 0, len(ep.attempts)
    while len(ep.attempts) == before and n < limit:
        ep.act(obs)
        n += 1
    return n - 1 if len(ep.attempts) > before else None


@pytest.mark.parametrize("on", [False, True])
def test_retry_on_response_ends_an_attempt_whose_object_answers_as_another_kind(tiny, monkeypatch, on):
    """retry_on_response (with retry_failed): C's squeeze that raised no fold (a rigid object) ends the attempt at
    once and rules C out; a fold keeps it going.  An A push pass after which the object cloud hangs below the table
    top (a drooping sheet) ends it and rules out A and B; a level object keeps it going.  The readings are logged
    either way; without the switch nothing ends early.  first_attempt moves its strategy to the ranking's top."""
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.policies.unified.modeling_flatlab_unified import C_SQUEEZED
    from flatlab_lerobot.strategies.a_push_to_edge import PASS_STAGES
    from flatlab_lerobot.tasks.clear_desk import HOME_STEPS, DeskItem, DeskLayout, make_desk_sim

    sim = make_desk_sim(DeskLayout(0, (DeskItem(get_object("chess_travel"), 0.12, 0.0, 0.1),)))
    flat = _desk_observed(sim)
    top = float(flat.object_points[:, 2].max())
    fold = Observed(flat.state, flat.cell, flat.cloud, np.r_[flat.object_points, [[0.0, 0.0, top + 0.04]]])
    droop = Observed(flat.state, flat.cell, flat.cloud, np.r_[flat.object_points, [[0.9, 0.0, flat.table_top - 0.06]]])

    def episode(first, **retries):
        retries = retries or {"retry_failed": "true", "retry_rank": "first_sight"}
        pol = _load(tiny["artifact"], retry_switch_after="2", retry_on_response="AC" if on else "", first_attempt=first,
                    **retries)
        monkeypatch.setattr(pol, "rank_strategies", lambda cloud: ["B", "A", "C"])
        ep = _Episode(pol, pol._expert(0, sim.cell.calibration()), None)
        pol._episodes = [ep]
        ep.act(flat)  # the first attempt starts on the flat object
        assert ep.attempts == [first]  # ranked first by first_attempt, though the generator ranks it last
        return ep

    ep = episode("C")  # a rigid object: the squeeze raised nothing
    steps = _steps_to_next_attempt(ep, C_SQUEEZED, flat)
    reading = [d for d in ep.log if "fold_rise" in d][0]
    assert reading["fold_rise"] < 0.02 and reading["response_failed"] is on
    if on:
        assert steps == HOME_STEPS and ep.attempts == ["C", "B"] and ep.tried == ["C", "C", "B"]
    else:
        assert steps is None and ep.attempts == ["C"]  # the attempt goes on
    ep = episode("C")  # a sheet: the squeeze raised a fold, the attempt goes on
    assert _steps_to_next_attempt(ep, C_SQUEEZED, fold) is None and ep.attempts == ["C"]
    assert [d["response_failed"] for d in ep.log if "fold_rise" in d] == [False]
    ep = episode("C")  # no fold, but at a later attempt (a sheet a failed A left over the edge folds less): goes on
    ep.attempts, ep.tried = ["A", "C"], ["A", "C"]
    assert _steps_to_next_attempt(ep, C_SQUEEZED, flat) is None
    assert [d["response_failed"] for d in ep.log if "fold_rise" in d] == [False]

    ep = episode("A")  # a sheet drooping over the edge after the first push pass
    steps = _steps_to_next_attempt(ep, PASS_STAGES, droop)
    reading = [d for d in ep.log if "droop" in d][0]
    assert reading["droop"] > 0.03 and reading["response_failed"] is on
    if on:
        assert steps == HOME_STEPS and ep.attempts == ["A", "C"]  # A and B ruled out
    else:
        assert steps is None and ep.attempts == ["A"]
    ep = episode("A")  # a level object after the push pass: A goes on
    assert _steps_to_next_attempt(ep, PASS_STAGES, flat, limit=5) is None
    assert [d["response_failed"] for d in ep.log if "droop" in d] == [False]
    ep = episode("C", clear_all="true", retry_next_strategy="true")  # the desk's retries, on the object left in place
    steps = _steps_to_next_attempt(ep, C_SQUEEZED, flat)
    assert (steps, ep.attempts) == ((HOME_STEPS, ["C", "B"]) if on else (None, ["C"]))
    with pytest.raises(ValueError, match="retry_on_response needs --policy.retry_failed=true or"):
        FlatLabUnifiedConfig(retry_on_response="C")
    with pytest.raises(ValueError, match="retry_on_response: letters of A, C"):
        FlatLabUnifiedConfig(retry_on_response="B", retry_failed=True)
    with pytest.raises(ValueError, match="first_attempt: one of A, B, C"):
        FlatLabUnifiedConfig(first_attempt="D")


@pytest.mark.parametrize("on", [False, True])
def test_retry_on_fold_lost_ends_a_c_whose_fold_lay_back_down(tiny, monkeypatch, on):
    """retry_on_fold_lost (with retry_failed): as C's pinching hand is about to straddle the fold and again as it is
    about to pinch, the seen top's rise since the attempt started is logged (fold_kept); below the switch's height as
    the pinch begins, at the first C attempt on the object (a stiff pad whose fold lay back down flat), the attempt
    ends at once and C is ruled out; a standing fold goes on, and so does a later C attempt.  Without the switch
    nothing ends early."""
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.policies.unified.modeling_flatlab_unified import C_PINCH, C_STRADDLE
    from flatlab_lerobot.tasks.clear_desk import HOME_STEPS, DeskItem, DeskLayout, make_desk_sim

    assert STAGE_SPECS["C"][C_STRADDLE - 1].primitive == "move" and C_PINCH == C_STRADDLE + 1
    sim = make_desk_sim(DeskLayout(0, (DeskItem(get_object("chess_travel"), 0.12, 0.0, 0.1),)))
    flat = _desk_observed(sim)
    top = float(flat.object_points[:, 2].max())
    fold = Observed(flat.state, flat.cell, flat.cloud, np.r_[flat.object_points, [[0.0, 0.0, top + 0.04]]])

    def episode():
        pol = _load(tiny["artifact"], retry_failed="true", retry_switch_after="2", retry_rank="first_sight",
                    first_attempt="C", retry_on_fold_lost="0.01" if on else "0")
        monkeypatch.setattr(pol, "rank_strategies", lambda cloud: ["B", "A", "C"])
        ep = _Episode(pol, pol._expert(0, sim.cell.calibration()), None)
        pol._episodes = [ep]
        ep.act(flat)
        return ep

    def before_straddle(ep, obs):  # C's left hand has just moved out: straddling, then pinching, on the cloud ``obs``
        return _steps_to_next_attempt(ep, C_STRADDLE, obs)

    ep = episode()  # the fold lay back down: nothing above where the object lay
    steps = before_straddle(ep, flat)
    reading = [d for d in ep.log if "fold_kept" in d]
    assert [d["index"] for d in reading] == [C_STRADDLE, C_PINCH] and all(d["fold_kept"] < 0.01 for d in reading)
    assert [d["response_failed"] for d in reading] == [False, on]  # the straddle's reading is only logged
    if on:
        straddle = STAGE_SPECS["C"][C_STRADDLE]
        assert steps == round((straddle.transit + straddle.seconds()) / 0.1) + HOME_STEPS  # straddled, then home
        assert ep.attempts == ["C", "B"] and ep.tried == ["C", "C", "B"]
    else:
        assert steps is None and ep.attempts == ["C"]
    ep = episode()  # the fold stands: the pinch goes on
    assert before_straddle(ep, fold) is None and ep.attempts == ["C"]
    assert [d["fold_kept"] > 0.01 and not d["response_failed"] for d in ep.log if "fold_kept" in d] == [True, True]
    ep = episode()  # a later C attempt on the object: goes on
    ep.attempts, ep.tried = ["A", "C"], ["A", "C"]
    assert before_straddle(ep, flat) is None
    assert [d["response_failed"] for d in ep.log if "fold_kept" in d] == [False] * 2
    with pytest.raises(ValueError, match="retry_on_fold_lost needs --policy.retry_failed=true or"):
        FlatLabUnifiedConfig(retry_on_fold_lost=0.02)
    with pytest.raises(ValueError, match="retry_on_fold_lost: a height in"):
        FlatLabUnifiedConfig(retry_on_fold_lost=0.5, retry_failed=True)


@pytest.mark.parametrize("retry", [False, True])
def test_retry_next_strategy_tries_the_next_most_probable_on_an_object_left_in_place(tiny, monkeypatch, retry):
    """retry_next_strategy (with clear_all): an attempt on the object seen where the last one started takes the
    generator's most probable strategy not yet tried there; all three tried, from the top again; an object seen
    elsewhere (the next one, or this one pushed away) starts afresh.  Without it every attempt asks again."""
    pol = _load(tiny["artifact"], clear_all="true", retry_next_strategy=str(retry).lower())
    monkeypatch.setattr(pol, "rank_strategies", lambda cloud: ["B", "A", "C"])
    ep = _Episode(pol, None, None)
    cell = np.r_[0.75, 0.6, np.zeros(5)]

    def seen(x, y):
        noise = np.random.default_rng(0).normal(0, 0.01, (K, 3))
        return Observed(np.zeros(16), cell, np.zeros((N, 3)), np.r_[x, y, 0.76] + noise)

    here, moved = seen(0.1, -0.2), seen(0.1, -0.08)
    got = [ep._next_strategy(o) for o in (here, here, here, here, moved, moved)]
    assert got == (["B", "A", "C", "B", "B", "A"] if retry else ["B"] * 6)
    if retry:
        assert [d["retry"]["same_object"] for d in ep.log] == [False, True, True, True, False, True]
    with pytest.raises(ValueError, match="retry_next_strategy=true needs --policy.clear_all=true"):
        FlatLabUnifiedConfig(retry_next_strategy=True)


def test_hold_still_holds_on_while_the_object_slides_and_lets_go_of_one_still_sliding(tiny):
    """hold_still (with clear_all): at the end of the final hold the carry waits while the object cloud, relative to
    the lifting hands, has moved hold_still or more within the last 2 s; an object that stops sliding is carried
    (the wait logged), one still sliding when hold_still_max_s has run out is let go (the arms go home), one that
    never slid is carried at once (nothing logged), and one not seen aloft is not held on."""
    from flatlab_lerobot.policies.unified.modeling_flatlab_unified import HOLD_STILL_S

    pol = _load(tiny["artifact"], clear_all="true", hold_still="0.005", hold_still_max_s="3.0")
    window, cap = round(HOLD_STILL_S / pol.config.control_dt), round(3.0 / pol.config.control_dt)
    cell = np.r_[0.75, 0.6, np.zeros(5)]
    aloft = Observed(np.zeros(16), cell, np.zeros((N, 3)), np.r_[0.3, 0.0, 0.9] + np.zeros((K, 3)))
    on_table = Observed(np.zeros(16), cell, np.zeros((N, 3)), np.r_[0.3, 0.0, 0.76] + np.zeros((K, 3)))

    def hold(slides: list[bool], obs=aloft):
        """Feed one sample per step (sliding 2 mm per step or still) and ask at every step after the hold's own
        length; returns the episode and how many steps it held on."""
        ep = _Episode(pol, None, None)
        ep.index, ep.q, ep.grip = 0, np.zeros(14), {"left": 0.04, "right": 0.04}
        at, extra = np.zeros(3), 0
        for k, slide in enumerate(slides):
            at = at + (np.r_[0.0, 0.0, -0.002] if slide else 0.0)
            ep.hold_rel.append(at.copy())
            if k >= window - 1:
                if not ep._hold_on(obs):
                    return ep, extra
                extra += 1
        raise AssertionError("still holding on")

    ep, extra = hold([False] * window)  # never slid: carried at once, nothing logged
    assert extra == 0 and not ep.hold_slid and not any("hold_still" in d for d in ep.log)
    # slid 6 mm as the hold ended, then stopped: carried once the 2-s window starts within 5 mm of where it stopped
    ep, extra = hold([False] * (window - 3) + [True] * 3 + [False] * window)
    assert extra == window - 3 and not ep.hold_slid
    assert ep.log[-1]["hold_still"] == {"extra_steps": window - 3, "still": True, "moved": 0.004}
    ep, extra = hold([True] * (window + 3 * cap))  # still sliding when the wait runs out: let go, not carried
    assert extra == cap and ep.hold_slid and ep.log[-1]["hold_still"]["still"] is False
    next(ep._after_hold(aloft))
    assert ep.log[-1]["after"] == "home"
    ep, extra = hold([True] * window, obs=on_table)  # not aloft: the carry or the way home decides at once
    assert extra == 0 and not ep.hold_slid
    with pytest.raises(ValueError, match="--policy.hold_still"):
        FlatLabUnifiedConfig(hold_still=0.005)  # without clear_all
    with pytest.raises(ValueError, match="--policy.hold_still"):
        FlatLabUnifiedConfig(hold_still=0.2, clear_all=True)
    with pytest.raises(ValueError, match="--policy.hold_still_max_s"):
        FlatLabUnifiedConfig(hold_still_max_s=-1.0)


@pytest.mark.parametrize("rank", ["current", "first_sight"])
def test_retry_rank_first_sight_keeps_the_ranking_of_the_untouched_object(tiny, monkeypatch, rank):
    """retry_failed with retry_switch_after=2: the generator ranks the untouched object C, A, B and every later
    cloud B, A, C (a dropped cloth lies folded).  current ranks each retry on the cloud seen then; first_sight keeps
    the first attempt's ranking for every retry on the object.  A bad value names the flag."""
    pol = _load(tiny["artifact"], retry_failed="true", retry_switch_after="2", retry_rank=rank)
    calls = []
    monkeypatch.setattr(pol, "rank_strategies", lambda cloud: calls.append(1) or (["C", "A", "B"] if len(calls) == 1
                                                                                  else ["B", "A", "C"]))  # fmt: skip
    ep = _Episode(pol, None, None)
    cell = np.r_[0.75, 0.6, np.zeros(5)]
    obs = Observed(np.zeros(16), cell, np.zeros((N, 3)), np.r_[0.1, -0.2, 0.76] + np.zeros((K, 3)))
    got = [ep._next_strategy(obs) for _ in range(6)]
    assert got == (["C", "B", "B", "A", "A", "C"] if rank == "current" else ["C", "C", "A", "A", "B", "B"])
    assert len(calls) == (6 if rank == "current" else 1)
    with pytest.raises(ValueError, match="--policy.retry_rank"):
        FlatLabUnifiedConfig(retry_rank="last")


@pytest.mark.parametrize("switch", ["", "contact_a_pusher_side", "a_side_arms"])
def test_a_pusher_side_pushes_with_the_arm_on_the_seen_objects_side(tiny, switch):
    """contact_a_pusher_side (observed contact) and a_side_arms (learned poses, the desk's objects far off the centre
    line): A's push passes are commanded to the arm on the seen object's side (the expert's rule), the executor's
    other arm's motion mirrored onto it, chosen once per attempt; without the switch the executor's arm pushes (here
    forced to the far one)."""
    from flatlab_lerobot.strategies.a_push_to_edge import A_PREAPPROACH, arm_on_side

    kw = {"contact": "observed", "contact_a_pusher_side": "true"} if switch == "contact_a_pusher_side" else {}
    kw.update({"a_side_arms": "true", "continue_from_hand": "AC"} if switch == "a_side_arms" else {})
    pol = _load(tiny["artifact"], strategy="A", **kw)
    env = _env()
    obs, _ = env.reset(seed=3)
    pts = obs["object_pointcloud"].astype(float)
    side = arm_on_side(float(pts[np.any(pts != 0, 1)][:, :2].mean(0)[1]))
    far = next(a for a in ARMS if a != side)
    orig = pol.executor.predict_poses

    def far_arm(*args, **kw):
        poses = orig(*args, **kw)
        for a in ARMS:
            poses[a]["active"] = np.array([0.95 if a == far else 0.05])
        return poses

    pol.executor.predict_poses = far_arm
    pol.reset()
    for _ in range(60):
        obs, *_ = env.step(pol.select_action(_batch(obs))[0].numpy())
        if pol.stage_indices[0] >= 3:
            break
    env.close()
    push = [d for d in pol.decisions[0] if "primitive" in d and d["index"] < A_PREAPPROACH]
    assert len(push) >= 3
    assert all(d["arms"] == ([side] if switch else [far]) for d in push), push
    if switch:
        assert all(d["a_arm"] == {"learned": [far], "side": side, "mirrored_from": far} for d in push)
    else:
        assert not any("a_arm" in d for d in push)
    with pytest.raises(ValueError, match="a_side_arms=true is for --policy.contact=learned"):
        FlatLabUnifiedConfig(a_side_arms=True, contact="observed")


@pytest.mark.parametrize("backoff", [False, True])
def test_a_side_arms_pusher_backs_off_when_the_other_arm_grasps(tiny, monkeypatch, backoff):
    """a_side_arms with contact_a_backoff (learned poses): when the pushes leave the object on the other arm's
    side, at A's pre-approach the pusher backs off from its commanded hand as the expert's does (pusher_backoff),
    out of the lifted object's way; without the switch it stays where its release left it.  Learned desk 22
    (stop 74): the lifted CD case rose into the idle hand and was carried off before the hold rule was met."""
    from flatlab_lerobot.policies.unified import modeling_flatlab_unified as M
    from flatlab_lerobot.strategies.a_push_to_edge import A_PREAPPROACH, pusher_backoff

    sides = iter(["left", "right"])  # the first touch sees the object left of the centre line, the pre-approach right
    monkeypatch.setattr(M, "a_side_arm", lambda pts: next(sides))
    posed = _posed_stages(monkeypatch)
    kw = {"contact_a_backoff": "true"} if backoff else {}
    pol = _load(tiny["artifact"], strategy="A", a_side_arms="true", continue_from_hand="AC",
                continue_a_preapproach_line="true", max_push_passes="1", **kw)  # fmt: skip
    env = _env()
    obs, _ = env.reset(seed=3)
    pol.reset()
    for _ in range(200):
        obs, *_ = env.step(pol.select_action(_batch(obs))[0].numpy())
        if pol.stage_indices[0] > A_PREAPPROACH:
            break
    env.close()
    prim, pre, _ = next((p, d, o) for p, d, o in posed if d.get("index") == A_PREAPPROACH)
    assert pre["a_arm"]["side"] == "right", pre
    if backoff:  # from the commanded hand (where the release left it) to the expert's back-off from it
        assert "left" in pre["arms"] and "backoff" in pre["heights"]["left"], pre
        hand = prim.motions["left"].start[0]
        np.testing.assert_allclose(prim.motions["left"].end[0], pusher_backoff("left", hand))
        np.testing.assert_allclose(pre["heights"]["left"]["backoff"], pusher_backoff("left", hand))
    else:
        assert "left" not in pre["arms"] and "left" not in prim.motions, pre
    with pytest.raises(ValueError, match="contact_a_backoff=true needs"):
        FlatLabUnifiedConfig(contact_a_backoff=True)
    assert FlatLabUnifiedConfig(a_side_arms=True, contact_a_backoff=True).contact_a_backoff


def test_retry_switch_after_gives_each_strategy_that_many_attempts(tiny, monkeypatch):
    """retry_switch_after=k: on an object left in place each strategy, most probable first, gets k attempts
    before the next one; all three tried k times, from the top again; an object seen elsewhere starts afresh."""
    pol = _load(tiny["artifact"], clear_all="true", retry_next_strategy="true", retry_switch_after="2")
    monkeypatch.setattr(pol, "rank_strategies", lambda cloud: ["B", "A", "C"])
    ep = _Episode(pol, None, None)
    cell = np.r_[0.75, 0.6, np.zeros(5)]
    noise = np.random.default_rng(0).normal(0, 0.01, (K, 3))
    here = Observed(np.zeros(16), cell, np.zeros((N, 3)), np.r_[0.1, -0.2, 0.76] + noise)
    moved = Observed(np.zeros(16), cell, np.zeros((N, 3)), np.r_[0.1, -0.08, 0.76] + noise)
    got = [ep._next_strategy(o) for o in [here] * 7 + [moved] * 3]
    assert got == ["B", "B", "A", "A", "C", "C", "B", "B", "B", "A"]
    for bad in (0, 11):
        with pytest.raises(ValueError, match="retry_switch_after: must be in"):
            FlatLabUnifiedConfig(clear_all=True, retry_next_strategy=True, retry_switch_after=bad)


@pytest.mark.parametrize("track", [False, True])
def test_retry_track_follows_the_object_an_attempt_pushed(tiny, monkeypatch, track):
    """retry_track: the object an attempt moved (A's push: 30 cm towards the edge, 3 cm a step) is still the
    one tried, so after two A attempts on it the next is B; a jump of the seen centre is the next object,
    which starts afresh.  Without it, where the last attempt started finds nothing: A again and again."""
    pol = _load(tiny["artifact"], clear_all="true", retry_next_strategy="true", retry_switch_after="2",
                retry_track=str(track).lower())  # fmt: skip
    monkeypatch.setattr(pol, "rank_strategies", lambda cloud: ["A", "B", "C"])
    ep = _Episode(pol, None, None)
    cell = np.r_[0.75, 0.6, np.zeros(5)]
    noise = np.random.default_rng(0).normal(0, 0.01, (K, 3))

    def seen(x, y):
        o = Observed(np.zeros(16), cell, np.zeros((N, 3)), np.r_[x, y, 0.76] + noise)
        ep._track(o) if track else None  # act() follows the cloud at every step
        return o

    got = [ep._next_strategy(seen(-0.2, -0.2))]
    for x in np.arange(-0.17, 0.12, 0.03):  # the first push
        seen(x, -0.2)
    got.append(ep._next_strategy(seen(0.1, -0.2)))
    for x in np.arange(0.12, 0.2, 0.02):  # the second, to the edge; the pushed object stays on the table
        seen(x, -0.2)
    got.append(ep._next_strategy(seen(0.2, -0.2)))
    got.append(ep._next_strategy(seen(-0.1, 0.2)))  # lifted and carried off: the env shows the next object
    assert got == (["A", "A", "B", "A"] if track else ["A", "A", "A", "A"])
    with pytest.raises(ValueError, match="retry_track=true needs --policy.retry_next_strategy"):
        FlatLabUnifiedConfig(clear_all=True, retry_track=True)


@pytest.mark.parametrize("reach", [False, True])
def test_reach_check_ends_the_attempt_before_the_arm_moves_out_of_reach(tiny, monkeypatch, reach):
    """reach_check: a stage whose start the arm's IK misses by more than 3 cm is not run: the arm does not move
    towards it, the attempt ends (arms home) and, with retry_next_strategy, the strategy counts as tried
    retry_switch_after times, so the next attempt on the object takes the next one.  Without it the arm goes."""
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.primitives import ArmMotion, Primitive
    from flatlab_lerobot.tasks.clear_desk import HOME_STEPS, DeskItem, DeskLayout, make_desk_sim

    sim = make_desk_sim(DeskLayout(0, (DeskItem(get_object("chess_travel"), 0.12, 0.0, 0.1),)))
    pol = _load(tiny["artifact"], clear_all="true", retry_next_strategy="true", retry_switch_after="2",
                reach_check=str(reach).lower())  # fmt: skip
    monkeypatch.setattr(pol, "rank_strategies", lambda cloud: ["B", "A", "C"])
    ep = _Episode(pol, pol._expert(0, sim.cell.calibration()), None)
    q0 = sim.joint_positions().astype(float)
    far = (np.array([-0.2, -0.6, 0.764]), ep.expert.fk(np.r_[q0[0:7], q0[8:15]])["left"][1])
    monkeypatch.setattr(ep, "_primitive", lambda obs: Primitive("touch", {"left": ArmMotion(far, far, (0.04, 0.04))}, 0.5))
    moved = 0.0
    for _ in range(HOME_STEPS + 5):
        a = ep.act(_desk_observed(sim))
        moved = max(moved, float(np.abs(a[0:7] - q0[0:7]).max()))
        sim.step(a)
        if len(ep.attempts) == 2:
            break
    misses = [d["unreachable"] for d in ep.log if "unreachable" in d]
    if reach:
        assert misses and all(m["left"] > 0.3 for m in misses) and moved < 0.05, (misses, moved)
        assert ep.attempts == ["B", "A"]  # B counted twice on the chess set: A next (its stage refused too)
    else:
        assert not misses and moved > 0.3 and ep.attempts == ["B"]


def test_rank_strategies_orders_the_generators_probabilities(tiny, monkeypatch):
    """rank_strategies: A, B, C by the generator's probability for the cloud it reads, so its first is the
    generator's own argmax (choose_strategy, unchanged)."""
    pol = _load(tiny["artifact"])
    cloud = _batch(_env().reset(seed=0)[0])["observation.object_pointcloud"][0].numpy()
    inputs, real = [], pol.generator.predict_logits

    def spy(batch, tta=None):
        inputs.append(batch)
        return real(batch, tta)

    monkeypatch.setattr(pol.generator, "predict_logits", spy)
    ranked = pol.rank_strategies(cloud)
    probs = real(inputs[0]).softmax(-1)[0].tolist()
    assert sorted(ranked) == ["A", "B", "C"]
    assert [probs["ABC".index(s)] for s in ranked] == sorted(probs, reverse=True)
    assert ranked[0] == pol.generator.predict_strategy(inputs[0])[0] == pol.choose_strategy(cloud)


@pytest.mark.parametrize("width", [0.0, 0.09])
def test_b_min_width_ranks_b_last_for_an_object_seen_narrower(tiny, monkeypatch, width):
    """b_min_width: a seen object narrower than it gets B last, the others keep their order; a wider one, an
    unseen one, or the switch off (0) leave the generator's ranking as it is."""
    pol = _load(tiny["artifact"], b_min_width=width)
    monkeypatch.setattr(pol.generator, "rank_cloud", lambda cloud, n, tta: ["B", "C", "A"])
    narrow, wide = np.zeros((600, 3)), np.zeros((600, 3))  # zero rows: not seen
    rng = np.random.default_rng(0)
    narrow[:500] = [0.0, 0.0, 0.77] + rng.uniform(-0.038, 0.038, (500, 3)) * [1, 1, 0]  # a 7.6-cm pad
    wide[:500] = [0.0, 0.0, 0.77] + rng.uniform(-1, 1, (500, 3)) * [0.145, 0.0525, 0]  # a 29 x 10.5-cm keyboard
    assert pol.rank_strategies(narrow) == (["C", "A", "B"] if width else ["B", "C", "A"])
    assert pol.rank_strategies(wide) == ["B", "C", "A"]
    assert pol.rank_strategies(np.zeros((K, 3))) == ["B", "C", "A"]
    assert pol.choose_strategy(narrow) == ("C" if width else "B")


def test_stage_specs_name_the_primitives_the_expert_poses():
    """The executor is conditioned on STAGE_SPECS' primitive names; the primitive set recorded the
    names of the primitives the expert's stage functions returned: they must be the same."""
    R = np.eye(3)
    for deformable in (False, True):
        w = World(np.array([0.0, 0.05, 0.76]), 0.2, np.array([0.25, 0.2, 0.02]), deformable, 0.75, 0.3)
        poses = {a: (np.array([0.2, 0.3 if a == "left" else -0.3, 0.9]), R) for a in ("left", "right")}
        grip = {"left": 0.04, "right": 0.04}
        for strat, stages in STRATEGIES.items():
            assert len(stages) == len(STAGE_SPECS[strat]) <= C.MAX_STAGES
            ctx = {}
            for i, stage in enumerate(stages):
                prim = stage(None, w, poses, grip, ctx)
                spec = STAGE_SPECS[strat][i]
                assert prim.name == spec.primitive and prim.transit == spec.transit, (strat, i)
                # StageSpec.start (the executor's relative_starts): "current" = every commanded arm starts at
                # its current pose; "world" = a moving arm starts at a pose computed from the scene
                at_current = [np.allclose(m.start[0], poses[a][0]) and np.allclose(m.start[1], poses[a][1])
                              for a, m in prim.motions.items()]  # fmt: skip
                assert spec.start in ("current", "world"), (strat, i)
                assert all(at_current) if spec.start == "current" else not all(at_current), (strat, i, spec.start)


# ------------------------------------------------------------------------------ through the CLIs
@pytest.mark.slow
def test_lerobot_eval_runs_the_artifact(tiny, tmp_path):
    out = tmp_path / "eval"
    cmd = [str(BIN / "lerobot-eval"), f"--policy.path={tiny['artifact']}", "--env.type=flatlab",
           f"--env.object_id={OBJECT}", *ENV_FLAGS, "--env.render_size=32", "--env.episode_length=30",
           "--eval.n_episodes=1", "--eval.batch_size=1", f"--output_dir={out}"]  # fmt: skip
    res = subprocess.run(cmd, check=False, capture_output=True, text=True, env={**os.environ, "MUJOCO_GL": "egl"},
                         timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1


@pytest.mark.slow
def test_flatlab_eval_fills_column_s(tiny, tmp_path):
    from flatlab_lerobot.evaluation.protocol import main as eval_main

    out = tmp_path / "feval"
    assert eval_main(["--policy", str(tiny["artifact"]), "--objects", OBJECT, "--trials", "1", "--workers", "1",
                      "--quiet", "--no-plot", "--out", str(out), *ENV_FLAGS, "--env.episode_length=20"]) == 0  # fmt: skip
    (rec,) = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert rec["strategy"] in ("A", "B", "C") and rec["S"] == (rec["strategy"] == "B") and rec["steps"] == 20


@pytest.mark.slow
def test_flatlab_eval_skips_the_clouds_the_policy_will_not_read_and_runs_the_same_episode(tiny, tmp_path, monkeypatch):
    """``flatlab eval`` lets the env skip the clouds of steps where ``reads_next_clouds`` is False (inside a stage);
    the episode -- every action and the record -- is the one run with clouds rendered at every step
    (``--render-every-step``, as lerobot-eval's loop), with far fewer renders."""
    from flatlab_lerobot.evaluation.protocol import main as eval_main

    seen, actions, renders = {}, [], []  # the lists: the current run's, filled by the spies patched in once
    real_step, real_obs = FlatLabEnv.step, FlatLabEnv._observe
    monkeypatch.setattr(FlatLabEnv, "step", lambda self, a: actions.append(np.array(a)) or real_step(self, a))
    monkeypatch.setattr(FlatLabEnv, "_observe", lambda self: renders.append(not self._skip_clouds) or real_obs(self))

    def run(tag: str, *flags: str):
        actions.clear()
        renders.clear()
        out = tmp_path / tag
        assert eval_main(["--policy", str(tiny["artifact"]), "--objects", OBJECT, "--trials", "1", "--workers", "1",
                          "--quiet", "--no-plot", "--out", str(out), *ENV_FLAGS, "--env.episode_length=80",
                          "--policy.strategy=B", *flags]) == 0  # fmt: skip
        (rec,) = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
        seen[tag] = (np.array(actions), sum(renders), {k: v for k, v in rec.items() if k not in ("wall_s", "pid")})

    run("every", "--render-every-step")
    run("skip")
    (a_every, n_every, rec_every), (a_skip, n_skip, rec_skip) = seen["every"], seen["skip"]
    assert rec_skip == rec_every and rec_every["steps"] == 80
    np.testing.assert_array_equal(a_skip, a_every)
    assert n_every == 81 and n_skip < n_every / 4, (n_every, n_skip)  # the reset + one per step; a few decisions


# ------------------------------------------------------------------------------ Train objects only
def _fake_dataset(root: Path, tasks: list[str], frames: pd.DataFrame | None = None, export: dict | None = None):
    (root / "meta").mkdir(parents=True)
    (root / "meta" / "info.json").write_text("{}")
    pd.DataFrame({"task_index": range(len(tasks))}, index=pd.Index(tasks, name="task")).to_parquet(
        root / "meta" / "tasks.parquet"
    )
    if frames is not None:
        frames.to_parquet(root / "meta" / "flatlab_strategy_frames.parquet")
    if export is not None:
        (root / "flatlab_export.json").write_text(json.dumps(export))


def _with_train_config(model: Path, dest: Path, dataset: Path) -> Path:
    import shutil

    shutil.copytree(model, dest)
    (dest / "train_config.json").write_text(json.dumps({"dataset": {"repo_id": "local/x", "root": str(dataset)}}))
    return dest


def test_builder_checks_that_submodels_saw_train_objects_only(tiny, tmp_path):
    from flatlab_lerobot.catalog import load_objects
    from flatlab_lerobot.policies.executor.configuration_flatlab_executor import task_string

    cat = load_objects()
    train = sorted(o.id for o in cat.values() if o.split == "train")[:2]
    test = sorted(o.id for o in cat.values() if o.split == "test_alpha")[0]
    ok_ex, bad_ex, evalonly_ex, ok_gen, bad_gen = (tmp_path / n for n in ("ok_ex", "bad_ex", "eo_ex", "ok_gen", "bad_gen"))
    _fake_dataset(ok_ex, [task_string(o, "train", "A") for o in train], export={"eval_only": False})
    _fake_dataset(bad_ex, [task_string(train[0], "train", "A"), task_string(test, "test_alpha", "B")])
    _fake_dataset(evalonly_ex, [task_string(train[0], "train", "A")], export={"eval_only": True})
    _fake_dataset(ok_gen, ["x"], frames=pd.DataFrame({"base_object_id": train, "split": ["train"] * len(train)}))
    _fake_dataset(bad_gen, ["x"], frames=pd.DataFrame({"base_object_id": [train[0], test], "split": ["train", "train"]}))
    gen = {n: _with_train_config(tiny["generator"], tmp_path / f"m_{n}", tmp_path / n) for n in ("ok_gen", "bad_gen")}
    ex = {n: _with_train_config(tiny["executor"], tmp_path / f"m_{n}", tmp_path / n) for n in ("ok_ex", "bad_ex", "eo_ex")}
    quiet = {"log": lambda *a: None}
    rec = unified_build.build(gen["ok_gen"], ex["ok_ex"], tmp_path / "ok", **quiet)
    assert rec["train_only_check"]["executor"]["objects"] == train and rec["train_only_check"]["generator"]["verified"]
    assert not rec["allow_unverified"]
    with pytest.raises(unified_build.UnifiedBuildError, match=test):
        unified_build.build(gen["ok_gen"], ex["bad_ex"], tmp_path / "x1", **quiet)
    with pytest.raises(unified_build.UnifiedBuildError, match="eval_only"):
        unified_build.build(gen["ok_gen"], ex["eo_ex"], tmp_path / "x2", **quiet)
    with pytest.raises(unified_build.UnifiedBuildError, match=test):
        unified_build.build(gen["bad_gen"], ex["ok_ex"], tmp_path / "x3", **quiet)
    with pytest.raises(unified_build.UnifiedBuildError, match="train_config.json missing"):  # no --allow-unverified
        unified_build.build(tiny["generator"], tiny["executor"], tmp_path / "x4", **quiet)
    with pytest.raises(unified_build.UnifiedBuildError, match="flatlab_strategy"):  # the sub-models swapped
        unified_build.build(ex["ok_ex"], gen["ok_gen"], tmp_path / "x5", **quiet)


def test_carry_box_centre_takes_the_middle_of_the_seen_extent():
    """carry_box_centre: the carry-off's centre is the middle of the cloud's extent, not the mean that the
    side the cameras see densest pulls (a held keyboard_compact, Train desk 6: mean 4 cm behind the centre),
    so B's 'centre past the edge' carry lets go of the object past the edge."""
    from flatlab_lerobot.policies.unified.modeling_flatlab_unified import _extent_middle, _points_mean
    from flatlab_lerobot.tasks.clear_desk import CARRY_MARGIN, carry_displacements

    rng = np.random.default_rng(0)
    flat = rng.uniform([-0.04, -0.1, 0.92], [0.26, 0.1, 0.93], (1000, 3))
    near = rng.uniform([0.16, -0.1, 0.92], [0.26, 0.1, 0.93], (1500, 3))  # the densely seen front part
    pts = np.vstack([flat, near])
    assert _points_mean(pts)[0] > 0.15
    np.testing.assert_allclose(_extent_middle(pts)[:2], [0.11, 0.0], atol=2e-3)
    tip = carry_displacements(pts, _extent_middle(pts), 0.30, ("left", "right"))[3]  # the centre past the edge
    assert 0.11 + tip[0] == pytest.approx(0.30 + CARRY_MARGIN, abs=2e-3)
    with pytest.raises(ValueError, match="carry_box_centre=true acts on the carry-off"):
        FlatLabUnifiedConfig(carry_box_centre=True)
    FlatLabUnifiedConfig(carry_box_centre=True, clear_all=True)

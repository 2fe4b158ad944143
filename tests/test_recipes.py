"""Every training recipe in ``policies/`` (JSON for ``lerobot-train --config_path``) parses as lerobot's
``TrainPipelineConfig``, and the package finds it (and the collection recipes) through ``paths.py``."""

import json

import draccus
import pytest

from flatlab_lerobot.paths import POLICIES_DIR

RECIPES = sorted(POLICIES_DIR.glob("*.json"))


def test_there_are_recipes():
    assert any(p.name == "act_tiny_rigid.json" for p in RECIPES), RECIPES


@pytest.mark.parametrize("path", RECIPES, ids=lambda p: p.name)
def test_recipe_parses_as_a_train_pipeline_config(path):
    import lerobot.policies  # noqa: F401  registers lerobot's policy types, as lerobot-train does
    from lerobot.configs.train import TrainPipelineConfig

    import flatlab_lerobot  # noqa: F401  registers the flatlab env and policy types

    raw = json.loads(path.read_text())
    cfg = draccus.parse(config_class=TrainPipelineConfig, config_path=path, args=[])
    assert cfg.policy is not None and cfg.policy.type == raw["policy"]["type"]
    assert cfg.dataset.repo_id == raw["dataset"]["repo_id"]
    assert cfg.steps == raw.get("steps", cfg.steps)

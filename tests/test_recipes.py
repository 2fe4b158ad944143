"""Every training recipe in ``policies/`` (JSON for ``lerobot-train --config_path``) parses as lerobot's
``TrainPipelineConfig``, every collection recipe in ``datasets/`` loads, and the package finds both
through ``paths.py`` (so an installed wheel, which ships them, does too)."""

import json

import draccus
import pytest

from flatlab_lerobot.paths import DATASETS_DIR, POLICIES_DIR

RECIPES = sorted(POLICIES_DIR.glob("**/*.json"))


def test_there_are_recipes():
    assert any(p.relative_to(POLICIES_DIR).as_posix() == "act/tiny_rigid.json" for p in RECIPES), RECIPES


@pytest.mark.parametrize("path", RECIPES, ids=lambda p: p.relative_to(POLICIES_DIR).as_posix())
def test_recipe_parses_as_a_train_pipeline_config(path):
    import lerobot.policies  # noqa: F401  registers lerobot's policy types, as lerobot-train does
    from lerobot.configs.train import TrainPipelineConfig

    import flatlab_lerobot.lerobot_plugin  # noqa: F401  registers the flatlab env and policy types (as lerobot's CLIs do)

    raw = json.loads(path.read_text())
    cfg = draccus.parse(config_class=TrainPipelineConfig, config_path=path, args=[])
    assert cfg.policy is not None and cfg.policy.type == raw["policy"]["type"]
    assert cfg.dataset.repo_id == raw["dataset"]["repo_id"]
    assert cfg.steps == raw.get("steps", cfg.steps)


@pytest.mark.parametrize("path", sorted(DATASETS_DIR.glob("*.yaml")), ids=lambda p: p.name)
def test_collection_recipe_loads_by_path_and_by_name(path):
    from flatlab_lerobot.collect.recipe import load_recipe

    assert load_recipe(path).name == load_recipe(path.stem).name == load_recipe(f"datasets/{path.name}").name


def test_unknown_recipe_name_lists_the_shipped_ones():
    from flatlab_lerobot.collect.recipe import RecipeError, load_recipe

    with pytest.raises(RecipeError, match="no_such_recipe: recipe file not found .*tiny_rigid"):
        load_recipe("no_such_recipe")

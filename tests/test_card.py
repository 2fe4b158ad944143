"""The dataset card (``datasets/card_template.md`` rendered by ``collect.card.render_card``): it names
the recipe portably, lists only the modalities the dataset has, cites the paper and this project, and
``flatlab push --card-out`` writes it readable like any other file."""

import re
from pathlib import Path

import pytest
import yaml

from flatlab_lerobot.collect.recipe import load_recipe
from flatlab_lerobot.collect.card import render_card
from flatlab_lerobot.paths import CARD_TEMPLATE, DATASETS_DIR

CAMS = {"front": {"width": 64, "height": 64, "fx": 50.0, "fy": 50.0, "cx": 32.0, "cy": 32.0}}
RECORDS = [{"dataset_episode_index": 0, "seed": 0, "object_id": "ref_box", "strategy": "B", "num_frames": 3,
            "success": False, "failure_reason": "not_aloft"}]  # fmt: skip


def _card(recipe_path: Path) -> str:
    recipe = load_recipe(recipe_path)
    assert Path(recipe.source).is_absolute()  # what the collecting machine knows
    return render_card(recipe, {"recipe_source": recipe.source, "cameras": CAMS}, RECORDS)


def _absolute_paths(text: str) -> list[str]:
    """Absolute file paths in ``text`` (URLs do not count)."""
    return re.findall(r"(?<![\w:/.~-])(?:/[\w.~-]+){2,}", text)


def test_template_is_found_through_paths():
    assert CARD_TEMPLATE == DATASETS_DIR / "card_template.md" and CARD_TEMPLATE.is_file()


def test_card_has_no_absolute_path(tmp_path):
    card = _card(DATASETS_DIR / "tiny_rigid.yaml")
    assert not _absolute_paths(card), _absolute_paths(card)
    assert "--recipe datasets/tiny_rigid.yaml" in card
    outside = tmp_path / "elsewhere" / "my_recipe.yaml"  # a recipe outside the project: its name only
    outside.parent.mkdir()
    outside.write_text((DATASETS_DIR / "tiny_rigid.yaml").read_text())
    card = _card(outside)
    assert str(tmp_path) not in card and not _absolute_paths(card), _absolute_paths(card)
    assert "--recipe my_recipe.yaml" in card


@pytest.mark.parametrize("modalities", [["rgb", "pointcloud"], ["rgb", "depth"], ["rgb"]])
def test_card_names_only_the_modalities_the_dataset_has(tmp_path, modalities):
    raw = yaml.safe_load((DATASETS_DIR / "tiny_rigid.yaml").read_text())
    path = tmp_path / "r.yaml"
    path.write_text(yaml.safe_dump({**raw, "modalities": modalities}))
    card = _card(path)
    assert ("observation.depth." in card) == ("depth" in modalities)
    assert ("`observation.pointcloud`" in card) == ("pointcloud" in modalities)


def test_card_cites_the_paper_and_the_project():
    card = _card(DATASETS_DIR / "tiny_rigid.yaml")
    assert "## Citation" in card and card.count("```bibtex") == 2
    assert "FlatLab: A Unified Methodology Framework and Simulation-Based Benchmark" in card
    assert "Zhu, Xingyu" in card and "Gao, Yixing" in card and "@software{flatlab_lerobot" in card

"""Where the package's declarative content lives.

``envs/`` (objects, scenes, materials, robot), ``datasets/`` (collection recipes and the dataset-card
template) and ``policies/`` (lerobot-train recipes) sit next to the package in a source checkout and
are shipped inside the wheel as ``flatlab_lerobot/_data/<name>`` (see pyproject.toml), so a plain
``pip install`` finds them too.
"""

from __future__ import annotations

import os
from pathlib import Path

_PKG = Path(__file__).resolve().parent


def _find(name: str) -> Path:
    for candidate in (_PKG.parent / name, _PKG / "_data" / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"FlatLab data folder '{name}/' not found next to {_PKG}")


ENVS_DIR: Path = Path(os.environ.get("FLATLAB_ENVS_DIR", "")) if os.environ.get("FLATLAB_ENVS_DIR") else _find("envs")
DATASETS_DIR: Path = _find("datasets")  # collection recipes (*.yaml) and card_template.md
POLICIES_DIR: Path = _find("policies")  # lerobot-train recipes (*.json, for --config_path)
CARD_TEMPLATE: Path = DATASETS_DIR / "card_template.md"
OUTPUTS_DIR: Path = Path(os.environ.get("FLATLAB_OUTPUTS", "outputs"))


def portable_name(path: str | Path) -> str:
    """How to name ``path`` to someone on another machine: relative to the project (the folder
    holding ``envs/``, ``datasets/`` ...) when it lies inside it, else relative to the working
    directory when inside that, else just its file name -- never an absolute path of this machine."""
    p = Path(path)
    if not p.is_absolute():
        return p.as_posix()
    p = p.resolve()
    for base in (_PKG.parent, _PKG / "_data", Path.cwd().resolve()):
        if p.is_relative_to(base):
            return p.relative_to(base).as_posix()
    return p.name

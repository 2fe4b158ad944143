"""Where the package's declarative content lives.

``envs/`` (objects, scenes, materials, robot) sits next to the package in a source checkout and
is shipped inside the wheel as ``flatlab_lerobot/_data/envs`` (see pyproject.toml), so a plain
``pip install`` finds it too.
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
OUTPUTS_DIR: Path = Path(os.environ.get("FLATLAB_OUTPUTS", "outputs"))

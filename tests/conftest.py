"""Shared pytest setup.  MuJoCo picks its GL backend when first imported, so the headless EGL
backend is selected here, before any test module imports mujoco."""

import importlib.util
import os
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])


@pytest.fixture
def tiny_scene_catalog(tmp_path):
    """A one-material (oak, friction 0.4) materials folder and a scenes folder holding one scene
    's1' (Study desk, 0.6 x 0.9 m, 0.75 m high, 3 cm thick) plus ``extra`` fields.  Returns
    ``(scenes_dir, materials_dir, scene_yaml_text)``; tests rewrite ``scenes_dir / 's.yaml'``."""

    def write(extra: str) -> tuple:
        mats = tmp_path / "materials"
        mats.mkdir()
        (mats / "m.yaml").write_text("materials:\n  - {id: oak, name: oak, friction: 0.4, rgba: [0.6, 0.4, 0.3, 1]}\n")
        scenes = tmp_path / "scenes"
        scenes.mkdir()
        good = ("scenes:\n  - {id: s1, room: Study, name: desk, table_size: [0.6, 0.9], table_height: 0.75,"
                f" table_thickness: 0.03, {extra}}}\n")  # fmt: skip
        (scenes / "s.yaml").write_text(good)
        return scenes, mats, good

    return write


@pytest.fixture
def script():
    """A loader of ``scripts/<name>.py`` as a module (the scripts folder is not a package)."""

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / "scripts" / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    return load

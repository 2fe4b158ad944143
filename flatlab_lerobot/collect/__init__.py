"""Dataset collection (``flatlab collect --recipe datasets/<recipe>.yaml``).

* :mod:`.recipe`: the typed YAML recipe (:func:`load_recipe`, :class:`RecipeError`),
* :mod:`.runner`: one expert episode -> labelled LeRobot frames,
* :mod:`.writer`: LeRobotDataset v3 features, video encoding (in the workers), crash-safe commits,
  camera meta, dataset card,
* :mod:`.collector`: the worker pool, the in-order resumable loop and the CLI entry point :func:`main`.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless; must be set before mujoco is imported
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])


def main(argv=None) -> int:
    from flatlab_lerobot.collect.collector import main as _main

    return _main(argv)


__all__ = ["main"]

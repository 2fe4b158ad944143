"""Dataset collection (``flatlab collect --recipe datasets/<recipe>.yaml``).

* :mod:`.recipe`: the typed YAML recipe (:func:`load_recipe`, :class:`RecipeError`),
* :mod:`.runner`: one expert episode -> labelled LeRobot frames,
* :mod:`.features`: the LeRobotDataset features and camera metadata (depth -> clouds),
* :mod:`.video`: camera streams -> MP4s, encoded in the workers,
* :mod:`.store`: the dataset store with crash-safe, resumable commits,
* :mod:`.card`: the dataset card (``datasets/card_template.md``),
* :mod:`.hub`: ``flatlab push``,
* :mod:`.collector`: the worker pool, the in-order resumable loop and the CLI entry point :func:`main`.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless; must be set before mujoco is imported
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])


def main(argv=None) -> int:
    from flatlab_lerobot.collect.collector import main as _main

    return _main(argv)


__all__ = ["main"]

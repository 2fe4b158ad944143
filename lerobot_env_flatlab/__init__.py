"""Discovery shim for LeRobot's CLIs.

lerobot-train / lerobot-eval import every installed distribution whose metadata Name starts with
``lerobot_env_`` (the Name must equal a top-level package).  This is that package; all code lives
in :mod:`flatlab_lerobot`, whose import registers the ``flatlab`` env and our policy types.
"""

from flatlab_lerobot.lerobot_plugin import register  # noqa: F401  (import side effect: registration)

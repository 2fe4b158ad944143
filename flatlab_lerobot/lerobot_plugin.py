"""Registers FlatLab with LeRobot: the ``flatlab`` EnvConfig and our policy types.

Imported by the discovery shim ``lerobot_env_flatlab`` (which lerobot's CLIs import on their own).
"""


def register() -> None:
    """Import the modules whose import registers the env and policy configs (idempotent)."""


register()

"""Registers FlatLab with LeRobot: the ``flatlab`` EnvConfig, the gym id and our policy types.

Imported by the discovery shim ``lerobot_env_flatlab`` (which lerobot's CLIs import on their own).
"""


def register() -> None:
    """Import the modules whose import registers the env and policy configs (idempotent)."""
    import flatlab_lerobot.env
    import flatlab_lerobot.lerobot_env
    import flatlab_lerobot.policies.scripted.configuration_flatlab_scripted  # noqa: F401  "flatlab_scripted"
    import flatlab_lerobot.policies.strategy.configuration_flatlab_strategy  # noqa: F401  "flatlab_strategy"
    import flatlab_lerobot.policies.executor.configuration_flatlab_executor  # noqa: F401  "flatlab_executor"
    import flatlab_lerobot.policies.dp3.configuration_flatlab_dp3  # noqa: F401  "flatlab_dp3"
    import flatlab_lerobot.policies.unified.configuration_flatlab_unified  # noqa: F401  "flatlab_unified"


register()

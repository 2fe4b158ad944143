"""``flatlab_scripted``: the scripted expert (strategies A/B/C) as a LeRobot policy type."""

from flatlab_lerobot.policies.scripted.configuration_flatlab_scripted import FlatLabScriptedConfig

__all__ = ["FlatLabScriptedConfig"]

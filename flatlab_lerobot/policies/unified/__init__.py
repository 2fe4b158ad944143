"""``flatlab_unified``: the learned strategy generator + action execution module as one LeRobot policy
(per step: strategy from the object cloud, then each primitive's poses from the scene cloud, executed
by the expert's primitive runner)."""

from flatlab_lerobot.policies.unified.configuration_flatlab_unified import FlatLabUnifiedConfig

__all__ = ["FlatLabUnifiedConfig"]

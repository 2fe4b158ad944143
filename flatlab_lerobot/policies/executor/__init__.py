"""``flatlab_executor``: the action execution module (PointNet++ scene encoder -> primitive poses)."""

from flatlab_lerobot.policies.executor.configuration_flatlab_executor import FlatLabExecutorConfig

__all__ = ["FlatLabExecutorConfig"]

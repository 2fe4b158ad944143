"""``flatlab_strategy``: the learned strategy generator (PointNet + MLP head, CE + NT-Xent) as a
LeRobot policy type, trained by ``lerobot-train`` on ``flatlab strategy-export`` datasets."""

from flatlab_lerobot.policies.strategy.configuration_flatlab_strategy import FlatLabStrategyConfig

__all__ = ["FlatLabStrategyConfig"]

"""``flatlab_dp3``: 3D Diffusion Policy (DP3) as a LeRobot policy type, the point-cloud end-to-end
baseline; trained by ``lerobot-train`` on ``flatlab collect`` datasets (see docs/baselines.md)."""

from flatlab_lerobot.policies.dp3.configuration_flatlab_dp3 import FlatLabDP3Config

__all__ = ["FlatLabDP3Config"]

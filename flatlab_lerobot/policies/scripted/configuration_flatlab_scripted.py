"""Config of the ``flatlab_scripted`` policy type (``--policy.type=flatlab_scripted``).

The policy needs no training and no checkpoint.  ``strategy``:

* ``"A"``, ``"B"`` or ``"C"``: always run that strategy;
* ``"auto"`` (default): per episode, from the first ``observation.environment_state``:
  **C** if the deformable flag (index 10) is set, else **B** if the object's thickness (size z,
  index 9) is >= ``thick_threshold`` (0.04 m), else **A**.

It reads ``observation.state`` (16,), ``observation.environment_state`` (14,) and ``observation.cell``
(7,: the cell's table and arm-base calibration, from which it builds its kinematic model) *un-normalized*:
its processors have no normalizer step, and ``normalization_mapping`` is IDENTITY everywhere.

``b_right_half_turn``: the expert's option of that name (``strategies.expert.ExpertOptions``): B's right
hand posed a half turn about its approach axis, so its wrist stays inside its range.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, NormalizationMode, PreTrainedConfig
from lerobot.optim import AdamConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE

from flatlab_lerobot.lerobot_env import OBS_CELL
from flatlab_lerobot.policies import identity_normalization


@PreTrainedConfig.register_subclass("flatlab_scripted")
@dataclass
class FlatLabScriptedConfig(PreTrainedConfig):
    strategy: str = "auto"  # "auto" | "A" | "B" | "C"
    thick_threshold: float = 0.04  # m: "auto" picks B for objects at least this thick
    control_dt: float = 0.1  # s: must match the env's 1/fps
    b_right_half_turn: bool = False  # ExpertOptions.b_right_half_turn
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=identity_normalization)

    def __post_init__(self):
        super().__post_init__()
        if self.strategy not in ("auto", "A", "B", "C"):
            raise ValueError(f"strategy must be auto|A|B|C, got {self.strategy!r}")

    @property
    def observation_delta_indices(self) -> None:
        return None

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamConfig:
        return AdamConfig(lr=0.0)

    def get_scheduler_preset(self) -> None:
        return None

    def validate_features(self) -> None:
        feats = self.input_features or {}
        for key in (OBS_STATE, OBS_ENV_STATE, OBS_CELL):
            if feats and key not in feats:
                raise ValueError(f"flatlab_scripted needs input feature {key!r} (got {sorted(feats)})")
        act = (self.output_features or {}).get(ACTION)
        if act is not None and tuple(act.shape) != (16,):
            raise ValueError(
                f"flatlab_scripted outputs joint targets (16,), env wants {tuple(act.shape)}: use action_mode=joint"
            )
        if act is not None and act.type is not FeatureType.ACTION:
            raise ValueError("action feature must be of type ACTION")

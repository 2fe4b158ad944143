"""``FlatLabScriptedPolicy``: one :class:`~flatlab_lerobot.strategies.Expert` episode generator per
batch element, fed from ``observation.state`` and ``observation.environment_state``.  The expert's
kinematic model is the cell the env observes (``observation.cell``: table height and size, arm
bases), so it plans in the scene it is evaluated in."""

from __future__ import annotations

import numpy as np
import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import OBS_ENV_STATE, OBS_STATE
from torch import Tensor

from flatlab_lerobot.lerobot_env import OBS_CELL
from flatlab_lerobot.policies.scripted.configuration_flatlab_scripted import FlatLabScriptedConfig
from flatlab_lerobot.sim.core import ENV_STATE_INDEX
from flatlab_lerobot.strategies.expert import ExpertCache, ExpertOptions


def pick_strategy(env_state, thick_threshold: float = 0.04) -> str:
    """The ``auto`` rule: C if deformable, else B if thickness >= threshold, else A."""
    v = np.asarray(env_state, dtype=float)
    if v[ENV_STATE_INDEX["deformable"]] > 0.5:
        return "C"
    return "B" if v[ENV_STATE_INDEX["obj_size_z"]] >= thick_threshold else "A"


class _Episode:
    """One batch element's expert and generator; ``obs`` is updated before each ``next``."""

    def __init__(self, expert, strategy: str):
        self.strategy = strategy
        self.obs = (None, None)
        self.stage = None
        self.gen = expert.episode(strategy, lambda: self.obs)

    def act(self, agent_pos: np.ndarray, env_state: np.ndarray) -> np.ndarray:
        self.obs = (agent_pos, env_state)
        self.stage, _, action = next(self.gen)
        return action


class FlatLabScriptedPolicy(PreTrainedPolicy):
    config_class = FlatLabScriptedConfig
    name = "flatlab_scripted"

    def __init__(self, config: FlatLabScriptedConfig, dataset_stats=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config = config
        self._experts = ExpertCache(config.control_dt, ExpertOptions(b_right_half_turn=config.b_right_half_turn))
        self._episodes: list[_Episode] | None = None

    def _expert(self, i: int, cell: np.ndarray | None):
        """Batch element ``i``'s expert for the cell with calibration ``cell`` (None: the default cell)."""
        return self._experts.get(i, cell)

    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self):
        self._episodes = None

    @property
    def stages(self) -> list[str | None]:
        return [e.stage for e in self._episodes or []]

    @property
    def strategies(self) -> list[str]:
        return [e.strategy for e in self._episodes or []]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        state = batch[OBS_STATE]
        env_state = batch[OBS_ENV_STATE]
        if state.dim() == 1:
            state, env_state = state.unsqueeze(0), env_state.unsqueeze(0)
        s = state.detach().cpu().numpy().astype(np.float64)
        e = env_state.detach().cpu().numpy().astype(np.float64)
        cells = batch.get(OBS_CELL)
        if cells is not None:
            cells = cells.reshape(len(s), -1).detach().cpu().numpy()
        if self._episodes is None or len(self._episodes) != len(s):
            self._episodes = []
            for i in range(len(s)):
                strat = self.config.strategy
                if strat == "auto":
                    strat = pick_strategy(e[i], self.config.thick_threshold)
                self._episodes.append(_Episode(self._expert(i, None if cells is None else cells[i]), strat))
        actions = np.stack([ep.act(s[i], e[i]) for i, ep in enumerate(self._episodes)])
        return torch.as_tensor(actions, dtype=torch.float32, device=state.device)

    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        return self.select_action(batch).unsqueeze(1)

    def forward(self, batch: dict[str, Tensor]):
        raise NotImplementedError("flatlab_scripted is a scripted expert: it has nothing to train")

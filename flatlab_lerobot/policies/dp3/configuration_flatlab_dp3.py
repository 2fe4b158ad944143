"""Config of the ``flatlab_dp3`` policy type (``--policy.type=flatlab_dp3``): 3D Diffusion Policy
(DP3, Ze et al., RSS 2024) as a LeRobot policy, the point-cloud baseline of the FlatLab paper's
Table 1.  Named ``flatlab_dp3`` so that it never collides with a ``dp3`` lerobot may ship later.

Inputs (``validate_features`` keeps these and drops every other feature, so the privileged
``observation.environment_state`` never reaches the model):

* ``pointcloud_key`` (default ``observation.pointcloud``: the env's world-frame scene cloud, N x 3).
  Inside the model each cloud is cropped to the box [``crop_min``, ``crop_max``] (world frame, m;
  the default covers the table top and 0.6 m above it in every FlatLab scene), reduced to
  ``n_points`` by farthest-point sampling (``fpsample``, deterministic start) and mapped from that
  box into [-1, 1]^3 -- DP3's crop + FPS + limits normalization, done in the model so the env's raw
  cloud works as is.  lerobot's normalizer never sees the cloud (its per-point-index statistics mean
  nothing for an unordered set).
* ``observation.state`` (16: joints + gripper widths), and with ``use_ee_pose`` also
  ``observation.ee_pose`` (14), min-max normalized to [-1, 1] by the processor.

Model (the DP3 paper, Sec. 3 / App.): point encoder = per-point MLP 3 -> 64 -> 128 -> 256 with
LayerNorm + ReLU after each layer, max-pool over points, projection Linear(256 -> 64) + LayerNorm;
state MLP state_dim -> 64 -> 64 (ReLU between); per observation step the 64 + 64 features are
concatenated, over ``n_obs_steps`` steps flattened into the U-Net's global condition.  Decoder:
lerobot's ``DiffusionConditionalUnet1d`` (FiLM scale + bias; DP3's ``down_dims`` 512/1024/2048,
``preset="simple"`` Simple-DP3's 128/256/384).  Noise: DDIM, 100 training steps, 10 inference steps,
squared-cosine betas, ``prediction_type="sample"``, clipped to [-1, 1] (DP3's scheduler settings).
Horizon 4, 2 observation steps, 3 action steps executed per inference (DP3's defaults).

Not in this port: DP3's EMA of the weights (lerobot-train keeps no EMA) and point colours.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, NormalizationMode, PreTrainedConfig
from lerobot.optim import AdamWConfig
from lerobot.optim.schedulers import DiffuserSchedulerConfig
from lerobot.utils.constants import ACTION, OBS_STATE

from flatlab_lerobot.lerobot_env import OBS_EE_POSE, OBS_POINTCLOUD

PRESETS = {"dp3": (512, 1024, 2048), "simple": (128, 256, 384)}  # the U-Net widths of DP3 / Simple-DP3
POINTCLOUD_KEYS = (OBS_POINTCLOUD, "observation.object_pointcloud")
# Crop box (world frame, m) covering every FlatLab scene's table top (0.5-0.7 x 0.9-1.0 m, 0.65-0.9 m
# high) and the arms' working height above it; the env has already cropped to its own table.
DEFAULT_CROP_MIN = (-0.45, -0.6, 0.6)
DEFAULT_CROP_MAX = (0.6, 0.6, 1.55)


@PreTrainedConfig.register_subclass("flatlab_dp3")
@dataclass
class FlatLabDP3Config(PreTrainedConfig):
    # Inputs / output structure (DP3: horizon 4, 2 observation steps, 3 action steps).
    n_obs_steps: int = 2
    horizon: int = 4
    n_action_steps: int = 3
    drop_n_last_frames: int = 0  # horizon - n_action_steps - n_obs_steps + 1 (lerobot's episode-aware sampler)

    pointcloud_key: str = OBS_POINTCLOUD
    use_ee_pose: bool = False  # also condition on observation.ee_pose (14) through the state MLP
    n_points: int = 512  # after the crop, by farthest-point sampling (DP3: 512 or 1024)
    use_point_crop: bool = True
    crop_min: list[float] = field(default_factory=lambda: list(DEFAULT_CROP_MIN))
    crop_max: list[float] = field(default_factory=lambda: list(DEFAULT_CROP_MAX))

    # Encoder (the DP3 paper's).
    encoder_channels: list[int] = field(default_factory=lambda: [64, 128, 256])
    encoder_output_dim: int = 64
    state_mlp: list[int] = field(default_factory=lambda: [64, 64])

    # U-Net (lerobot's DiffusionConditionalUnet1d reads these fields).
    preset: str = "dp3"  # "dp3" | "simple": down_dims when down_dims is not given
    down_dims: list[int] | None = None
    kernel_size: int = 5
    n_groups: int = 8
    diffusion_step_embed_dim: int = 128
    use_film_scale_modulation: bool = True
    gradient_checkpointing: bool = False

    # Noise scheduler: DDIM as DP3.
    num_train_timesteps: int = 100
    num_inference_steps: int = 10
    beta_schedule: str = "squaredcos_cap_v2"
    beta_start: float = 0.0001
    beta_end: float = 0.02
    prediction_type: str = "sample"
    clip_sample: bool = True
    clip_sample_range: float = 1.0
    do_mask_loss_for_padding: bool = False

    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.MIN_MAX,
            "ENV": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )

    # Training presets (DP3: AdamW 1e-4, betas 0.95/0.999, wd 1e-6, cosine with 500 warm-up steps).
    optimizer_lr: float = 1e-4
    optimizer_betas: tuple[float, float] = (0.95, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-6
    scheduler_name: str = "cosine"
    scheduler_warmup_steps: int = 500

    def __post_init__(self):
        super().__post_init__()
        if self.preset not in PRESETS:
            raise ValueError(f"--policy.preset: must be one of {list(PRESETS)}, got {self.preset!r}")
        if self.down_dims is None:
            self.down_dims = list(PRESETS[self.preset])
        self.down_dims = [int(d) for d in self.down_dims]
        if self.pointcloud_key not in POINTCLOUD_KEYS:
            raise ValueError(f"--policy.pointcloud_key: must be one of {list(POINTCLOUD_KEYS)}, got {self.pointcloud_key!r}")
        if self.prediction_type not in ("epsilon", "sample"):
            raise ValueError(f"--policy.prediction_type: 'epsilon' or 'sample', got {self.prediction_type!r}")
        for name in ("n_obs_steps", "horizon", "n_action_steps", "n_points", "encoder_output_dim",
                     "num_train_timesteps", "num_inference_steps"):  # fmt: skip
            if int(getattr(self, name)) < 1:
                raise ValueError(f"--policy.{name}: must be >= 1, got {getattr(self, name)!r}")
        if self.n_action_steps > self.horizon - self.n_obs_steps + 1:
            raise ValueError(
                f"--policy.n_action_steps={self.n_action_steps}: at most horizon - n_obs_steps + 1 = "
                f"{self.horizon - self.n_obs_steps + 1} (the actions after the current observation)"
            )
        factor = 2 ** (len(self.down_dims) - 1)  # the U-Net halves the horizon at every level but the last
        if self.horizon % factor:
            raise ValueError(f"--policy.horizon={self.horizon}: must be a multiple of {factor} for down_dims={self.down_dims}")
        if any(d % self.n_groups for d in self.down_dims):
            raise ValueError(f"--policy.down_dims={self.down_dims}: each a multiple of n_groups={self.n_groups}")
        if not self.encoder_channels or not self.state_mlp:
            raise ValueError("--policy.encoder_channels / --policy.state_mlp: non-empty lists")
        if len(self.crop_min) != 3 or len(self.crop_max) != 3 or any(a >= b for a, b in zip(self.crop_min, self.crop_max)):
            raise ValueError(f"--policy.crop_min / crop_max: two xyz lists with min < max, got {self.crop_min}, {self.crop_max}")
        if self.num_inference_steps > self.num_train_timesteps:
            raise ValueError("--policy.num_inference_steps: at most num_train_timesteps")

    # ------------------------------------------------------------------ lerobot API
    @property
    def observation_delta_indices(self) -> list[int]:
        return list(range(1 - self.n_obs_steps, 1))

    @property
    def action_delta_indices(self) -> list[int]:
        return list(range(1 - self.n_obs_steps, 1 - self.n_obs_steps + self.horizon))

    @property
    def reward_delta_indices(self) -> None:
        return None

    @property
    def state_keys(self) -> list[str]:
        return [OBS_STATE, OBS_EE_POSE] if self.use_ee_pose else [OBS_STATE]

    @property
    def state_dim(self) -> int:
        return sum(int(self.input_features[k].shape[0]) for k in self.state_keys)

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(
            lr=self.optimizer_lr, betas=self.optimizer_betas, eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
        )  # fmt: skip

    def get_scheduler_preset(self) -> DiffuserSchedulerConfig:
        return DiffuserSchedulerConfig(name=self.scheduler_name, num_warmup_steps=self.scheduler_warmup_steps)

    def validate_features(self) -> None:
        """Keep only the cloud and the state inputs (never ``observation.environment_state``, the
        images or anything else the dataset holds) and check their shapes."""
        feats = self.input_features or {}
        if feats:
            need = [self.pointcloud_key, *self.state_keys]
            missing = [k for k in need if k not in feats]
            if missing:
                raise ValueError(
                    f"flatlab_dp3: the data has no {missing} (has {sorted(feats)}); collect with the "
                    f"'pointcloud'{' and ee_pose' if self.use_ee_pose else ''} modalities"
                )
            self.input_features = {k: feats[k] for k in need}
            pc = feats[self.pointcloud_key]
            if len(pc.shape) != 2 or pc.shape[-1] < 3:
                raise ValueError(f"flatlab_dp3: {self.pointcloud_key} has shape {tuple(pc.shape)}; expected (N, 3)")
            for k in self.state_keys:
                if len(feats[k].shape) != 1:
                    raise ValueError(f"flatlab_dp3: {k} has shape {tuple(feats[k].shape)}; expected a vector")
        act = (self.output_features or {}).get(ACTION)
        if act is not None and (act.type is not FeatureType.ACTION or len(act.shape) != 1):
            raise ValueError(f"flatlab_dp3: 'action' must be a vector of type ACTION, got {act.type} {tuple(act.shape)}")

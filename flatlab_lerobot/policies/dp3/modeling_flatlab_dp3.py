"""``FlatLabDP3Policy``: 3D Diffusion Policy on the scene cloud and proprioception.  See
:mod:`.configuration_flatlab_dp3` for the inputs, the encoder and the diffusion settings.

The observation / action queues follow lerobot's own ``DiffusionPolicy``: ``n_obs_steps`` observations
are kept (the first copied to fill the queue), one inference denoises ``horizon`` actions starting at
the oldest observation, and the ``n_action_steps`` from the current step on are executed."""

from __future__ import annotations

from collections import deque

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.policies.utils import populate_queues
from lerobot.utils.constants import ACTION
from torch import Tensor, nn

from flatlab_lerobot.policies.dp3.configuration_flatlab_dp3 import FlatLabDP3Config


# ------------------------------------------------------------------------------ point clouds
def fps_indices(points: np.ndarray, n: int) -> np.ndarray:
    """Indices of ``n`` of ``points`` (K, 3): farthest-point sampling from point 0 when K > n (so the
    same cloud always gives the same points), every point once plus repeats of the first when K <= n."""
    import fpsample

    k = len(points)
    if k > n:
        h = int(np.clip(np.log2(k) - 8, 3, 9))  # KD-tree height: buckets of 2**h points
        return np.asarray(fpsample.bucket_fps_kdline_sampling(points, n, h=h, start_idx=0), np.int64)
    return np.resize(np.arange(k), n)


def prepare_clouds(clouds: Tensor, n_points: int, lo, hi, crop: bool = True) -> Tensor:
    """(..., N, C>=3) world-frame clouds -> (..., n_points, 3) in [-1, 1]^3: xyz only, cropped to the
    box [lo, hi] (when ``crop``), farthest-point sampled, then mapped from the box to [-1, 1].  A cloud
    with no point in the box becomes zeros (the box centre)."""
    lead = clouds.shape[:-2]
    flat = clouds[..., :3].detach().reshape(-1, clouds.shape[-2], 3).to("cpu", torch.float64).numpy()
    lo_a, hi_a = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    out = np.zeros((len(flat), n_points, 3), np.float32)
    for i, p in enumerate(flat):
        if crop:
            p = p[np.all((p >= lo_a) & (p <= hi_a), axis=1)]
        if len(p) == 0:
            continue
        p = np.ascontiguousarray(p[fps_indices(p, n_points)])
        out[i] = 2.0 * (p - lo_a) / (hi_a - lo_a) - 1.0
    return torch.from_numpy(out).to(clouds.device).reshape(*lead, n_points, 3)


# ------------------------------------------------------------------------------ encoder
class DP3PointEncoder(nn.Module):
    """DP3's point encoder: per point Linear + LayerNorm + ReLU per channel count (3 -> 64 -> 128 -> 256),
    a max-pool over the points, then Linear(256 -> out_dim) + LayerNorm.  (B, N, 3) -> (B, out_dim)."""

    def __init__(self, channels: list[int], out_dim: int, in_dim: int = 3):
        super().__init__()
        layers, c_in = [], in_dim
        for c in channels:
            layers += [nn.Linear(c_in, c), nn.LayerNorm(c), nn.ReLU()]
            c_in = c
        self.mlp = nn.Sequential(*layers)
        self.projection = nn.Sequential(nn.Linear(c_in, out_dim), nn.LayerNorm(out_dim))
        self.out_dim = out_dim

    def forward(self, x: Tensor) -> Tensor:
        return self.projection(self.mlp(x).amax(dim=-2))


def state_mlp(in_dim: int, sizes: list[int]) -> nn.Sequential:
    """DP3's state MLP: Linear layers of ``sizes`` with ReLU between (none after the last)."""
    layers, c_in = [], in_dim
    for i, c in enumerate(sizes):
        layers.append(nn.Linear(c_in, c))
        if i < len(sizes) - 1:
            layers.append(nn.ReLU())
        c_in = c
    return nn.Sequential(*layers)


class DP3Encoder(nn.Module):
    """One observation step -> the concatenated cloud and state features (B, out_dim)."""

    def __init__(self, config: FlatLabDP3Config):
        super().__init__()
        self.point_encoder = DP3PointEncoder(list(config.encoder_channels), config.encoder_output_dim)
        self.state_mlp = state_mlp(config.state_dim, list(config.state_mlp))
        self.out_dim = config.encoder_output_dim + int(config.state_mlp[-1])

    def forward(self, cloud: Tensor, state: Tensor) -> Tensor:
        return torch.cat([self.point_encoder(cloud), self.state_mlp(state)], dim=-1)


# ------------------------------------------------------------------------------ policy
class FlatLabDP3Policy(PreTrainedPolicy):
    config_class = FlatLabDP3Config
    name = "flatlab_dp3"

    def __init__(self, config: FlatLabDP3Config, dataset_stats=None, **kwargs):
        from diffusers.schedulers.scheduling_ddim import DDIMScheduler

        super().__init__(config)
        config.validate_features()
        self.config = config
        self.encoder = DP3Encoder(config)
        # lerobot's conditional 1-D U-Net reads down_dims, kernel_size, n_groups, diffusion_step_embed_dim,
        # use_film_scale_modulation, gradient_checkpointing and action_feature from our config.
        self.unet = DiffusionConditionalUnet1d(config, global_cond_dim=self.encoder.out_dim * config.n_obs_steps)
        self.noise_scheduler = DDIMScheduler(
            num_train_timesteps=config.num_train_timesteps, beta_start=config.beta_start, beta_end=config.beta_end,
            beta_schedule=config.beta_schedule, clip_sample=config.clip_sample,
            clip_sample_range=config.clip_sample_range, set_alpha_to_one=True, steps_offset=0,
            prediction_type=config.prediction_type,
        )  # fmt: skip
        self._queues: dict[str, deque] = {}
        self.reset()

    # ------------------------------------------------------------------ lerobot API
    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self):
        """Empty the observation and action queues (at every env reset)."""
        n = self.config.n_obs_steps
        self._queues = {k: deque(maxlen=n) for k in (self.config.pointcloud_key, *self.config.state_keys)}
        self._queues[ACTION] = deque(maxlen=self.config.n_action_steps)

    # ------------------------------------------------------------------ conditioning
    def global_condition(self, batch: dict[str, Tensor]) -> Tensor:
        """(B, n_obs_steps * encoder.out_dim) from the cloud (B, T, N, 3) and state (B, T, D) inputs."""
        cfg = self.config
        for k in (cfg.pointcloud_key, *cfg.state_keys):
            if k not in batch:
                raise KeyError(f"flatlab_dp3: the batch has no {k!r}; keys: {sorted(batch)}")
        cloud = batch[cfg.pointcloud_key]
        state = torch.cat([batch[k] for k in cfg.state_keys], dim=-1)
        if state.dim() == 2:  # (B, D): one observation step
            cloud, state = cloud.unsqueeze(1), state.unsqueeze(1)
        b, t = state.shape[:2]
        if t != cfg.n_obs_steps:
            raise ValueError(f"flatlab_dp3: {t} observation steps in the batch, the config has n_obs_steps={cfg.n_obs_steps}")
        pts = prepare_clouds(cloud, cfg.n_points, cfg.crop_min, cfg.crop_max, cfg.use_point_crop)
        pts = pts.to(dtype=state.dtype)
        feats = self.encoder(pts.reshape(b * t, *pts.shape[2:]), state.reshape(b * t, -1))
        return feats.reshape(b, -1)

    # ------------------------------------------------------------------ inference
    @torch.no_grad()
    def conditional_sample(self, global_cond: Tensor, noise: Tensor | None = None, generator=None) -> Tensor:
        cfg = self.config
        b = global_cond.shape[0]
        sample = noise if noise is not None else torch.randn(
            (b, cfg.horizon, cfg.action_feature.shape[0]), dtype=global_cond.dtype, device=global_cond.device,
            generator=generator)  # fmt: skip
        self.noise_scheduler.set_timesteps(cfg.num_inference_steps)
        for t in self.noise_scheduler.timesteps:
            out = self.unet(sample, torch.full((b,), int(t), dtype=torch.long, device=sample.device), global_cond=global_cond)
            sample = self.noise_scheduler.step(out, t, sample, generator=generator).prev_sample
        return sample

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """(B, n_action_steps, action_dim) normalized actions from the current step on.  With filled
        queues (during a rollout) they are the inputs; otherwise ``batch`` (B, n_obs_steps, ...) is."""
        if any(len(self._queues[k]) for k in self._queues if k != ACTION):
            batch = {k: torch.stack(list(q), dim=1) for k, q in self._queues.items() if k != ACTION}
        actions = self.conditional_sample(self.global_condition(batch), noise=noise)
        start = self.config.n_obs_steps - 1
        return actions[:, start : start + self.config.n_action_steps]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """One (B, action_dim) action; a new chunk is denoised every ``n_action_steps`` calls."""
        batch = {k: v for k, v in batch.items() if k in self._queues and k != ACTION}
        self._queues = populate_queues(self._queues, batch)
        if len(self._queues[ACTION]) == 0:
            self._queues[ACTION].extend(self.predict_action_chunk(batch, noise=noise).transpose(0, 1))
        return self._queues[ACTION].popleft()

    # ------------------------------------------------------------------ training
    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Diffusion loss of a batch: inputs (B, n_obs_steps, ...), ``action`` (B, horizon, D)."""
        cfg = self.config
        global_cond = self.global_condition(batch)
        traj = batch[ACTION]
        if traj.shape[1] != cfg.horizon:
            raise ValueError(f"flatlab_dp3: {traj.shape[1]} actions per sample, the config has horizon={cfg.horizon}")
        eps = torch.randn_like(traj)
        t = torch.randint(0, cfg.num_train_timesteps, (traj.shape[0],), device=traj.device).long()
        noisy = self.noise_scheduler.add_noise(traj, eps, t)
        pred = self.unet(noisy, t, global_cond=global_cond)
        target = eps if cfg.prediction_type == "epsilon" else traj
        loss = F.mse_loss(pred, target, reduction="none")
        if cfg.do_mask_loss_for_padding and "action_is_pad" in batch:
            mask = (~batch["action_is_pad"].bool()).unsqueeze(-1)
            loss = (loss * mask).sum() / (mask.sum() * loss.shape[-1]).clamp_min(1)
        else:
            loss = loss.mean()
        return loss, {"loss": float(loss.detach())}

"""``FlatLabStrategyPolicy``: PointNet (or, for ablation A-7, a small CNN) -> F -> MLP head -> 3
strategy logits, trained with cross-entropy + lambda * NT-Xent (paper §3.2).  See
:mod:`.configuration_flatlab_strategy` for the inputs, the loss and the switches."""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION
from torch import Tensor, nn

from flatlab_lerobot.policies import distinct_indices, fps_indices, seen_points
from flatlab_lerobot.policies.strategy.configuration_flatlab_strategy import FlatLabStrategyConfig

STRATEGY_LETTERS = ("A", "B", "C")


def normalize_cloud(cloud: Tensor, return_radius: bool = False):
    """(..., N, 3): centred on the mean, divided by the largest point norm (unit sphere); with
    ``return_radius`` also that norm (..., ) in the cloud's units."""
    c = cloud - cloud.mean(dim=-2, keepdim=True)
    r = c.norm(dim=-1).amax(dim=-1, keepdim=True).clamp_min(1e-8)
    out = c / r.unsqueeze(-1)
    return (out, r.squeeze(-1)) if return_radius else out


def cloud_extents(cloud: Tensor) -> Tensor:
    """(B, N, 3) metric clouds (z up) -> (B, 3) extents in the cloud's units: the vertical one
    (max z - min z: an object's thickness when the side cameras see its sides), then the
    horizontal ones along the principal axes of the xy points, longest first.  Invariant to
    translation and to turns about z."""
    z = cloud[..., 2]
    ez = z.amax(dim=1) - z.amin(dim=1)
    xy = cloud[..., :2] - cloud[..., :2].mean(dim=1, keepdim=True)
    cov = xy.transpose(1, 2) @ xy / xy.shape[1]
    _, vec = torch.linalg.eigh(cov)  # ascending eigenvalues: column 1 is the long axis
    proj = xy @ vec
    ext = proj.amax(dim=1) - proj.amin(dim=1)  # (B, 2): short, long
    return torch.stack([ez, ext[:, 1], ext[:, 0]], dim=1)


class PointNetEncoder(nn.Module):
    """Shared point-wise MLP (Conv1d k=1 + BatchNorm + ReLU) and a global max pool: (B, N, 3) -> (B, C)."""

    def __init__(self, channels: list[int], in_dim: int = 3):
        super().__init__()
        layers, c_in = [], in_dim
        for c in channels:
            layers += [nn.Conv1d(c_in, c, 1), nn.BatchNorm1d(c), nn.ReLU(inplace=True)]
            c_in = c
        self.net = nn.Sequential(*layers)
        self.out_dim = c_in

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x.transpose(1, 2)).amax(dim=2)


class ImageEncoder(nn.Module):
    """A small CNN (3x3 stride-2 Conv + BatchNorm + ReLU per channel count, global max pool):
    (B, 3, H, W) in [0, 1] -> (B, C).  Ablation A-7."""

    def __init__(self, channels: list[int]):
        super().__init__()
        layers, c_in = [], 3
        for c in channels:
            layers += [nn.Conv2d(c_in, c, 3, stride=2, padding=1), nn.BatchNorm2d(c), nn.ReLU(inplace=True)]
            c_in = c
        self.net = nn.Sequential(*layers)
        self.out_dim = c_in

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x * 2 - 1).amax(dim=(2, 3))


def nt_xent(z: Tensor, labels: Tensor, objects: Tensor, tau: float, negatives: str = "same_object") -> Tensor:
    """NT-Xent over a batch of L2-normalized embeddings ``z`` (M, D).

    For an anchor i and each positive p (same label, different object), the term is
    ``-log(exp(s_ip/tau) / (exp(s_ip/tau) + sum_n exp(s_in/tau)))`` over its negatives n (same
    object, different label; or with ``negatives="other_strategy"`` every sample of another label).
    Anchors without a positive or a negative contribute nothing; the mean is over the remaining
    (anchor, positive) pairs, 0 when there are none."""
    s = z @ z.T / tau
    same_label = labels[:, None] == labels[None, :]
    same_obj = objects[:, None] == objects[None, :]
    pos = same_label & ~same_obj
    neg = ~same_label & (same_obj if negatives == "same_object" else torch.ones_like(same_obj))
    has = pos.any(1) & neg.any(1)
    if not bool(has.any()):
        return z.sum() * 0.0
    s, pos, neg = s[has], pos[has], neg[has]
    neg_lse = torch.logsumexp(s.masked_fill(~neg, -math.inf), dim=1, keepdim=True)  # (A, 1)
    per_pair = torch.logaddexp(s, neg_lse) - s  # (A, M): -log softmax of each positive vs the negatives
    return (per_pair * pos).sum() / pos.sum()


class FlatLabStrategyPolicy(PreTrainedPolicy):
    config_class = FlatLabStrategyConfig
    name = "flatlab_strategy"

    def __init__(self, config: FlatLabStrategyConfig, dataset_stats=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config = config
        ch = [int(c) for c in config.encoder_channels]
        self.encoder = ImageEncoder(ch) if config.is_image else PointNetEncoder(ch)
        d = self.encoder.out_dim
        self.scale_embed = None
        if config.use_scale and not config.is_image:
            self.scale_embed = nn.Sequential(nn.Linear(1, 16), nn.ReLU(inplace=True))
            d += 16
        self.extent_embed = None
        if config.use_extent and not config.is_image:
            self.extent_embed = nn.Sequential(nn.Linear(3, 16), nn.ReLU(inplace=True))
            d += 16
        self.head = nn.Sequential(
            nn.Linear(d, config.head_hidden), nn.ReLU(inplace=True), nn.Dropout(config.dropout),
            nn.Linear(config.head_hidden, len(STRATEGY_LETTERS)),
        )  # fmt: skip
        self.projection = nn.Sequential(
            nn.Linear(d, config.proj_hidden), nn.ReLU(inplace=True), nn.Linear(config.proj_hidden, config.proj_dim)
        )
        self._strategies: list[str] = []

    # ------------------------------------------------------------------ lerobot API
    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self):
        self._strategies = []

    @property
    def strategies(self) -> list[str]:
        """The strategy letters chosen at the last :meth:`select_action` / :meth:`predict_strategy`."""
        return list(self._strategies)

    # ------------------------------------------------------------------ inputs
    def _prepare(
        self, x: Tensor, train: bool, tta_pass: int = 0, tta: int = 1
    ) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """A batch of one input (B, N, C>=3) cloud or (B, 3, H, W) image -> (the encoder's input,
        the cloud's radius before normalization (B,) or None, its extents (B, 3) (:func:`cloud_extents`
        of the drawn points) with ``use_extent``, else None).  At inference, pass ``tta_pass`` of ``tta``
        draws fixed subset ``tta_pass`` and turns the cloud by 2*pi*tta_pass/tta about z (config ``tta``)."""
        cfg = self.config
        if cfg.is_image:
            return x.float(), None, None
        x = x[..., :3].float()  # colour-free
        n = x.shape[1]
        if train:
            idx = torch.rand(x.shape[0], n, device=x.device).argsort(dim=1)[:, : cfg.n_points]
            if n < cfg.n_points:  # fewer points than asked: repeat random ones
                idx = torch.randint(0, n, (x.shape[0], cfg.n_points), device=x.device)
            x = torch.gather(x, 1, idx[..., None].expand(-1, -1, 3))
        elif n != cfg.n_points or tta_pass:
            g = torch.Generator().manual_seed(tta_pass)
            idx = torch.randperm(n, generator=g)[: cfg.n_points] if n >= cfg.n_points else (
                torch.randint(0, n, (cfg.n_points,), generator=g))  # fmt: skip
            x = x[:, idx.to(x.device)]
        extents = cloud_extents(x) if cfg.use_extent else None
        x, radius = normalize_cloud(x, return_radius=True)
        turn = None
        if train and cfg.augment_yaw:
            turn = torch.rand(x.shape[0], device=x.device) * 2 * math.pi
        elif not train and tta_pass:
            turn = x.new_full((x.shape[0],), 2 * math.pi * tta_pass / tta)
        if turn is not None:
            c, s = torch.cos(turn), torch.sin(turn)
            xy = torch.stack([c[:, None] * x[..., 0] - s[:, None] * x[..., 1],
                              s[:, None] * x[..., 0] + c[:, None] * x[..., 1]], dim=-1)  # fmt: skip
            x = torch.cat([xy, x[..., 2:]], dim=-1)
        if train and cfg.augment_jitter > 0:
            x = x + cfg.augment_jitter * torch.randn_like(x)
        return x, radius, extents

    def _input(self, batch: dict[str, Tensor]) -> Tensor:
        key = self.config.input_key
        if key not in batch:
            raise KeyError(f"flatlab_strategy: the batch has no {key!r} (its input_key); keys: {sorted(batch)}")
        return batch[key]

    def features(self, x: Tensor, train: bool = False, tta_pass: int = 0, tta: int = 1) -> Tensor:
        """F: the encoder's global feature, with the embedded log-radius (metres) of the cloud
        when ``use_scale`` (the unit-sphere normalization removes the object's size, which
        decides A vs B for a rescaled object), and with ``use_extent`` the embedded log-extents
        (metres) of the drawn points: thickness, length, width."""
        x, radius, extents = self._prepare(x, train, tta_pass, tta)
        f = self.encoder(x)
        if self.scale_embed is not None:
            f = torch.cat([f, self.scale_embed(torch.log(radius)[:, None])], dim=1)
        if self.extent_embed is not None:
            f = torch.cat([f, self.extent_embed(torch.log(extents.clamp_min(1e-3)))], dim=1)
        return f

    # ------------------------------------------------------------------ inference
    @torch.no_grad()
    def predict_logits(self, batch: dict[str, Tensor], tta: int | None = None) -> Tensor:
        """(B, 3) logits of one observation per batch element (an unbatched one is batched); ``tta``
        (default ``config.tta``): passes averaged."""
        x = self._input(batch)
        if x.dim() == (3 if self.config.is_image else 2):
            x = x.unsqueeze(0)
        k = int(self.config.tta if tta is None else tta)  # checked by config.check_tta where it is set
        if k == 1:
            return self.head(self.features(x, train=False))
        # k passes (config ``tta``): the log of the averaged class probabilities
        probs = torch.stack([self.head(self.features(x, False, j, k)).softmax(dim=1) for j in range(k)]).mean(0)
        return probs.clamp(min=1e-12).log()

    @torch.no_grad()
    def predict_strategy(self, batch: dict[str, Tensor], tta: int | None = None) -> list[str]:
        logits = self.predict_logits(batch, tta)
        self._strategies = [STRATEGY_LETTERS[int(i)] for i in logits.argmax(dim=1)]
        return self.strategies

    @torch.no_grad()
    def rank_cloud(self, object_cloud: np.ndarray, cloud_points: int = 2048, tta: int | None = None) -> list[str]:
        """The strategies (A/B/C), most probable first, for one env object cloud (K, 3) read as: its
        distinct seen points (the env pads a cloud it sees fewer points of by repeating them, and fills an
        unseen one with zeros), farthest-point sampled to ``cloud_points`` (0: all) when there are more, as
        the strategy set's clouds are FPS samples of the object's pixels.  The repeats would shift the
        cloud's mean, the centre of the normalization (at 128 px, Train S 73 % with them, 97 % without:
        docs/unified.md)."""
        dev = next(self.parameters()).device
        pts, seen = np.asarray(object_cloud, np.float64).reshape(-1, 3), seen_points(object_cloud)
        if len(seen):
            pts = seen[distinct_indices(seen)]
        if cloud_points and len(pts) > cloud_points:
            pts = pts[fps_indices(pts, cloud_points)]
        x = torch.as_tensor(pts, dtype=torch.float32, device=dev)[None]
        logits = self.predict_logits({self.config.input_key: x}, tta=tta)[0]
        return [STRATEGY_LETTERS[int(i)] for i in torch.argsort(logits, descending=True, stable=True)]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """(B, 3) strategy probabilities (A, B, C); :attr:`strategies` holds the argmax letters."""
        logits = self.predict_logits(batch)
        self._strategies = [STRATEGY_LETTERS[int(i)] for i in logits.argmax(dim=1)]
        return logits.softmax(dim=1)

    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        return self.select_action(batch).unsqueeze(1)

    # ------------------------------------------------------------------ training
    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Loss of a training batch: one sample = ``group_size`` frames of one episode (input
        (B, K, ...), label ``action`` (B, K, 3) one-hot, ``*_is_pad`` (B, K)), or single frames."""
        cfg = self.config
        x, y = self._input(batch), batch[ACTION]
        single = 3 if cfg.is_image else 2
        if x.dim() == single + 1:  # (B, ...) single frames
            x, y = x.unsqueeze(1), y.unsqueeze(1)
        b, k = x.shape[:2]
        pad = batch.get(f"{cfg.input_key}_is_pad")
        valid = torch.ones(b, k, dtype=torch.bool, device=x.device) if pad is None else ~pad.bool().reshape(b, k)
        obj = batch.get("object_index")
        obj = torch.arange(b, device=x.device) if obj is None else obj.reshape(b).to(x.device)
        labels = y.reshape(b * k, -1).argmax(dim=1)
        objects = obj[:, None].expand(b, k).reshape(-1)
        keep = valid.reshape(-1)
        x = x.reshape(b * k, *x.shape[2:])[keep]
        labels, objects = labels[keep], objects[keep]
        f = self.features(x, train=self.training)
        logits = self.head(f)
        ce = F.cross_entropy(logits, labels)
        info = {"ce": float(ce.detach()), "acc": float((logits.argmax(1) == labels).float().mean())}
        loss = ce
        if cfg.contrast_weight > 0:
            z = F.normalize(self.projection(f), dim=1)
            con = nt_xent(z, labels, objects, cfg.temperature, cfg.contrast_negatives)
            loss = loss + cfg.contrast_weight * con
            info["nt_xent"] = float(con.detach())
        return loss, info

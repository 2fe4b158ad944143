"""A compact pure-torch PointNet++ encoder (Qi et al. 2017, single-scale grouping), CPU-friendly.

Set abstraction: farthest point sampling picks ``npoint`` centroids, a ball query gathers up to
``nsample`` neighbours within ``radius`` of each (padded with the nearest one: the first found),
a shared MLP (1x1 conv + BN + ReLU) runs on the neighbours' centroid-relative xyz (+ features) and a
max-pool gives each centroid a feature.  A final global level pools everything into one vector.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


def farthest_point_sample(xyz: Tensor, npoint: int) -> Tensor:
    """(B, N, 3) -> (B, npoint) indices; deterministic (starts at point 0)."""
    B, N, _ = xyz.shape
    idx = torch.zeros(B, npoint, dtype=torch.long, device=xyz.device)
    dist = torch.full((B, N), float("inf"), device=xyz.device, dtype=xyz.dtype)
    far = torch.zeros(B, dtype=torch.long, device=xyz.device)
    ar = torch.arange(B, device=xyz.device)
    for i in range(npoint):
        idx[:, i] = far
        c = xyz[ar, far].unsqueeze(1)
        dist = torch.minimum(dist, ((xyz - c) ** 2).sum(-1))
        far = dist.argmax(-1)
    return idx


def gather(points: Tensor, idx: Tensor) -> Tensor:
    """points (B, N, C), idx (B, ...) -> (B, ..., C)."""
    B = points.shape[0]
    flat = idx.reshape(B, -1)
    out = torch.gather(points, 1, flat.unsqueeze(-1).expand(-1, -1, points.shape[-1]))
    return out.reshape(*idx.shape, points.shape[-1])


def ball_query(radius: float, nsample: int, xyz: Tensor, centers: Tensor) -> Tensor:
    """Indices (B, S, nsample) of up to ``nsample`` points of ``xyz`` within ``radius`` of each
    centre (in index order); missing slots repeat the first hit (a centre is one of the points, so
    there is always one)."""
    B, N, _ = xyz.shape
    d2 = torch.cdist(centers, xyz) ** 2  # (B, S, N)
    ar = torch.arange(N, device=xyz.device).expand_as(d2)
    idx = torch.where(d2 <= radius * radius, ar, torch.full_like(ar, N))
    k = min(nsample, N)
    idx = idx.topk(k, dim=-1, largest=False).values  # smallest indices = in-ball points first
    first = idx[..., :1]
    nearest = d2.argmin(-1, keepdim=True)
    first = torch.where(first == N, nearest, first)
    idx = torch.where(idx == N, first.expand_as(idx), idx)
    if k < nsample:
        idx = torch.cat([idx, first.expand(-1, -1, nsample - k)], -1)
    return idx


def _mlp2d(channels: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for a, b in zip(channels[:-1], channels[1:]):
        layers += [nn.Conv2d(a, b, 1), nn.BatchNorm2d(b), nn.ReLU(inplace=True)]
    return nn.Sequential(*layers)


class SetAbstraction(nn.Module):
    def __init__(self, npoint: int | None, radius: float, nsample: int, in_ch: int, mlp: list[int]):
        super().__init__()
        self.npoint, self.radius, self.nsample = npoint, radius, nsample
        self.mlp = _mlp2d([in_ch + 3, *mlp])
        self.out_ch = mlp[-1]

    def forward(self, xyz: Tensor, feats: Tensor | None) -> tuple[Tensor, Tensor]:
        """xyz (B, N, 3), feats (B, N, C) or None -> (new_xyz (B, S, 3), new_feats (B, S, C'))."""
        if self.npoint is None:  # global level: all points, one group centred at the origin
            grouped = xyz.unsqueeze(1)  # (B, 1, N, 3)
            if feats is not None:
                grouped = torch.cat([grouped, feats.unsqueeze(1)], -1)
            new_xyz = xyz.new_zeros(xyz.shape[0], 1, 3)
        else:
            new_xyz = gather(xyz, farthest_point_sample(xyz, self.npoint))
            idx = ball_query(self.radius, self.nsample, xyz, new_xyz)  # (B, S, K)
            grouped = gather(xyz, idx) - new_xyz.unsqueeze(2)
            if feats is not None:
                grouped = torch.cat([grouped, gather(feats, idx)], -1)
        h = self.mlp(grouped.permute(0, 3, 1, 2))  # (B, C', S, K)
        return new_xyz, h.max(-1).values.transpose(1, 2)


class PointNet2Encoder(nn.Module):
    """(B, N, 3) centred cloud -> (B, out_dim) F_env."""

    def __init__(self, npoints, radii, nsamples, mlps, global_mlp):
        super().__init__()
        levels, ch = [], 0
        for k, r, s, m in zip(npoints, radii, nsamples, mlps):
            levels.append(SetAbstraction(int(k), float(r), int(s), ch, list(m)))
            ch = levels[-1].out_ch
        levels.append(SetAbstraction(None, 0.0, 0, ch, list(global_mlp)))
        self.levels = nn.ModuleList(levels)
        self.out_dim = int(global_mlp[-1])

    def forward(self, xyz: Tensor) -> Tensor:
        feats = None
        for level in self.levels:
            xyz, feats = level(xyz, feats)
        return feats[:, 0]

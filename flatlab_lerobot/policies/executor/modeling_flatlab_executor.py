"""``FlatLabExecutorPolicy``: the action execution module (paper §3.3) as a LeRobot policy.

``forward`` (training, ``lerobot-train``): loss on one batch of primitive samples.
``predict_poses`` (the unified policy's entry point): scene cloud + strategy + primitive (+ TCP
proprioception) -> each arm's start / end pose and gripper width, in the world frame.
``select_action`` returns the same prediction flattened in the ``action`` layout (34,).
The policy never reads ``observation.environment_state``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION
from torch import Tensor, nn

from flatlab_lerobot.policies.executor.configuration_flatlab_executor import (
    ACTION_DIM,
    ARMS,
    GRASP_STAGE,
    MAX_STAGES,
    OBJECT_FRAMES,
    OBS_OBJECT_CLOUD,
    OBS_POINTCLOUD,
    OBS_PRIMITIVE,
    OBS_TCP_STATE,
    PRIMITIVE_DIM,
    STRATEGY_NAMES,
    TCP_STATE_DIM,
    FlatLabExecutorConfig,
    arm_slices,
    check_training_tasks,
    decode_primitive,
    encode_primitive,
)
from flatlab_lerobot.policies.executor.pointnet2 import PointNet2Encoder
from flatlab_lerobot.strategies.registry import STAGE_SPECS

NS = len(STRATEGY_NAMES)


# ------------------------------------------------------------------------------ geometry
def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product of wxyz quaternions (..., 4)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
         aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)  # fmt: skip


def quat_z(phi: Tensor) -> Tensor:
    """(B,) angles -> (B, 4) wxyz rotations about z."""
    z = torch.zeros_like(phi)
    return torch.stack([torch.cos(phi / 2), z, z, torch.sin(phi / 2)], -1)


def canonical(q: Tensor) -> Tensor:
    """Unit quaternion with w >= 0."""
    q = F.normalize(q, dim=-1)
    return torch.where(q[..., :1] < 0, -q, q)


def geodesic_angle(q_hat: Tensor, q: Tensor) -> Tensor:
    """theta = 2 arccos |<q_hat, q>| (rad) of unit quaternions; 0 for q and -q.  The gradient is
    finite everywhere (|<.,.>| is clamped below 1 inside arccos; theta is exactly 0 at the clamp)."""
    d = (F.normalize(q_hat, dim=-1) * F.normalize(q, dim=-1)).sum(-1).abs()
    lim = 1.0 - 1e-7
    theta = 2.0 * torch.acos(d.clamp(max=lim))
    return torch.where(d >= lim, torch.zeros_like(theta), theta)


def geodesic_loss(q_hat: Tensor, q: Tensor) -> Tensor:
    """Paper's L_rot = E[theta^2]."""
    return (geodesic_angle(q_hat, q) ** 2).mean()


def mean_predictions(passes: list[list[dict[str, Tensor]]]) -> list[dict[str, Tensor]]:
    """The mean of several world-frame predictions (``predict_world`` outputs: per arm a dict of (B, .)
    tensors): test-time augmentation passes, or the members of an ensemble.  Quaternions: q and -q are
    one rotation, so each is sign-aligned to the first before the mean, which is then normalized."""
    if len(passes) == 1:
        return passes[0]
    out = []
    for i in range(len(passes[0])):
        arm = {}
        for key in passes[0][i]:
            v = torch.stack([p[i][key] for p in passes])  # (k, B, .)
            if key.endswith("quat"):
                v = v * torch.where((v * v[:1]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
                m = v.mean(0)
                arm[key] = canonical(m / m.norm(dim=-1, keepdim=True).clamp(min=1e-12))
            else:
                arm[key] = v.mean(0)
        out.append(arm)
    return out


def seen_quantile_z(cloud: Tensor, seen: Tensor, q: float) -> Tensor:
    """(B,) the ``q`` quantile of the heights of each cloud's seen points (``seen`` (B, K) bool; nearest
    rank from the top: q = 1 is the highest seen point).  A row with none seen gives -inf."""
    z = torch.where(seen, cloud[..., 2], torch.full_like(cloud[..., 2], -math.inf))
    z = z.sort(dim=1, descending=True).values
    k = ((1.0 - q) * (seen.sum(1) - 1).clamp(min=0).float()).round().long()  # rank among the seen points
    return torch.gather(z, 1, k[:, None])[:, 0]


class SceneFrame:
    """The model frame of a batch: ``x' = s * Rz(phi) (x - c)`` with c the cloud mean (paper App. B:
    clouds normalised to zero mean), s and phi the augmentation (1 and 0 at eval).  Positions and
    quaternions of the targets and the proprioception go through the same map as the cloud."""

    def __init__(self, center: Tensor, scale: Tensor, phi: Tensor):
        self.c, self.s, self.phi = center, scale, phi  # (B, 3), (B,), (B,)
        cos, sin = torch.cos(phi), torch.sin(phi)
        z, o = torch.zeros_like(phi), torch.ones_like(phi)
        self.R = torch.stack([cos, -sin, z, sin, cos, z, z, z, o], -1).view(-1, 3, 3)
        self.qz = quat_z(phi)

    def _bshape(self, x: Tensor, t: Tensor) -> Tensor:
        return t.view(t.shape[0], *([1] * (x.dim() - 2)), *t.shape[1:])

    def pos_in(self, p: Tensor) -> Tensor:  # (B, ..., 3) world -> model
        R = self._bshape(p, self.R)
        return self._bshape(p, self.s[:, None])[..., :1] * (R @ (p - self._bshape(p, self.c)).unsqueeze(-1)).squeeze(-1)

    def pos_out(self, p: Tensor) -> Tensor:  # model -> world
        R = self._bshape(p, self.R)
        return (R.transpose(-1, -2) @ (p / self._bshape(p, self.s[:, None])[..., :1]).unsqueeze(-1)).squeeze(-1) + self._bshape(p, self.c)

    def quat_in(self, q: Tensor) -> Tensor:
        return quat_mul(self._bshape(q, self.qz).expand_as(q), q)

    def quat_out(self, q: Tensor) -> Tensor:
        inv = self.qz * self.qz.new_tensor([1.0, -1.0, -1.0, -1.0])
        return quat_mul(self._bshape(q, inv).expand_as(q), q)


def _mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


# ------------------------------------------------------------------------------ policy
class FlatLabExecutorPolicy(PreTrainedPolicy):
    config_class = FlatLabExecutorConfig
    name = "flatlab_executor"

    def __init__(self, config: FlatLabExecutorConfig, dataset_stats=None, dataset_meta=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config = config
        if dataset_meta is not None:
            check_training_tasks(dataset_meta)  # Test-alpha / Test-beta objects never train it
        c = config
        self.encoder = PointNet2Encoder(c.sa_npoints, c.sa_radii, c.sa_nsamples, c.sa_mlps, c.global_mlp)
        self.cond = nn.Sequential(nn.Linear(PRIMITIVE_DIM, c.cond_dim), nn.ReLU(inplace=True))
        self.object_encoder = None
        if c.object_mlp:
            from flatlab_lerobot.policies.strategy.modeling_flatlab_strategy import PointNetEncoder

            self.object_encoder = PointNetEncoder([int(w) for w in c.object_mlp])
        in_dim = (self.encoder.out_dim + c.cond_dim + (TCP_STATE_DIM if c.use_proprio else 0)
                  + (self.object_encoder.out_dim if self.object_encoder is not None else 0))  # fmt: skip
        na = len(ARMS)
        self.pos_head = _mlp([in_dim, *c.head_hidden, na * 8])  # per arm: start xyz, end xyz, gripper start/end
        self.rot_head = _mlp([in_dim, *c.head_hidden, na * 8])  # per arm: start quat, end quat
        # relative_starts: per (strategy, stage) whether the stage starts where the arm is (StageSpec.start)
        from_current = torch.zeros(NS, MAX_STAGES, dtype=torch.bool)
        for i, s in enumerate(STRATEGY_NAMES):
            for k, spec in enumerate(STAGE_SPECS[s]):
                from_current[i, k] = spec.start == "current"
        self.register_buffer("from_current", from_current, persistent=False)
        # which arms the primitive commands (A picks its pushing / grasping arm from where the object is)
        self.active_head = _mlp([in_dim, c.head_hidden[-1], na])
        self.reset()

    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self):
        pass

    # ---------------------------------------------------------------- inputs
    def _cloud(self, cloud: Tensor) -> Tensor:
        n = self.config.n_points
        N = cloud.shape[1]
        if N >= n:
            if self.training:  # a random subset each step; eval: the first n (the stored order is random)
                return cloud[:, torch.randperm(N, device=cloud.device)[:n]]
            return cloud[:, :n]
        reps = math.ceil(n / N)
        return cloud.repeat(1, reps, 1)[:, :n]

    def _object_feature(self, frame: SceneFrame, obj: Tensor) -> Tensor:
        """The object encoder's feature of the object cloud (B, K, 3) in the model frame: a max pool over
        ``n_object_points`` of its seen points (all-zero rows are unseen; repeats fill a short cloud;
        a cloud with none seen gives a zero feature)."""
        n = self.config.n_object_points
        seen = obj.abs().sum(-1) > 0  # (B, K)
        # order: seen points first (random order in training, stored order at eval), then unseen ones
        key = seen.float() * 2 + (torch.rand(seen.shape, device=obj.device) if self.training else 0.0)
        order = key.argsort(dim=1, descending=True, stable=True)
        n_seen = seen.sum(1, keepdim=True)  # (B, 1)
        slot = torch.arange(n, device=obj.device)[None]  # (1, n): slot i takes seen point i mod n_seen
        pick = torch.gather(order, 1, torch.remainder(slot, n_seen.clamp(min=1)).expand(obj.shape[0], -1))
        pts = torch.gather(obj, 1, pick[..., None].expand(-1, -1, 3))
        x = frame.pos_in(pts)
        if self.training and self.config.augment and self.config.aug_jitter_std > 0:
            x = x + self.config.aug_jitter_std * torch.randn_like(x)
        f = self.object_encoder(x)
        return torch.where(n_seen > 0, f, torch.zeros_like(f))

    def _center(self, batch: dict[str, Tensor], cloud: Tensor) -> Tensor:
        """(B, 3) origin of the model frame: the scene cloud's mean, or (``frame_center="object"``) the
        mean of the object cloud's seen points (all-zero rows are unseen; none seen: the scene mean),
        or (``"object_table"``) that mean in x, y with z on the table plane (``table_quantile`` of the
        scene cloud's heights), or (``"object_top"``) that mean in x, y with z at the object's seen top
        (``top_quantile`` of its seen points' heights)."""
        c = cloud.mean(1)
        if self.config.frame_center not in OBJECT_FRAMES:
            return c
        obj = batch[OBS_OBJECT_CLOUD].float()
        seen = (obj.abs().sum(-1) > 0).float()  # (B, K)
        n = seen.sum(1, keepdim=True)
        c_obj = (obj * seen[..., None]).sum(1) / n.clamp(min=1.0)
        c = torch.where(n > 0, c_obj, c)
        if self.config.frame_center == "object_table":
            z = torch.quantile(cloud[..., 2], self.config.table_quantile, dim=1)
            c = torch.cat([c[:, :2], z[:, None]], 1)
        elif self.config.frame_center == "object_top":
            c = torch.cat([c[:, :2], torch.where(n[:, 0] > 0, seen_quantile_z(obj, seen > 0, self.config.top_quantile),
                                                 c[:, 2])[:, None]], 1)  # fmt: skip
        return c

    def _frame(self, cloud: Tensor, c: Tensor | None = None, turn: float = 0.0) -> SceneFrame:
        """``turn``: an extra rotation about z (rad) at inference (test-time augmentation)."""
        B = cloud.shape[0]
        c = cloud.mean(1) if c is None else c
        one, zero = cloud.new_ones(B), cloud.new_zeros(B)
        if self.training and self.config.augment:
            lo, hi = self.config.aug_scale
            s = lo + (hi - lo) * torch.rand(B, device=cloud.device)
            a = math.radians(self.config.aug_rot_z_deg)
            phi = (2 * torch.rand(B, device=cloud.device) - 1) * a
            return SceneFrame(c, s, phi)
        return SceneFrame(c, one, zero + turn)

    def _conditioning(self, prim: Tensor) -> Tensor:
        if not self.config.decompose_primitives:  # the strategy only, no primitive
            prim = torch.cat([prim[:, :NS], torch.zeros_like(prim[:, NS:])], 1)
        return prim

    def _proprio_in(self, frame: SceneFrame, tcp: Tensor) -> list[tuple[Tensor, Tensor, Tensor]]:
        """Per arm (TCP position, quaternion, finger opening) in the model frame."""
        parts = []
        for i in range(len(ARMS)):
            a = tcp[:, 8 * i : 8 * i + 8]
            parts.append((frame.pos_in(a[:, :3]), canonical(frame.quat_in(canonical(a[:, 3:7]))), a[:, 7:8]))
        return parts

    def relative_mask(self, prim: Tensor) -> Tensor:
        """(B,) bool: with ``relative_starts``, the sample's stage starts where the arm is (its poses are
        predicted relative to the TCP); all False otherwise."""
        if not (self.config.relative_starts and self.config.decompose_primitives):
            return torch.zeros(prim.shape[0], dtype=torch.bool, device=prim.device)
        strat, stage, _ = decode_primitive(prim)
        return self.from_current[strat, stage]

    def _run(self, batch: dict[str, Tensor], frame: SceneFrame | None = None, turn: float = 0.0):
        """-> (frame, per-arm predictions in the model frame)."""
        cloud = self._cloud(batch[OBS_POINTCLOUD].float())
        frame = frame or self._frame(cloud, self._center(batch, cloud), turn)
        x = frame.pos_in(cloud)
        if self.training and self.config.augment and self.config.aug_jitter_std > 0:
            x = x + self.config.aug_jitter_std * torch.randn_like(x)
        feats = [self.encoder(x), self.cond(self._conditioning(batch[OBS_PRIMITIVE].float()))]
        tcp = None
        if self.config.use_proprio:
            tcp = self._proprio_in(frame, batch[OBS_TCP_STATE].float())
            feats.append(torch.cat([t for arm in tcp for t in arm], 1))
        if self.object_encoder is not None:
            feats.append(self._object_feature(frame, batch[OBS_OBJECT_CLOUD].float()))
        h = torch.cat(feats, 1)
        pos, rot, act = self.pos_head(h), self.rot_head(h), self.active_head(h)
        rel = self.relative_mask(batch[OBS_PRIMITIVE].float())[:, None]  # (B, 1)
        any_rel = bool(rel.any())
        out = []
        for i in range(len(ARMS)):
            p, r = pos[:, 8 * i : 8 * i + 8], rot[:, 8 * i : 8 * i + 8]
            arm = {"start_pos": p[:, 0:3], "end_pos": p[:, 3:6], "gripper_start": p[:, 6:7], "gripper_end": p[:, 7:8],
                   "start_quat": canonical(r[:, 0:4]), "end_quat": canonical(r[:, 4:8]), "active_logit": act[:, i]}  # fmt: skip
            if any_rel:  # stages that start where the arm is: TCP + d_start, then start + d_end
                t_pos, t_q, _ = tcp[i]
                s_pos = t_pos + p[:, 0:3]
                s_q = canonical(quat_mul(F.normalize(r[:, 0:4], dim=-1), t_q))
                e_q = canonical(quat_mul(F.normalize(r[:, 4:8], dim=-1), s_q))
                arm["start_pos"] = torch.where(rel, s_pos, arm["start_pos"])
                arm["end_pos"] = torch.where(rel, s_pos + p[:, 3:6], arm["end_pos"])
                arm["start_quat"] = torch.where(rel, s_q, arm["start_quat"])
                arm["end_quat"] = torch.where(rel, e_q, arm["end_quat"])
            out.append(arm)
        return frame, out

    # ---------------------------------------------------------------- training
    def grasp_mask(self, prim: Tensor) -> Tensor:
        """(B,) bool: the sample is its strategy's grasp primitive (a_grasp, b_squeeze, c_pinch)."""
        strat, stage, _ = decode_primitive(prim)
        grasp = prim.new_tensor([GRASP_STAGE[s] for s in STRATEGY_NAMES]).long()
        return stage == grasp[strat]

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        frame, pred = self._run(batch)
        target = batch[ACTION].float()
        prim = batch[OBS_PRIMITIVE].float()
        grasp = self.grasp_mask(prim)
        sample_w = torch.ones_like(grasp, dtype=target.dtype) if self.config.decompose_primitives else grasp.to(target.dtype)
        pos_terms, rot_terms, grip_terms, ws, act_terms = [], [], [], [], []
        for i, p in enumerate(pred):
            sl = arm_slices(i)
            active = target[:, sl["active"]].squeeze(1)
            w = active * sample_w
            act_terms.append(F.binary_cross_entropy_with_logits(p["active_logit"], active, reduction="none") * sample_w)
            for end in ("start", "end"):
                t_pos = frame.pos_in(target[:, sl[f"{end}_pos"]])
                t_q = canonical(frame.quat_in(target[:, sl[f"{end}_quat"]]))
                se = ((p[f"{end}_pos"] - t_pos) ** 2).sum(-1)
                th = geodesic_angle(p[f"{end}_quat"], t_q)
                pos_terms.append(se * w)
                rot_terms.append(th**2 * w)
                ws.append(w)
            for g in ("gripper_start", "gripper_end"):
                grip_terms.append(((p[g] - target[:, sl[g]]) ** 2).squeeze(1) * w)
        wsum = torch.stack(ws).sum().clamp(min=1.0)
        l_pos = torch.stack(pos_terms).sum() / wsum
        l_rot = torch.stack(rot_terms).sum() / wsum
        l_grip = torch.stack(grip_terms).sum() / wsum
        l_act = torch.stack(act_terms).sum() / (len(act_terms) * sample_w.sum()).clamp(min=1.0)
        c = self.config
        loss = c.lambda_pos * l_pos + c.lambda_grip * l_grip + c.lambda_active * l_act
        if c.rotation_loss:
            loss = loss + c.lambda_rot * l_rot
        # (pose errors per split / primitive: `flatlab executor-metrics`, not the augmented training batch)
        return loss, {"pos_loss": l_pos.item(), "rot_loss": l_rot.item(), "grip_loss": l_grip.item(), "active_loss": l_act.item()}

    # ---------------------------------------------------------------- inference
    @torch.no_grad()
    def predict_world(self, batch: dict[str, Tensor], tta: int | None = None) -> list[dict[str, Tensor]]:
        """Per arm (``ARMS`` order) dict of world-frame predictions, tensors (B, .).

        ``tta`` (default ``config.tta``): k > 1 averages k passes, pass j in a model frame rotated about z
        by :meth:`tta_turn` and on the cloud's points rolled by j*n_points (another subset of them)."""
        k = int(self.config.tta if tta is None else tta)
        was = self.training
        self.eval()
        try:
            passes = [self._world(batch, j, k) for j in range(k)]
        finally:
            self.train(was)
        return mean_predictions(passes)

    def tta_turn(self, j: int, k: int) -> float:
        """Pass ``j`` of ``k``'s extra rotation about z (rad), within the rotations the model was trained
        under: 2*pi*j/k when it saw every turn (``aug_rot_z_deg`` 180), else ``k`` turns evenly spread over
        [-aug_rot_z_deg, aug_rot_z_deg] (one pass: no turn)."""
        a = float(self.config.aug_rot_z_deg) if self.config.augment else 0.0
        if a >= 180.0:
            return 2 * math.pi * j / k
        return 0.0 if k == 1 else math.radians(a * (2.0 * j / (k - 1) - 1.0))

    def _world(self, batch: dict[str, Tensor], j: int, k: int) -> list[dict[str, Tensor]]:
        """One inference pass (``j`` of ``k``) in world coordinates."""
        if j:
            batch = {**batch, OBS_POINTCLOUD: torch.roll(batch[OBS_POINTCLOUD], -j * self.config.n_points, dims=1)}
            if self.object_encoder is not None:
                obj = batch[OBS_OBJECT_CLOUD]
                batch[OBS_OBJECT_CLOUD] = torch.roll(obj, -j * self.config.n_object_points, dims=1)
        frame, pred = self._run(batch, turn=self.tta_turn(j, k))
        out = []
        for p in pred:
            out.append({
                "start_pos": frame.pos_out(p["start_pos"]), "end_pos": frame.pos_out(p["end_pos"]),
                "start_quat": canonical(frame.quat_out(p["start_quat"])),
                "end_quat": canonical(frame.quat_out(p["end_quat"])),
                "gripper_start": p["gripper_start"].clamp(min=0.0), "gripper_end": p["gripper_end"].clamp(min=0.0),
                "active": torch.sigmoid(p["active_logit"])[:, None],
            })  # fmt: skip
        return out

    def _flat(self, per_arm: list[dict[str, Tensor]]) -> Tensor:
        B = per_arm[0]["start_pos"].shape[0]
        act = per_arm[0]["start_pos"].new_zeros(B, ACTION_DIM)
        for i, p in enumerate(per_arm):
            sl = arm_slices(i)
            for k, v in p.items():  # "active": the probability that the primitive commands this arm
                act[:, sl[k]] = v
        return act

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        return self._flat(self.predict_world(batch)).unsqueeze(1)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        return self.predict_action_chunk(batch)[:, 0]

    @torch.no_grad()
    def predict_poses(self, scene_cloud, strategy, stage_index, primitive, proprio=None, object_cloud=None, tta=None,
                      members: tuple[FlatLabExecutorPolicy, ...] = ()) -> dict[str, dict]:  # fmt: skip
        """The unified policy's call: one decision.

        scene_cloud: (N, 3) or (B, N, 3) world-frame scene cloud (crop + cameras as the primitive set).
        strategy / stage_index / primitive: the stage being posed (``strategies.STRATEGIES[strategy]
        [stage_index]``, its primitive name); scalars, or sequences of length B.
        proprio: (16,) / (B, 16) per arm measured TCP pos (3), quat wxyz (4), finger opening (1);
        required when ``config.use_proprio``.
        object_cloud: (K, 3) / (B, K, 3) world-frame segmented object cloud (env obs
        ``object_pointcloud``); required when ``config.frame_center`` is an object frame ("object", "object_table", "object_top"), ignored otherwise.
        tta: test-time augmentation passes (default ``config.tta``; see ``predict_world``).
        members: further executors that read the same inputs (an ensemble: the same recipe trained with
        other seeds); the poses are the mean of this executor's and theirs (``mean_predictions``).
        Returns ``{arm: {"start": (pos (B,3), quat (B,4)), "end": (...), "gripper": ((B,), (B,)),
        "active": (B,)}}`` as numpy arrays (B=1 kept); ``active`` is the predicted probability that the
        primitive commands the arm (A's pushing / grasping arm depends on where the object is)."""
        dev = next(self.parameters()).device
        cloud = torch.as_tensor(np.array(scene_cloud, np.float32), device=dev)
        if cloud.dim() == 2:
            cloud = cloud[None]
        if cloud.dim() != 3 or cloud.shape[-1] != 3:
            raise ValueError(f"predict_poses: scene_cloud must be (N, 3) or (B, N, 3), got {tuple(cloud.shape)}")
        B = cloud.shape[0]

        def per(x):
            return list(x) if isinstance(x, (list, tuple, np.ndarray)) else [x] * B

        prims = [encode_primitive(s, int(k), p) for s, k, p in zip(per(strategy), per(stage_index), per(primitive))]
        if len(prims) != B:
            raise ValueError(f"predict_poses: {len(prims)} primitives for {B} clouds")
        batch = {OBS_POINTCLOUD: cloud, OBS_PRIMITIVE: torch.tensor(prims, device=dev)}
        if self.config.use_proprio:
            if proprio is None:
                raise ValueError("predict_poses: proprio (16,) is required (config.use_proprio=true)")
            pr = torch.as_tensor(np.array(proprio, np.float32), device=dev).reshape(B, TCP_STATE_DIM)
            batch[OBS_TCP_STATE] = pr
        if self.config.frame_center in OBJECT_FRAMES:
            if object_cloud is None:
                raise ValueError(f"predict_poses: object_cloud (K, 3) is required (config.frame_center={self.config.frame_center!r})")
            batch[OBS_OBJECT_CLOUD] = torch.as_tensor(np.array(object_cloud, np.float32), device=dev).reshape(B, -1, 3)
        members = [self, *members]
        return pose_dict(mean_predictions([m.predict_world(batch, tta) for m in members]))


def pose_dict(per_arm: list[dict[str, Tensor]]) -> dict[str, dict]:
    """``predict_world``'s per-arm tensors as ``predict_poses`` returns them: numpy, keyed by arm."""
    out = {}
    for arm, p in zip(ARMS, per_arm):
        n = {k: v.cpu().numpy() for k, v in p.items()}
        out[arm] = {"start": (n["start_pos"], n["start_quat"]), "end": (n["end_pos"], n["end_quat"]),
                    "gripper": (n["gripper_start"][:, 0], n["gripper_end"][:, 0]), "active": n["active"][:, 0]}  # fmt: skip
    return out

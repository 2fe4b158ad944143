"""Config of the ``flatlab_executor`` policy type: the paper's action execution module (§3.3, App. B).

A PointNet++ encoder of the *scene* cloud gives F_env; two parallel MLP heads (position, rotation)
conditioned on the strategy and the primitive predict each arm's commanded start and end TCP pose
(position in m, unit quaternion wxyz) and gripper width.  Loss
``lambda_pos * E||p_hat - p||^2 + lambda_rot * E[theta^2]`` with ``theta = 2 arccos |<q_hat, q>|``
(+ ``lambda_grip`` * gripper-width MSE), over the arms the primitive commands, + ``lambda_active`` *
BCE of a per-arm "this primitive commands the arm" head (A's arm depends on where the object lies).

Features (written by ``flatlab primitive-export``; see :mod:`flatlab_lerobot.learning.primitive_export`):

* ``observation.pointcloud`` (N, 3): world-frame scene cloud at the primitive's decision.
* ``observation.primitive`` (29,): one-hot strategy (3) | stage index in the strategy (17) | primitive
  name (9) -- :func:`encode_primitive`.
* ``observation.tcp_state`` (16,): per arm (left, right) measured TCP position (3), quaternion (4),
  finger opening (1) -- proprioception, used only if ``use_proprio``.
* ``action`` (34,): per arm: active flag (1), start pos (3), start quat (4), end pos (3), end quat (4),
  gripper start (1), gripper end (1) -- :data:`ACTION_NAMES`.

The policy never reads ``observation.environment_state`` (privileged).  No lerobot normalizer: the
model centres the cloud on its mean (paper App. B) and predicts positions relative to that centre,
so ``normalization_mapping`` is IDENTITY everywhere.

Ablations (paper Table 2): A-4 ``rotation_loss=false``; A-5 ``decompose_primitives=false`` (one
network maps the scene (+ strategy) straight to the grasp pose: no primitive conditioning, trained
on the grasp primitive only); A-6 both.
"""

from __future__ import annotations

import re

from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PreTrainedConfig
from lerobot.optim import AdamConfig
from lerobot.utils.constants import ACTION

from flatlab_lerobot.policies import identity_normalization

ARMS = ("left", "right")
STRATEGY_NAMES = ("A", "B", "C")
PRIMITIVE_NAMES = ("move", "touch", "press", "slide", "squeeze", "grasp", "lift", "hold", "release")  # = primitives.PRIMITIVE_NAMES
MAX_STAGES = 17  # len(strategies.STRATEGIES["A"]) = 4 * A_PASSES + 5 (checked by a test)
GRASP_STAGE = {"A": 14, "B": 2, "C": 6}  # a_grasp, b_squeeze, c_pinch (checked by a test)
PRIMITIVE_DIM = len(STRATEGY_NAMES) + MAX_STAGES + len(PRIMITIVE_NAMES)

OBS_POINTCLOUD = "observation.pointcloud"
OBS_PRIMITIVE = "observation.primitive"
OBS_TCP_STATE = "observation.tcp_state"
OBS_OBJECT_CLOUD = "observation.object_pointcloud"
FRAME_CENTERS = ("scene", "object", "object_table", "object_top")
OBJECT_FRAMES = ("object", "object_table", "object_top")  # frames that read observation.object_pointcloud
TCP_STATE_DIM = 8 * len(ARMS)

ARM_FIELDS = (("active", 1), ("start_pos", 3), ("start_quat", 4), ("end_pos", 3), ("end_quat", 4),
              ("gripper_start", 1), ("gripper_end", 1))  # fmt: skip
ARM_DIM = sum(n for _, n in ARM_FIELDS)
ACTION_DIM = ARM_DIM * len(ARMS)
ACTION_NAMES = [
    f"{arm}_{name}" if n == 1 else f"{arm}_{name}_{i}" for arm in ARMS for name, n in ARM_FIELDS for i in range(n)
]


def arm_slices(arm_index: int) -> dict[str, slice]:
    """Slices of one arm's fields in the ``action`` vector."""
    out, k = {}, arm_index * ARM_DIM
    for name, n in ARM_FIELDS:
        out[name] = slice(k, k + n)
        k += n
    return out


def encode_primitive(strategy: str, stage_index: int, primitive: str) -> list[float]:
    """The ``observation.primitive`` vector of (strategy, stage index, primitive name)."""
    if strategy not in STRATEGY_NAMES:
        raise ValueError(f"strategy must be one of {STRATEGY_NAMES}, got {strategy!r}")
    if not (0 <= int(stage_index) < MAX_STAGES):
        raise ValueError(f"stage_index must be in [0, {MAX_STAGES}), got {stage_index!r}")
    if primitive not in PRIMITIVE_NAMES:
        raise ValueError(f"primitive must be one of {PRIMITIVE_NAMES}, got {primitive!r}")
    v = [0.0] * PRIMITIVE_DIM
    v[STRATEGY_NAMES.index(strategy)] = 1.0
    v[len(STRATEGY_NAMES) + int(stage_index)] = 1.0
    v[len(STRATEGY_NAMES) + MAX_STAGES + PRIMITIVE_NAMES.index(primitive)] = 1.0
    return v


def decode_primitive(prim):
    """The inverse of ``encode_primitive`` for a batch of ``observation.primitive`` rows (B, PRIMITIVE_DIM),
    tensor or array: the (strategy, stage index, primitive name) indices, each (B,)."""
    ns = len(STRATEGY_NAMES)
    return prim[:, :ns].argmax(1), prim[:, ns : ns + MAX_STAGES].argmax(1), prim[:, ns + MAX_STAGES :].argmax(1)


@PreTrainedConfig.register_subclass("flatlab_executor")
@dataclass
class FlatLabExecutorConfig(PreTrainedConfig):
    # cloud
    n_points: int = 1024  # points fed to PointNet++ (first n of the stored random-order cloud at eval)
    # PointNet++ (single-scale grouping): set abstraction levels, then a global level
    sa_npoints: list[int] = field(default_factory=lambda: [256, 64])
    sa_radii: list[float] = field(default_factory=lambda: [0.04, 0.12])  # m
    sa_nsamples: list[int] = field(default_factory=lambda: [16, 32])
    sa_mlps: list[list[int]] = field(default_factory=lambda: [[32, 32, 64], [64, 64, 128]])
    global_mlp: list[int] = field(default_factory=lambda: [128, 256])
    # heads
    cond_dim: int = 64  # embedding of observation.primitive
    head_hidden: list[int] = field(default_factory=lambda: [256, 128])
    use_proprio: bool = True
    # the model frame's origin: "scene" = the scene cloud's mean (paper App. B); "object" = the mean of
    # the segmented object cloud (observation.object_pointcloud, what the strategy generator reads):
    # poses are then predicted relative to the object, not to the table; "object_table" = the object's
    # mean in x, y and the table plane in z (the ``table_quantile`` of the scene cloud's heights: the
    # workspace crop starts at the table top, so its lowest points are the table): heights are then
    # predicted above the table, which is what B's squeeze and C's pinch heights are; "object_top" = the
    # object's mean in x, y and its seen top in z (the ``top_quantile`` of the object cloud's seen heights):
    # heights are then predicted from the object's top, which is where A's touch and press act (the expert
    # presses 1 mm into the top), so the network need not read a 5-mm thickness off the cloud to land there
    frame_center: str = "scene"
    table_quantile: float = 0.05
    top_quantile: float = 0.95
    # a second encoder on the segmented object cloud (``observation.object_pointcloud``, in the same model
    # frame): a PointNet (shared MLP of these widths + max pool over the seen points) whose feature joins
    # F_env.  In the 1024-point scene cloud a thin object is a few dozen points a few mm above the table;
    # its own cloud shows its outline and height directly.  [] (default, the paper's): scene cloud only
    object_mlp: list[int] = field(default_factory=list)
    n_object_points: int = 256  # object points fed to that encoder (random subset in training, the first n at eval)
    # stages that start where the arm is (the expert's ``StageSpec.start == "current"``: press, slide,
    # squeeze, grasp, lift, ...) are predicted relative to the arm's measured TCP: start = TCP + d_start,
    # end = start + d_end (rotations: q_start = r_start x q_tcp, q_end = r_end x q_start); stages that
    # start at a pose computed from the scene (touch, approach, pre-approach) stay in the model frame.
    # Only with decompose_primitives (the stage is known).  false (default, the paper's): every pose absolute
    relative_starts: bool = False
    # loss
    lambda_pos: float = 10.0  # paper App. D: P-MSE minimal for lambda_pos 5-10 with lambda_rot 1
    lambda_rot: float = 1.0
    lambda_grip: float = 1.0
    lambda_active: float = 0.1  # BCE of the per-arm "commanded by this primitive" flag
    rotation_loss: bool = True  # false: ablation A-4
    decompose_primitives: bool = True  # false: ablation A-5 (A-6: both false)
    # augmentation (training only; paper App. B)
    augment: bool = True
    aug_scale: list[float] = field(default_factory=lambda: [0.9, 1.1])
    aug_jitter_std: float = 0.002  # m
    aug_rot_z_deg: float = 180.0  # uniform in [-x, x] about the vertical axis through the cloud centre
    # test-time augmentation (inference only): average the world-frame predictions over this many
    # model frames, rotated about z by 360/k degree steps (a model trained with aug_rot_z_deg < 180: k
    # turns spread evenly over [-aug_rot_z_deg, aug_rot_z_deg]), each on a different subset of the cloud's
    # points (1: one pass, the paper's).  Positions, grippers and "active" are averaged, quaternions
    # sign-aligned and averaged.  Rotation about z is an augmentation the model was trained on.
    tta: int = 1
    # optimizer (paper App. B: Adam, lr 1e-4, weight decay 1e-4)
    optimizer_lr: float = 1e-4
    optimizer_weight_decay: float = 1e-4
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=identity_normalization)

    def __post_init__(self):
        super().__post_init__()

        def bad(name, msg):
            raise ValueError(f"flatlab_executor config: --policy.{name}: {msg}")

        if any(int(c) < 1 for c in self.object_mlp):
            bad("object_mlp", f"widths must be >= 1, got {self.object_mlp}")
        if self.object_mlp and self.frame_center not in OBJECT_FRAMES:
            bad("object_mlp", f"an object encoder needs frame_center in {OBJECT_FRAMES} (the object cloud input), "
                f"got {self.frame_center!r}")
        if self.relative_starts and not self.use_proprio:
            bad("relative_starts", "poses relative to the TCP need the TCP: set use_proprio=true")
        if self.n_object_points < 1:
            bad("n_object_points", f"must be >= 1, got {self.n_object_points}")
        if self.n_points < 16:
            bad("n_points", f"must be >= 16, got {self.n_points}")
        if not 1 <= int(self.tta) <= 64:
            bad("tta", f"must be in [1, 64] (1: no test-time augmentation), got {self.tta}")
        if self.frame_center not in FRAME_CENTERS:
            bad("frame_center", f"must be one of {FRAME_CENTERS}, got {self.frame_center!r}")
        if not 0.0 <= self.table_quantile < 0.5:
            bad("table_quantile", f"must be in [0, 0.5), got {self.table_quantile}")
        if not 0.5 < self.top_quantile <= 1.0:
            bad("top_quantile", f"must be in (0.5, 1], got {self.top_quantile}")
        n = len(self.sa_npoints)
        if n == 0 or not (len(self.sa_radii) == len(self.sa_nsamples) == len(self.sa_mlps) == n):
            bad("sa_npoints", "sa_npoints, sa_radii, sa_nsamples and sa_mlps need the same non-zero length")
        prev = self.n_points
        for i, k in enumerate(self.sa_npoints):
            if not (1 <= k <= prev):
                bad("sa_npoints", f"level {i}: {k} centroids from {prev} points (need 1 <= k <= {prev})")
            prev = k
        if any(r <= 0 for r in self.sa_radii):
            bad("sa_radii", f"must be > 0 m, got {self.sa_radii}")
        if any(not m for m in self.sa_mlps) or not self.global_mlp or not self.head_hidden:
            bad("sa_mlps", "sa_mlps entries, global_mlp and head_hidden must be non-empty")
        lo, hi = (list(self.aug_scale) + [None, None])[:2]
        if len(self.aug_scale) != 2 or not (0 < lo <= hi):
            bad("aug_scale", f"must be [lo, hi] with 0 < lo <= hi, got {self.aug_scale}")
        if self.aug_jitter_std < 0 or not (0 <= self.aug_rot_z_deg <= 180):
            bad("aug_jitter_std/aug_rot_z_deg", "jitter >= 0 m, rotation in [0, 180] deg")
        for name in ("lambda_pos", "lambda_rot", "lambda_grip", "lambda_active"):
            if getattr(self, name) < 0:
                bad(name, f"must be >= 0, got {getattr(self, name)}")

    @property
    def ablation(self) -> str:
        """``full``, ``A-4``, ``A-5`` or ``A-6`` (paper Table 2)."""
        return {(True, True): "full", (True, False): "A-4", (False, True): "A-5", (False, False): "A-6"}[
            (self.decompose_primitives, self.rotation_loss)
        ]

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
        return AdamConfig(lr=self.optimizer_lr, weight_decay=self.optimizer_weight_decay)

    def get_scheduler_preset(self) -> None:
        return None

    def validate_features(self) -> None:
        need = {OBS_POINTCLOUD: None, OBS_PRIMITIVE: (PRIMITIVE_DIM,)}
        if self.use_proprio:
            need[OBS_TCP_STATE] = (TCP_STATE_DIM,)
        if self.frame_center in OBJECT_FRAMES:
            need[OBS_OBJECT_CLOUD] = None
        for key, shape in need.items():
            ft = self.input_features.get(key)
            if ft is None:
                raise ValueError(
                    f"flatlab_executor: input feature '{key}' missing (have {sorted(self.input_features)}); "
                    "train on a `flatlab primitive-export` dataset"
                    + ("" if key != OBS_TCP_STATE else " or set --policy.use_proprio=false")
                )
            if shape is not None and tuple(ft.shape) != shape:
                raise ValueError(f"flatlab_executor: feature '{key}' has shape {tuple(ft.shape)}, expected {shape}")
        pc = self.input_features[OBS_POINTCLOUD]
        if len(pc.shape) != 2 or pc.shape[1] != 3:
            raise ValueError(f"flatlab_executor: feature '{OBS_POINTCLOUD}' has shape {tuple(pc.shape)}, expected (N, 3)")
        act = self.output_features.get(ACTION)
        if act is None or tuple(act.shape) != (ACTION_DIM,):
            got = None if act is None else tuple(act.shape)
            raise ValueError(f"flatlab_executor: output feature '{ACTION}' has shape {got}, expected ({ACTION_DIM},)")


# ------------------------------------------------- the training set's contract (flatlab primitive-export)
TASK_RE = re.compile(r"^flatlab primitive \| object=(?P<object>[^|]+) \| split=(?P<split>\w+) \| strategy=(?P<strategy>[ABC])$")
TRAIN_SPLIT = "train"


class PrimitiveExportError(ValueError):
    """Bad input; the message names the flag / file and field."""


def task_string(object_id: str, split: str, strategy: str) -> str:
    return f"flatlab primitive | object={object_id} | split={split} | strategy={strategy}"


def check_training_tasks(ds_meta) -> None:
    """Raise unless every task of the dataset is a flatlab primitive of a Train-split object."""
    tasks = getattr(ds_meta, "tasks", None)
    names = [] if tasks is None else list(tasks.index)
    where = getattr(ds_meta, "root", "the dataset")
    if not names:
        raise PrimitiveExportError(f"{where}: meta/tasks: no tasks; not a `flatlab primitive-export` dataset")
    bad, foreign = [], []
    for t in names:
        m = TASK_RE.match(str(t))
        if m is None:
            foreign.append(t)
        elif m["split"] != TRAIN_SPLIT:
            bad.append(f"{m['object']} ({m['split']})")
    if foreign:
        raise PrimitiveExportError(
            f"{where}: meta/tasks: {foreign[:3]} are not `flatlab primitive-export` tasks; flatlab_executor trains only on those"
        )
    if bad:
        raise PrimitiveExportError(
            f"{where}: meta/tasks: objects outside the Train split {sorted(set(bad))}: Test-alpha / Test-beta objects "
            "never train the executor (export the training set from Train objects only)"
        )

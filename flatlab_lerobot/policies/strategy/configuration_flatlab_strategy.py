"""Config of the ``flatlab_strategy`` policy type (``--policy.type=flatlab_strategy``): the paper's
learned strategy generator (§3.2, App. B).

The policy maps one observation to 3 strategy logits (A, B, C):

* input ``input_key`` only (default ``observation.object_pointcloud``: the object's cloud; ablation
  A-8: ``observation.scene_pointcloud``; A-7: ``observation.images.object``, an RGB crop).  A cloud
  is reduced to xyz (colour-free), ``n_points`` points are drawn, then it is centred on its mean and
  scaled into the unit sphere inside the model (the paper's normalization), so the placement does
  not matter.  With ``use_scale`` (default) the radius of that sphere (the object's size in m) is
  embedded and appended to F: a uniform rescaling -- the paper's scale transformation -- gives the
  same unit-sphere cloud yet may change the label (A <-> B), so without it those labels conflict.
  With ``use_extent`` (not in the paper; off by default) the drawn points' extents in m (vertical:
  the thickness the side cameras see; horizontal: along the principal axes) are embedded too.
  Clouds must then be metric (the env's world-frame cloud; ``flatlab strategy-export`` writes
  centred metric clouds).  ``observation.environment_state``
  is never read; ``validate_features`` keeps ``input_key`` as the only input feature.
* encoder: PointNet (shared point-wise Conv1d + BatchNorm + ReLU per ``encoder_channels``, global
  max pool) -> feature F; for an image, a small CNN with the same channels and a global max pool.
* head: two-layer MLP F -> ``head_hidden`` -> 3 logits.  Projection F -> ``proj_hidden`` ->
  ``proj_dim`` (L2-normalized) for the contrastive term.
* loss: cross-entropy + ``contrast_weight`` (lambda) * NT-Xent(``temperature``, tau) with
  positives = same strategy, different object; negatives = same object, different strategy
  (``contrast_negatives="same_object"``, the paper's; ``"other_strategy"``: any in-batch sample of
  another strategy).  ``contrast_weight=0`` is ablation A-1.  The object groups come from the
  dataset: ``group_size`` consecutive frames of one episode (one train object in one placement,
  its scale / material variants interleaved by strategy, ``flatlab strategy-export``) are loaded
  per sample through lerobot's delta indices.

The label is the dataset's ``action``: the strategy one-hot (3,).  ``select_action`` returns the
softmax over A/B/C; :attr:`FlatLabStrategyPolicy.strategies` the letters chosen for the batch.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, NormalizationMode, PreTrainedConfig
from lerobot.optim import AdamConfig
from lerobot.optim.schedulers import LRSchedulerConfig
from lerobot.utils.constants import ACTION

from flatlab_lerobot.policies import identity_normalization

INPUT_KEYS = ("observation.object_pointcloud", "observation.scene_pointcloud", "observation.images.object")
NEGATIVES = ("same_object", "other_strategy")


@LRSchedulerConfig.register_subclass("flatlab_step")
@dataclass
class FlatLabStepLRConfig(LRSchedulerConfig):
    """torch StepLR: the learning rate times ``gamma`` every ``step_size`` optimizer steps
    (the paper: x0.5 every 30 epochs).  ``num_warmup_steps`` is unused (kept for the base class)."""

    num_warmup_steps: int = 0
    step_size: int = 1000
    gamma: float = 0.5

    def build(self, optimizer, num_training_steps: int):
        from torch.optim.lr_scheduler import StepLR

        return StepLR(optimizer, step_size=self.step_size, gamma=self.gamma)


@PreTrainedConfig.register_subclass("flatlab_strategy")
@dataclass
class FlatLabStrategyConfig(PreTrainedConfig):
    input_key: str = "observation.object_pointcloud"
    n_points: int = 2048  # points drawn from the cloud (random in training, fixed at inference)
    encoder_channels: list[int] = field(default_factory=lambda: [64, 128, 256])
    head_hidden: int = 128
    dropout: float = 0.3
    proj_hidden: int = 128
    proj_dim: int = 64
    contrast_weight: float = 0.5  # lambda; 0 disables the contrastive term
    temperature: float = 0.1  # tau
    contrast_negatives: str = "same_object"
    group_size: int = 4  # frames of one episode per sample (1: no object groups)
    use_scale: bool = True  # also feed log(radius) of the cloud before normalization (its size in m)
    use_extent: bool = False  # also feed log of its extents in m (thickness, length, width; not in the paper)
    augment_yaw: bool = True  # random rotation about the vertical axis in training (clouds only)
    augment_jitter: float = 0.0  # std of Gaussian point jitter in training (unit-sphere units)
    # inference passes averaged (test-time augmentation, clouds only): pass j draws the j-th fixed subset of
    # n_points and turns the cloud by 2*pi*j/k about the vertical (the training's yaw augmentation); the
    # class probabilities are averaged.  1: one pass (subset 0, no turn), as trained and selected
    tta: int = 1
    # optimizer / scheduler presets (the paper: Adam 5e-4, wd 1e-4, x0.5 every 30 epochs)
    optimizer_lr: float = 5e-4
    optimizer_weight_decay: float = 1e-4
    scheduler_step_size: int = 1000  # optimizer steps
    scheduler_gamma: float = 0.5
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=identity_normalization)

    def __post_init__(self):
        super().__post_init__()
        if self.input_key not in INPUT_KEYS:
            raise ValueError(f"--policy.input_key: must be one of {list(INPUT_KEYS)}, got {self.input_key!r}")
        if self.contrast_negatives not in NEGATIVES:
            raise ValueError(
                f"--policy.contrast_negatives: must be one of {list(NEGATIVES)}, got {self.contrast_negatives!r}"
            )
        for name in ("n_points", "head_hidden", "proj_hidden", "proj_dim", "group_size", "scheduler_step_size"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"--policy.{name}: must be >= 1, got {getattr(self, name)!r}")
        if not self.encoder_channels or any(int(c) < 1 for c in self.encoder_channels):
            raise ValueError(f"--policy.encoder_channels: a non-empty list of ints >= 1, got {self.encoder_channels!r}")
        self.check_tta(self.tta)
        if self.contrast_weight < 0:
            raise ValueError(f"--policy.contrast_weight: must be >= 0, got {self.contrast_weight}")
        if self.temperature <= 0:
            raise ValueError(f"--policy.temperature: must be > 0, got {self.temperature}")
        if not 0 <= self.dropout < 1:
            raise ValueError(f"--policy.dropout: must be in [0, 1), got {self.dropout}")

    def check_tta(self, k: int, flag: str = "--policy.tta") -> None:
        """Raise (naming ``flag``) unless this model can average ``k`` inference passes: 1..64, and for
        k > 1 a cloud model trained with yaw augmentation (the passes turn the cloud about z)."""
        if not 1 <= int(k) <= 64:
            raise ValueError(f"{flag}: must be in [1, 64], got {k!r}")
        if int(k) > 1 and (self.is_image or not self.augment_yaw):
            raise ValueError(f"{flag}: passes > 1 turn the cloud about z, which an image model or a model trained "
                             "with --policy.augment_yaw=false never saw; keep 1")

    @property
    def is_image(self) -> bool:
        return self.input_key.startswith("observation.images.")

    @property
    def observation_delta_indices(self) -> list[int] | None:
        return list(range(self.group_size)) if self.group_size > 1 else None

    @property
    def action_delta_indices(self) -> list[int] | None:
        return self.observation_delta_indices

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamConfig:
        return AdamConfig(lr=self.optimizer_lr, weight_decay=self.optimizer_weight_decay)

    def get_scheduler_preset(self) -> FlatLabStepLRConfig:
        return FlatLabStepLRConfig(step_size=self.scheduler_step_size, gamma=self.scheduler_gamma)

    def validate_features(self) -> None:
        """Keep ``input_key`` as the only input feature (so no other observation, in particular
        ``observation.environment_state``, reaches the policy) and check the label feature."""
        feats = self.input_features or {}
        if feats:
            if self.input_key not in feats:
                raise ValueError(
                    f"flatlab_strategy: --policy.input_key={self.input_key!r} is not a feature of the data "
                    f"(has {sorted(feats)})"
                )
            self.input_features = {self.input_key: feats[self.input_key]}
            ft = feats[self.input_key]
            want = 3 if self.is_image else 2
            if len(ft.shape) != want or (not self.is_image and ft.shape[-1] < 3):
                raise ValueError(
                    f"flatlab_strategy: input {self.input_key!r} has shape {tuple(ft.shape)}; expected "
                    + ("(3, H, W)" if self.is_image else "(N, 3+)")
                )
        act = (self.output_features or {}).get(ACTION)
        if act is not None and (tuple(act.shape) != (3,) or act.type is not FeatureType.ACTION):
            raise ValueError(
                f"flatlab_strategy: 'action' must be the strategy one-hot (3,) of type ACTION, got {act.type} "
                f"{tuple(act.shape)} (export the set with `flatlab strategy-export`)"
            )

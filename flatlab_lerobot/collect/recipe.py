"""A data-collection recipe: a typed, validated description of one dataset, loaded from YAML.

Every loading error is ONE :class:`RecipeError` whose message names the file and the field, e.g.
``datasets/tiny_rigid.yaml: field 'image_size': must be an integer >= 16, got 'big'``.
Unknown keys are errors too (a typo must not silently fall back to a default).

Example (``datasets/tiny_rigid.yaml``)::

    name: tiny_rigid
    seed: 0                      # episode i uses seed + i (placement and cloud sampling)
    episodes: 2
    objects: [ref_box]           # ids, or "split:train" / "split:test_alpha" / ...; cycled by episode
    strategy: auto               # auto (the catalog label of each object) | A | B | C
    fps: 10
    max_steps: 120               # frames per episode at most (the expert stops early on success)
    cameras: [front, top]
    image_size: 64
    modalities: [rgb, depth, pointcloud, object_pointcloud, ee_pose, environment_state]
    commit_every: 1              # episodes per crash-safe commit
    workers: 1                   # simulation processes (``--workers`` overrides); same data for any N
    expert: {b_right_half_turn: false}  # the scripted expert's options (strategies.expert.ExpertOptions)
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from flatlab_lerobot.paths import DATASETS_DIR
from flatlab_lerobot.sim.domain import Domain, sample_domain
from flatlab_lerobot.strategies.expert import ExpertOptions
from flatlab_lerobot.tasks import DEFAULT_PLANAR, DEFAULT_YAW_DEG

MODALITIES = ("rgb", "depth", "pointcloud", "object_pointcloud", "ee_pose", "environment_state")
DEFAULT_MODALITIES = ("rgb", "pointcloud", "object_pointcloud", "ee_pose", "environment_state")
CAMERAS = ("front", "top", "left", "right")
STRATEGY_CHOICES = ("auto", "A", "B", "C")
VCODECS = ("h264", "libsvtav1", "hevc", "libx264", "libx265", "libaom-av1")
X26X_PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow")


class RecipeError(ValueError):
    """A malformed recipe; the message names the file and the field."""


@dataclass(frozen=True)
class Randomization:
    xy_range: float = DEFAULT_PLANAR  # object planar offset, uniform in ±xy_range (m)
    yaw_range_deg: float = DEFAULT_YAW_DEG  # object yaw, uniform in ±yaw_range_deg
    # The episode's domain (flatlab_lerobot.sim.domain; recorded per episode in meta/flatlab_episodes.jsonl):
    joint_noise: float = 0.0  # robot start posture: every arm joint uniform in ±joint_noise rad off home
    camera_pos_jitter: float = 0.0  # every camera moved uniform in ±this per world axis (m) ...
    camera_rot_jitter_deg: float = 0.0  # ... and turned uniform in ±this about each of its axes (deg)
    mass_scale: tuple[float, float] = (1.0, 1.0)  # object mass (and inertia) x uniform in [lo, hi]
    friction_scale: tuple[float, float] = (1.0, 1.0)  # object sliding friction x uniform in [lo, hi]

    def domain(self, seed: int, cameras) -> Domain:
        """The episode's domain: a function of the episode seed (a stream apart from the placement's)."""
        return sample_domain(
            seed, cameras, self.joint_noise, self.mass_scale, self.friction_scale,
            self.camera_pos_jitter, self.camera_rot_jitter_deg,
        )  # fmt: skip


@dataclass(frozen=True)
class VideoOptions:
    use_videos: bool = True  # False: cameras/depth stored as images inside the parquet files
    vcodec: str = "h264"  # RGB codec (lerobot's default is libsvtav1; h264 decodes everywhere)
    crf: int | None = None  # None: lerobot's default quality
    preset: str | None = None  # RGB encoder speed preset (x264/x265 names, e.g. "veryfast"); None: codec default
    # Depth is always lossless 12-bit HEVC, so its x265 preset trades only speed against file size
    # (measured at 224 px: "ultrafast" 2.3x less CPU, 2x larger files than the default "medium").
    depth_preset: str | None = None


@dataclass(frozen=True)
class Recipe:
    name: str
    episodes: int
    objects: tuple[str, ...]
    repo_id: str = ""
    seed: int = 0
    strategy: str = "auto"
    fps: int = 10
    max_steps: int = 250
    cameras: tuple[str, ...] = ("front", "top")
    image_size: int = 96
    modalities: tuple[str, ...] = DEFAULT_MODALITIES
    n_points: int = 1024
    n_object_points: int = 256
    pointcloud_cameras: tuple[str, ...] | None = None
    randomization: Randomization = field(default_factory=Randomization)
    video: VideoOptions = field(default_factory=VideoOptions)
    expert: ExpertOptions = field(default_factory=ExpertOptions)  # the scripted expert's options
    commit_every: int = 1  # episodes per crash-safe commit (a crash re-runs at most this many)
    workers: int = 1  # simulation worker processes (the dataset is the same for any number)
    robot_type: str = "flatlab_dual_panda"
    task: str | None = None  # None: the strategy's task description
    description: str = ""
    source: str = "<dict>"  # the file it came from (not part of the identity)

    # ------------------------------------------------------------------ derived
    @property
    def control_dt(self) -> float:
        return 1.0 / self.fps

    def has(self, modality: str) -> bool:
        return modality in self.modalities

    def episode_seed(self, episode_index: int) -> int:
        return self.seed + episode_index

    def object_for(self, episode_index: int) -> str:
        return self.objects[episode_index % len(self.objects)]

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.pop("source")
        for k, v in d.items():
            if isinstance(v, tuple):
                d[k] = list(v)
        return d

    def fingerprint(self) -> str:
        """Hash of everything that determines the episodes' content (not the episode count, so a
        dataset can be extended by raising ``episodes``)."""
        d = self.to_dict()
        for k in ("episodes", "description", "commit_every", "workers"):
            d.pop(k, None)
        for k in ("preset", "depth_preset"):  # added later: unset keeps older fingerprints valid
            if d["video"].get(k) is None:
                d["video"].pop(k, None)
        nominal = dataclasses.asdict(Randomization())
        for k in ("joint_noise", "camera_pos_jitter", "camera_rot_jitter_deg", "mass_scale", "friction_scale"):
            if d["randomization"].get(k) == nominal[k]:  # added later: the nominal value keeps older fingerprints
                d["randomization"].pop(k, None)
        if d["expert"] == dataclasses.asdict(ExpertOptions()):  # added later: the default expert keeps older fingerprints
            d.pop("expert")
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


# ---------------------------------------------------------------------------------- loading
class _V:
    def __init__(self, source: str):
        self.source = source

    def err(self, fld: str, msg: str) -> RecipeError:
        return RecipeError(f"{self.source}: field '{fld}': {msg}")

    def integer(self, fld, value, lo=None, hi=None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.err(fld, f"must be an integer{_range(lo, hi)}, got {value!r}")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise self.err(fld, f"must be an integer{_range(lo, hi)}, got {value!r}")
        return int(value)

    def number(self, fld, value, lo=None, hi=None) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.err(fld, f"must be a number{_range(lo, hi)}, got {value!r}")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise self.err(fld, f"must be a number{_range(lo, hi)}, got {value!r}")
        return float(value)

    def interval(self, fld, value, lo, hi) -> tuple[float, float]:
        """[low, high] with lo <= low <= high <= hi (a single number means [x, x])."""
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value, value]
        bad = f"must be [low, high] with {lo} <= low <= high <= {hi}, got {value!r}"
        if not isinstance(value, list) or len(value) != 2:
            raise self.err(fld, bad)
        a, b = (self.number(fld, x, lo, hi) for x in value)
        if a > b:
            raise self.err(fld, bad)
        return (a, b)

    def string(self, fld, value) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.err(fld, f"must be a non-empty string, got {value!r}")
        return value.strip()

    def boolean(self, fld, value) -> bool:
        if not isinstance(value, bool):
            raise self.err(fld, f"must be true or false, got {value!r}")
        return value

    def choice(self, fld, value, choices) -> str:
        if value not in choices:
            raise self.err(fld, f"must be one of {list(choices)}, got {value!r}")
        return value

    def str_list(self, fld, value, choices=None, allow_empty=False) -> tuple[str, ...]:
        if isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise self.err(fld, f"must be a list of strings, got {value!r}")
        if not value and not allow_empty:
            raise self.err(fld, "must not be empty")
        if len(set(value)) != len(value):
            raise self.err(fld, f"has duplicates: {value!r}")
        if choices is not None:
            bad = [v for v in value if v not in choices]
            if bad:
                raise self.err(fld, f"unknown value(s) {bad}; choose from {list(choices)}")
        return tuple(value)

    def mapping(self, fld, value, known) -> dict:
        if value is None:
            return {}
        if not isinstance(value, dict):
            raise self.err(fld, f"must be a mapping, got {value!r}")
        unknown = sorted(set(value) - set(known))
        if unknown:
            raise self.err(f"{fld}.{unknown[0]}", f"unknown key; known keys: {sorted(known)}")
        return value


def _range(lo, hi) -> str:
    if lo is not None and hi is not None:
        return f" in [{lo}, {hi}]"
    if lo is not None:
        return f" >= {lo}"
    if hi is not None:
        return f" <= {hi}"
    return ""


_TOP_KEYS = {f.name for f in dataclasses.fields(Recipe)} - {"source"}


def _resolve_objects(v: _V, raw) -> tuple[str, ...]:
    from flatlab_lerobot.catalog import SPLITS, load_objects

    items = v.str_list("objects", raw)
    catalog = load_objects()
    out: list[str] = []
    for item in items:
        if item.startswith("split:"):
            split = item.split(":", 1)[1]
            if split not in SPLITS:
                raise v.err("objects", f"unknown split {split!r} in {item!r}; known: {list(SPLITS)}")
            out += sorted(o.id for o in catalog.values() if o.split == split)
        elif item not in catalog:
            raise v.err("objects", f"unknown object id {item!r} (see envs/objects/*.yaml)")
        else:
            out.append(item)
    return tuple(dict.fromkeys(out))


def recipe_from_dict(raw: Any, source: str = "<dict>") -> Recipe:
    v = _V(source)
    if not isinstance(raw, dict):
        raise RecipeError(f"{source}: the recipe must be a YAML mapping, got {type(raw).__name__}")
    unknown = sorted(set(raw) - _TOP_KEYS)
    if unknown:
        raise v.err(unknown[0], f"unknown key; known keys: {sorted(_TOP_KEYS)}")
    for req in ("name", "episodes", "objects"):
        if req not in raw:
            raise v.err(req, "is required")
    kw: dict[str, Any] = {"source": source}
    kw["name"] = v.string("name", raw["name"])
    if any(c in kw["name"] for c in "/\\ ") or kw["name"].startswith("."):
        raise v.err("name", f"must be a plain folder name (no '/', '\\\\', spaces or leading '.'), got {kw['name']!r}")
    kw["episodes"] = v.integer("episodes", raw["episodes"], 1, 1_000_000)
    kw["objects"] = _resolve_objects(v, raw["objects"])
    kw["repo_id"] = v.string("repo_id", raw["repo_id"]) if "repo_id" in raw else f"local/flatlab_{kw['name']}"
    if kw["repo_id"].count("/") != 1:
        raise v.err("repo_id", f"must look like 'owner/name', got {kw['repo_id']!r}")
    if "seed" in raw:
        kw["seed"] = v.integer("seed", raw["seed"], 0, 2**31 - 1)
    if "strategy" in raw:
        kw["strategy"] = v.choice("strategy", raw["strategy"], STRATEGY_CHOICES)
    if "fps" in raw:
        kw["fps"] = v.integer("fps", raw["fps"], 1, 1000)
    if "max_steps" in raw:
        kw["max_steps"] = v.integer("max_steps", raw["max_steps"], 1, 100_000)
    if "cameras" in raw:
        kw["cameras"] = v.str_list("cameras", raw["cameras"], CAMERAS, allow_empty=True)
    if "image_size" in raw:
        kw["image_size"] = v.integer("image_size", raw["image_size"], 16, 1024)
    if "modalities" in raw:
        kw["modalities"] = v.str_list("modalities", raw["modalities"], MODALITIES, allow_empty=True)
    if "n_points" in raw:
        kw["n_points"] = v.integer("n_points", raw["n_points"], 1, 1_000_000)
    if "n_object_points" in raw:
        kw["n_object_points"] = v.integer("n_object_points", raw["n_object_points"], 1, 1_000_000)
    if raw.get("pointcloud_cameras") is not None:
        kw["pointcloud_cameras"] = v.str_list("pointcloud_cameras", raw["pointcloud_cameras"], CAMERAS)
    rand_keys = {f.name for f in dataclasses.fields(Randomization)}
    r = v.mapping("randomization", raw.get("randomization"), rand_keys)
    kw["randomization"] = Randomization(
        xy_range=v.number("randomization.xy_range", r.get("xy_range", DEFAULT_PLANAR), 0.0, 0.3),
        yaw_range_deg=v.number("randomization.yaw_range_deg", r.get("yaw_range_deg", DEFAULT_YAW_DEG), 0.0, 180.0),
        joint_noise=v.number("randomization.joint_noise", r.get("joint_noise", 0.0), 0.0, 0.5),
        camera_pos_jitter=v.number("randomization.camera_pos_jitter", r.get("camera_pos_jitter", 0.0), 0.0, 0.1),
        camera_rot_jitter_deg=v.number(
            "randomization.camera_rot_jitter_deg", r.get("camera_rot_jitter_deg", 0.0), 0.0, 15.0
        ),
        mass_scale=v.interval("randomization.mass_scale", r.get("mass_scale", [1.0, 1.0]), 0.1, 10.0),
        friction_scale=v.interval("randomization.friction_scale", r.get("friction_scale", [1.0, 1.0]), 0.1, 10.0),
    )
    vid = v.mapping("video", raw.get("video"), {"use_videos", "vcodec", "crf", "preset", "depth_preset"})
    crf = vid.get("crf")
    kw["video"] = VideoOptions(
        use_videos=v.boolean("video.use_videos", vid.get("use_videos", True)),
        vcodec=v.choice("video.vcodec", vid.get("vcodec", "h264"), VCODECS),
        crf=None if crf is None else v.integer("video.crf", crf, 0, 63),
        preset=None if vid.get("preset") is None else v.choice("video.preset", vid["preset"], X26X_PRESETS),
        depth_preset=(
            None
            if vid.get("depth_preset") is None
            else v.choice("video.depth_preset", vid["depth_preset"], X26X_PRESETS)
        ),
    )
    if kw["video"].preset is not None and kw["video"].vcodec not in ("h264", "hevc", "libx264", "libx265"):
        raise v.err("video.preset", f"presets are x264/x265 names; not for vcodec {kw['video'].vcodec!r}")
    exp_keys = {f.name for f in dataclasses.fields(ExpertOptions)}
    e = v.mapping("expert", raw.get("expert"), exp_keys)
    kw["expert"] = ExpertOptions(**{k: v.boolean(f"expert.{k}", e[k]) for k in sorted(e)})
    if "commit_every" in raw:
        kw["commit_every"] = v.integer("commit_every", raw["commit_every"], 1, 10_000)
    if "workers" in raw:
        kw["workers"] = v.integer("workers", raw["workers"], 1, 64)
    if "robot_type" in raw:
        kw["robot_type"] = v.string("robot_type", raw["robot_type"])
    if raw.get("task") is not None:
        kw["task"] = v.string("task", raw["task"])
    if raw.get("description") is not None:
        kw["description"] = v.string("description", raw["description"])
    rec = Recipe(**kw)
    # cross-field checks
    if (rec.has("rgb") or rec.has("depth")) and not rec.cameras:
        raise v.err("cameras", "modalities 'rgb'/'depth' need at least one camera")
    pc_cams = rec.pointcloud_cameras or rec.cameras
    if (rec.has("pointcloud") or rec.has("object_pointcloud")) and not pc_cams:
        raise v.err("pointcloud_cameras", "point-cloud modalities need at least one camera")
    if rec.strategy != "auto":
        from flatlab_lerobot.catalog import load_objects

        cat = load_objects()
        if rec.strategy == "C" and any(not cat[o].deformable for o in rec.objects):
            raise v.err("strategy", "strategy C needs deformable objects only")
    return rec


def load_recipe(path: str | Path) -> Recipe:
    """The recipe in file ``path``; a path that is not a file may name a shipped recipe
    (``datasets/<name>.yaml`` of the project or the installed wheel: ``tiny_rigid``, ``datasets/tiny_rigid.yaml``)."""
    path = Path(path)
    source = str(path)
    if not path.is_file():
        shipped = DATASETS_DIR / (path.name if path.suffix else f"{path.name}.yaml")
        if not shipped.is_file():
            names = sorted(p.stem for p in DATASETS_DIR.glob("*.yaml"))
            raise RecipeError(f"{source}: recipe file not found (shipped recipes: {', '.join(names)})")
        path, source = shipped, str(shipped)
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise RecipeError(f"{source}: invalid YAML: {exc}") from exc
    return recipe_from_dict(raw, source)

"""LeRobotDataset v3 writer with crash-safe, resumable commits.

Layout under ``--out`` (default ``outputs/datasets``)::

    <out>/<name>/                 the committed dataset (LeRobotDataset root), always loadable
    <out>/.<name>.staging/        the next version, being written (hard links to the committed
                                  data/video files + private copies of the small meta files)
    <out>/.<name>.old/            the previous version, only during the swap

A commit (every ``recipe.commit_every`` episodes): ``resume`` the staging copy, add the
episodes, ``finalize``, write FlatLab's own meta files, drop a ``.flatlab_ready`` marker, then
``rename(committed -> .old)``, ``rename(staging -> committed)``, delete ``.old``.  After a
``resume`` lerobot writes new episodes to *new* data/video/episode-meta files, so the hard-linked
files of the committed version are never written; the files lerobot rewrites in place
(``meta/info.json``, ``meta/stats.json``, ``meta/tasks.parquet``) are private copies.
:func:`recover` turns any crash state back into one committed version: a crash before the
marker loses only the uncommitted episodes (re-run deterministically from their seeds), a
crash after it completes the swap.

FlatLab metadata (inside ``meta/``, committed with the data):

* ``meta/flatlab.json``: the recipe, its fingerprint, camera intrinsics/extrinsics (so clouds can
  be rebuilt from depth), feature notes;
* ``meta/flatlab_episodes.jsonl``: one line per *attempted* episode (seed, object, placement,
  success, failure reason, ``dataset_episode_index`` or null when it produced no frame).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from flatlab_lerobot.collect.recipe import Recipe, RecipeError
from flatlab_lerobot.collect.runner import EpisodeResult
from flatlab_lerobot.sim.robot import ARMS

READY = ".flatlab_ready"
META_JSON = "meta/flatlab.json"
EPISODES_JSONL = "meta/flatlab_episodes.jsonl"
FORMAT_VERSION = 1
# Files lerobot writes once and never touches again after a resume: hard-linked into staging.
_IMMUTABLE_DIRS = ("data", "videos", "meta/episodes")


class DatasetMismatch(RuntimeError):
    """The folder holds a dataset made from another recipe (or not by FlatLab)."""


# ---------------------------------------------------------------------------------- features
def joint_names() -> list[str]:
    return [f"{arm}_{j}" for arm in ARMS for j in [*(f"joint{i}" for i in range(1, 8)), "gripper_width"]]


def build_features(recipe: Recipe) -> dict:
    from flatlab_lerobot.strategies import ENV_STATE_NAMES

    s = recipe.image_size
    vis = "video" if recipe.video.use_videos else "image"
    feats: dict = {
        "observation.state": {"dtype": "float32", "shape": (16,), "names": joint_names()},
        "action": {"dtype": "float32", "shape": (16,), "names": joint_names()},
    }
    if recipe.has("rgb"):
        for cam in recipe.cameras:
            feats[f"observation.images.{cam}"] = {
                "dtype": vis, "shape": (s, s, 3), "names": ["height", "width", "channels"],
            }  # fmt: skip
    if recipe.has("depth"):
        for cam in recipe.cameras:
            feats[f"observation.depth.{cam}"] = {
                "dtype": vis, "shape": (s, s, 1), "names": ["height", "width", "channels"],
                "info": {"is_depth_map": True},
            }  # fmt: skip
    if recipe.has("pointcloud"):
        feats["observation.pointcloud"] = {"dtype": "float32", "shape": (recipe.n_points, 3), "names": None}
    if recipe.has("object_pointcloud"):
        feats["observation.object_pointcloud"] = {
            "dtype": "float32", "shape": (recipe.n_object_points, 3), "names": None,
        }  # fmt: skip
    if recipe.has("ee_pose"):
        feats["observation.ee_pose"] = {
            "dtype": "float32", "shape": (14,),
            "names": [f"{arm}_{k}" for arm in ARMS for k in ("x", "y", "z", "qw", "qx", "qy", "qz")],
        }  # fmt: skip
    if recipe.has("environment_state"):
        feats["observation.environment_state"] = {"dtype": "float32", "shape": (14,), "names": list(ENV_STATE_NAMES)}
    feats.update(
        {
            "stage_index": {"dtype": "int64", "shape": (1,), "names": None},
            "stage": {"dtype": "string", "shape": (1,), "names": None},
            "strategy": {"dtype": "string", "shape": (1,), "names": None},
            "object_id": {"dtype": "string", "shape": (1,), "names": None},
            "success": {"dtype": "bool", "shape": (1,), "names": None},
            "failure_reason": {"dtype": "string", "shape": (1,), "names": None},
            "episode_seed": {"dtype": "int64", "shape": (1,), "names": None},
        }
    )
    return feats


def camera_meta(recipe: Recipe) -> dict:
    """Per camera: image size, pinhole intrinsics and camera-to-world extrinsics (fixed cameras)."""
    from flatlab_lerobot.collect.runner import make_env

    cams = list(dict.fromkeys([*recipe.cameras, *(recipe.pointcloud_cameras or ())]))
    if not cams:
        return {}
    env = make_env(recipe, recipe.objects[0])
    try:
        env.reset(seed=0)
        out = {}
        for cam in cams:
            fx, fy, cx, cy = env.rig.intrinsics(cam)
            pos, R = env.rig.extrinsics(env.sim.data, cam)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R, pos
            out[cam] = {
                "width": recipe.image_size,
                "height": recipe.image_size,
                "fx": fx, "fy": fy, "cx": cx, "cy": cy,
                "K": [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]],
                "cam_to_world": T.tolist(),
                "znear": float(env.rig._znear), "zfar": float(env.rig._zfar),
            }  # fmt: skip
        return out
    finally:
        env.close()


CAMERA_CONVENTION = (
    "OpenGL/MuJoCo camera frame: x right, y up, the camera looks along -z. Pixel (u=col, v=row, row 0 at "
    "the top) with metric depth z (metres along the optical axis; observation.depth.* decodes to mm by "
    "default) -> p_cam = ((u - cx) z / fx, -(v - cy) z / fy, -z); p_world = R p_cam + t with "
    "[R|t] = cam_to_world[:3]. Depth at or beyond 0.99*zfar means nothing was hit."
)


def depth_to_points(depth_m: np.ndarray, cam: dict) -> np.ndarray:
    """World points (K, 3) from an (H, W) depth map in metres and a ``meta/flatlab.json`` camera."""
    depth_m = np.asarray(depth_m, dtype=np.float64).squeeze()
    valid = (depth_m > 0) & (depth_m < 0.99 * cam["zfar"])
    v, u = np.nonzero(valid)
    z = depth_m[v, u]
    p = np.stack([(u - cam["cx"]) * z / cam["fx"], -(v - cam["cy"]) * z / cam["fy"], -z], axis=1)
    T = np.asarray(cam["cam_to_world"])
    return p @ T[:3, :3].T + T[:3, 3]


# ---------------------------------------------------------------------------------- store
def _link_or_copy_tree(src: Path, dst: Path) -> None:
    for dirpath, _, files in os.walk(src):
        rel = Path(dirpath).relative_to(src)
        (dst / rel).mkdir(parents=True, exist_ok=True)
        immutable = any(str(rel) == d or str(rel).startswith(d + os.sep) for d in _IMMUTABLE_DIRS)
        for fn in files:
            s, d = Path(dirpath) / fn, dst / rel / fn
            if fn == READY:
                continue
            if immutable:
                try:
                    os.link(s, d)
                    continue
                except OSError:
                    pass
            shutil.copy2(s, d)


def _fsync_tree(root: Path) -> None:
    for dirpath, _, files in os.walk(root):
        for fn in files:
            try:
                fd = os.open(os.path.join(dirpath, fn), os.O_RDONLY)
                os.fsync(fd)
                os.close(fd)
            except OSError:
                pass


class DatasetStore:
    """The committed dataset of one recipe under ``out``, and its staging version."""

    def __init__(self, recipe: Recipe, out: Path):
        self.recipe = recipe
        self.out = Path(out)
        self.root = self.out / recipe.name
        self.staging = self.out / f".{recipe.name}.staging"
        self.old = self.out / f".{recipe.name}.old"
        self.ds = None
        self._pending: list[dict] = []
        self._camera_meta: dict | None = None

    # ------------------------------------------------------------------ recovery / state
    def recover(self) -> str:
        """Bring the folder back to exactly one committed version; returns what was done."""
        self.out.mkdir(parents=True, exist_ok=True)
        did = "clean"
        staged_ready = (self.staging / READY).is_file()
        if not self.root.exists():
            if staged_ready:
                os.replace(self.staging, self.root)
                did = "completed an interrupted commit"
            elif self.old.exists():
                os.replace(self.old, self.root)
                did = "restored the previous version"
        if self.staging.exists():
            shutil.rmtree(self.staging)
            did = "discarded uncommitted episodes" if did == "clean" else did
        if self.old.exists():
            shutil.rmtree(self.old)
        (self.root / READY).unlink(missing_ok=True)
        return did

    def records(self) -> list[dict]:
        """The committed episode records (one per attempted episode)."""
        p = self.root / EPISODES_JSONL
        if not p.is_file():
            return []
        return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]

    def check_compatible(self) -> None:
        if not self.root.exists():
            return
        meta = self.root / META_JSON
        if not meta.is_file():
            raise DatasetMismatch(f"{self.root} exists but is not a FlatLab collection (no {META_JSON}); "
                                  "choose another --out or pass --overwrite")  # fmt: skip
        saved = json.loads(meta.read_text())
        if saved.get("recipe_fingerprint") != self.recipe.fingerprint():
            raise DatasetMismatch(
                f"{self.root} was collected from a different recipe (fingerprint {saved.get('recipe_fingerprint')} "
                f"!= {self.recipe.fingerprint()}); choose another --out or pass --overwrite"
            )
        from lerobot.datasets.io_utils import load_info

        info = load_info(self.root)
        saved_eps = sum(1 for r in self.records() if r.get("dataset_episode_index") is not None)
        if info.total_episodes != saved_eps:
            raise DatasetMismatch(
                f"{self.root}: meta/info.json has {info.total_episodes} episodes but {EPISODES_JSONL} lists "
                f"{saved_eps}; the folder was modified outside `flatlab collect`"
            )

    # ------------------------------------------------------------------ writing
    def _encoders(self) -> dict:
        from lerobot.configs.video import DepthEncoderConfig, RGBEncoderConfig

        v = self.recipe.video
        kw = {"vcodec": v.vcodec}
        if v.crf is not None:
            kw["crf"] = v.crf
        # lerobot's depth default (lossless 12-bit HEVC), minus x265's per-video banner on stderr
        depth = DepthEncoderConfig(extra_options={"x265-params": "lossless=1:log-level=error"})
        return {"rgb_encoder": RGBEncoderConfig(**kw), "depth_encoder": depth}

    def begin(self) -> None:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        if self.staging.exists():
            shutil.rmtree(self.staging)
        self._pending = []
        self._n_saved = sum(1 for r in self.records() if r.get("dataset_episode_index") is not None)
        if self.root.exists():
            _link_or_copy_tree(self.root, self.staging)
            self.ds = LeRobotDataset.resume(
                self.recipe.repo_id, root=self.staging, video_backend="pyav", **self._encoders()
            )
        else:
            self.ds = LeRobotDataset.create(
                self.recipe.repo_id,
                fps=self.recipe.fps,
                features=build_features(self.recipe),
                root=self.staging,
                robot_type=self.recipe.robot_type,
                use_videos=self.recipe.video.use_videos,
                video_backend="pyav",
                **self._encoders(),
            )

    def add(self, result: EpisodeResult) -> None:
        rec = result.record()
        if result.frames:
            for f in result.frames:
                self.ds.add_frame(f)
            _no_hf_progress_bars()  # lerobot re-enables them after each metadata write
            self.ds.save_episode(parallel_encoding=False)
            rec["dataset_episode_index"] = self._n_saved
            self._n_saved += 1
        else:
            rec["dataset_episode_index"] = None
        self._pending.append(rec)

    def commit(self) -> None:
        self.ds.finalize()
        self.ds = None
        records = self.records() + self._pending
        if self._camera_meta is None:
            self._camera_meta = camera_meta(self.recipe)
        meta = {
            "format_version": FORMAT_VERSION,
            "generator": "flatlab collect",
            "recipe": self.recipe.to_dict(),
            "recipe_source": self.recipe.source,
            "recipe_fingerprint": self.recipe.fingerprint(),
            "cameras": self._camera_meta,
            "camera_convention": CAMERA_CONVENTION,
            "frame_convention": "frame t = observation before step t + expert action at step t (joint targets)",
            "episodes_attempted": len(records),
            "episodes_saved": sum(1 for r in records if r["dataset_episode_index"] is not None),
            "episodes_successful": sum(1 for r in records if r["success"]),
        }
        (self.staging / META_JSON).write_text(json.dumps(meta, indent=2))
        (self.staging / EPISODES_JSONL).write_text("".join(json.dumps(r) + "\n" for r in records))
        (self.staging / "README.md").write_text(render_card(self.recipe, meta, records))
        shutil.rmtree(self.staging / "images", ignore_errors=True)  # lerobot's temporary frames
        _fsync_tree(self.staging)
        (self.staging / READY).write_text("ok\n")
        _fsync_dir(self.staging)
        if self.root.exists():
            os.replace(self.root, self.old)
        os.replace(self.staging, self.root)
        _fsync_dir(self.out)
        (self.root / READY).unlink(missing_ok=True)
        if self.old.exists():
            shutil.rmtree(self.old)
        self._pending = []

    def abort(self) -> None:
        """Drop the uncommitted episodes (e.g. on Ctrl-C)."""
        if self.ds is not None:
            try:
                self.ds.finalize()
            except Exception:  # noqa: BLE001, S110 -- best effort while aborting
                pass
            self.ds = None
        shutil.rmtree(self.staging, ignore_errors=True)
        self._pending = []


def _no_hf_progress_bars() -> None:
    try:
        from datasets.utils.logging import disable_progress_bar

        disable_progress_bar()
    except Exception:  # noqa: BLE001, S110 -- cosmetic only
        pass


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
        os.fsync(fd)
        os.close(fd)
    except OSError:
        pass


# ---------------------------------------------------------------------------------- card
def card_template_path() -> Path:
    return Path(__file__).resolve().parents[2] / "datasets" / "card_template.md"


_FALLBACK_CARD = """# {name}

FlatLab-LeRobot expert demonstrations ({episodes_saved} episodes, {episodes_successful} successful).

Recipe: `{recipe_source}` (fingerprint `{fingerprint}`)

{episode_table}
"""


def render_card(recipe: Recipe, meta: dict, records: list[dict]) -> str:
    p = card_template_path()
    template = p.read_text() if p.is_file() else _FALLBACK_CARD
    rows = ["| # | seed | object | strategy | frames | success | failure reason |", "|---|---|---|---|---|---|---|"]
    for r in records:
        idx = r["dataset_episode_index"]
        rows.append(
            f"| {'-' if idx is None else idx} | {r['seed']} | {r['object_id']} | {r['strategy']} | {r['num_frames']} "
            f"| {r['success']} | {r['failure_reason'] or ''} |"
        )
    feats = build_features(recipe)
    feat_rows = ["| key | dtype | shape |", "|---|---|---|"] + [
        f"| `{k}` | {v['dtype']} | {tuple(v['shape'])} |" for k, v in feats.items()
    ]
    values = {
        "name": recipe.name,
        "repo_id": recipe.repo_id,
        "description": recipe.description or "Scripted-expert demonstrations of grasping flat objects.",
        "recipe_source": recipe.source,
        "fingerprint": recipe.fingerprint(),
        "fps": recipe.fps,
        "cameras": ", ".join(recipe.cameras) or "none",
        "image_size": recipe.image_size,
        "modalities": ", ".join(recipe.modalities),
        "objects": ", ".join(recipe.objects),
        "seed": recipe.seed,
        "episodes_attempted": meta["episodes_attempted"],
        "episodes_saved": meta["episodes_saved"],
        "episodes_successful": meta["episodes_successful"],
        "success_rate": f"{100 * meta['episodes_successful'] / max(1, meta['episodes_attempted']):.0f}%",
        "feature_table": "\n".join(feat_rows),
        "episode_table": "\n".join(rows),
        "recipe_yaml": _yaml(recipe.to_dict()),
    }
    try:
        return template.format(**values)
    except (KeyError, IndexError, ValueError) as exc:
        raise RecipeError(f"{p}: bad placeholder in the card template: {exc}") from exc


def _yaml(d: dict) -> str:
    import yaml

    return yaml.safe_dump(d, sort_keys=False)

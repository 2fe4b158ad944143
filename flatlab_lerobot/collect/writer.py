"""LeRobotDataset v3 writer with crash-safe, resumable commits.

Camera streams are encoded by the process that simulated the episode (:func:`encode_videos`,
lerobot's codec settings, no PNG round trip); :class:`DatasetStore` then adds the episode through
lerobot's ``add_frame`` / ``save_episode``, handing it the finished MP4s (:class:`PreEncodedVideos`).

Layout under ``--out`` (default ``outputs/datasets``)::

    <out>/<name>/                 the committed dataset (LeRobotDataset root), always loadable
    <out>/.<name>.staging/        the next version, being written (hard links to the committed
                                  data/video files + private copies of the small meta files)
    <out>/.<name>.old/            the previous version, only during the swap
    <out>/.<name>.work/           MP4s encoded by the workers, not yet added (dropped on recovery)

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
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from flatlab_lerobot.collect.recipe import Recipe, RecipeError
from flatlab_lerobot.paths import CARD_TEMPLATE, portable_name
from flatlab_lerobot.collect.runner import EpisodeResult
from flatlab_lerobot.sim.core import ENV_STATE_DIM, ENV_STATE_NAMES, STATE_NAMES
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
    return list(STATE_NAMES)


def build_features(recipe: Recipe) -> dict:
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
        feats["observation.environment_state"] = {"dtype": "float32", "shape": (ENV_STATE_DIM,), "names": list(ENV_STATE_NAMES)}
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
                "znear": float(env.rig.znear), "zfar": float(env.rig.zfar),
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


def episode_cameras(cameras: dict, record: dict | None) -> dict:
    """The ``meta/flatlab.json`` cameras as they were in one episode: a recipe with camera jitter
    records each episode's ``cam_to_world`` in its ``meta/flatlab_episodes.jsonl`` line
    (``domain.cam_to_world``), which replaces the nominal extrinsics."""
    moved = ((record or {}).get("domain") or {}).get("cam_to_world") or {}
    return {c: {**m, "cam_to_world": moved[c]} if c in moved else m for c, m in cameras.items()}


def depth_to_points(depth_m: np.ndarray, cam: dict) -> np.ndarray:
    """World points (K, 3) from an (H, W) depth map in metres and a ``meta/flatlab.json`` camera."""
    depth_m = np.asarray(depth_m, dtype=np.float64).squeeze()
    valid = (depth_m > 0) & (depth_m < 0.99 * cam["zfar"])
    v, u = np.nonzero(valid)
    z = depth_m[v, u]
    p = np.stack([(u - cam["cx"]) * z / cam["fx"], -(v - cam["cy"]) * z / cam["fy"], -z], axis=1)
    T = np.asarray(cam["cam_to_world"])
    return p @ T[:3, :3].T + T[:3, 3]


# ---------------------------------------------------------------------------------- videos
# Camera streams are encoded where the episode was simulated (a collection worker), straight from
# the rendered arrays -- no PNG/TIFF round trip, no frames shipped to the writer process.  The
# writer hands the finished MP4s and their stats to lerobot's ``save_episode`` through its
# streaming-encoder hook (:class:`PreEncodedVideos`), so lerobot still places, concatenates and
# indexes them as it does for its own encoder.  The codec settings come from lerobot's encoder
# configs, resolved once in the writer into plain :class:`StreamSpec` data: importing lerobot
# pulls in torch (5-20 s and ~700 MB per process), which the workers never do.
# One codec thread per stream: each worker uses one core, and the bytes do not depend on how
# many cores the machine has.
ENCODER_THREADS = 1


def encoders(recipe: Recipe):
    """(RGB, depth) lerobot encoder configs of a recipe (also recorded in ``meta/info.json``)."""
    from lerobot.configs.video import DepthEncoderConfig, RGBEncoderConfig

    v = recipe.video
    kw = {"vcodec": v.vcodec}
    if v.crf is not None:
        kw["crf"] = v.crf
    if v.preset is not None:
        kw["preset"] = v.preset
    # lerobot's depth default (lossless 12-bit HEVC), minus x265's per-video banner on stderr and
    # its thread pool (one core per worker; under contention the pool's hand-offs cost more than
    # they gain), with 16-px coding tree units: at 224 px, 100 frames, 43 % less CPU (0.24 vs
    # 0.42 s per stream) for 3 % larger files -- lossless, so the decoded depth is the same.
    depth = DepthEncoderConfig(
        preset=v.depth_preset, extra_options={"x265-params": "lossless=1:ctu=16:log-level=error:pools=none"}
    )
    return RGBEncoderConfig(**kw), depth


def video_keys(recipe: Recipe) -> list[str]:
    """Features stored as videos (empty when the recipe stores images in the parquet files)."""
    if not recipe.video.use_videos:
        return []
    keys = [f"observation.images.{c}" for c in recipe.cameras] if recipe.has("rgb") else []
    return keys + ([f"observation.depth.{c}" for c in recipe.cameras] if recipe.has("depth") else [])


@dataclass(frozen=True)
class StreamSpec:
    """How one video feature is encoded: lerobot's encoder config reduced to plain data."""

    vcodec: str
    pix_fmt: str
    options: dict  # codec options, as lerobot passes them to PyAV
    depth: bool = False
    depth_min: float = 0.0  # depth quantiser (metres), lerobot's DepthEncoderConfig fields
    depth_max: float = 0.0
    shift: float = 0.0
    use_log: bool = True
    qmax: int = 0


def stream_specs(recipe: Recipe) -> dict[str, StreamSpec]:
    """Feature -> :class:`StreamSpec` of the recipe's video features (imports lerobot)."""
    from lerobot.configs.video import DEPTH_QMAX

    rgb, depth = encoders(recipe)
    out = {}
    for k in video_keys(recipe):
        if k.startswith("observation.depth."):
            out[k] = StreamSpec(depth.vcodec, depth.pix_fmt, depth.get_codec_options(ENCODER_THREADS, as_strings=True),
                                True, depth.depth_min, depth.depth_max, depth.shift, depth.use_log, DEPTH_QMAX)  # fmt: skip
        else:
            out[k] = StreamSpec(rgb.vcodec, rgb.pix_fmt, rgb.get_codec_options(ENCODER_THREADS, as_strings=True))
    return out


def quantize_depth(depth_m: np.ndarray, spec: StreamSpec) -> np.ndarray:
    """(H, W) uint16 depth codes of float metres, the same operations (and float32 rounding) as
    ``lerobot.datasets.depth_utils.quantize_depth`` -- tests/test_collect.py checks bit equality."""
    d = np.asarray(depth_m)
    if d.ndim == 3:
        d = d[..., 0]
    d = d.astype(np.float32, order="K")
    dmin, dmax, shift = np.float32(spec.depth_min), np.float32(spec.depth_max), np.float32(spec.shift)
    if spec.use_log:
        log_min, log_max = math.log(float(dmin + shift)), math.log(float(dmax + shift))
        norm = (np.log(d + shift) - log_min) / (log_max - log_min)
    else:
        norm = (d - dmin) / (dmax - dmin)
    return np.rint(norm * spec.qmax).clip(0, spec.qmax).astype(np.uint16, copy=False)


def _placeholders(recipe: Recipe) -> dict:
    """What ``add_frame`` gets for a pre-encoded video feature (it only checks shape and dtype;
    float32 depth tells lerobot the depth unit is metres, like the real frames)."""
    s = recipe.image_size
    out = {}
    for k in video_keys(recipe):
        depth = k.startswith("observation.depth.")
        arr = np.zeros((s, s, 1), np.float32) if depth else np.zeros((s, s, 3), np.uint8)
        arr.setflags(write=False)
        out[k] = arr
    return out


STATS_QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)  # lerobot's DEFAULT_QUANTILES (keys q01 ... q99)


def image_stats(frames: np.ndarray) -> dict:
    """Per-channel stats of a (T, H, W, C) stack in the layout lerobot's streaming encoder returns
    (raw units; lerobot divides RGB by 255 itself).  Exact over every pixel -- lerobot's own
    version is a 5000-bin histogram estimate with float32 sums and costs ~20x more CPU.
    ``count`` is the number of frames, as in lerobot's ``compute_episode_stats``."""
    c = frames.shape[-1]
    x = frames.reshape(-1, c)
    n = x.shape[0]
    if x.dtype == np.uint8:  # 256-bin histograms are exact: every statistic follows from them
        planes = np.ascontiguousarray(x.T)  # bincount of contiguous channels: ~3x faster
        hist = np.stack([np.bincount(planes[k], minlength=256) for k in range(c)]).astype(np.float64)
        v = np.arange(256.0)
        mean = hist @ v / n
        var = hist @ (v * v) / n - mean**2
        cdf = np.cumsum(hist, axis=1)

        def order_stat(i: int) -> np.ndarray:  # the i-th smallest value (0-based) per channel
            return np.array([np.searchsorted(cdf[k], i + 1) for k in range(c)], np.float64)

        quant = []
        for q in STATS_QUANTILES:  # numpy's default ("linear") quantile definition
            pos = q * (n - 1)
            lo = int(np.floor(pos))
            a, b = order_stat(lo), order_stat(min(lo + 1, n - 1))
            quant.append(a + (pos - lo) * (b - a))
        lo_v, hi_v = order_stat(0), order_stat(n - 1)
    else:
        xf = x.astype(np.float64)
        mean, var = xf.mean(axis=0), xf.var(axis=0)
        quant = list(np.quantile(x, STATS_QUANTILES, axis=0).astype(np.float64))
        lo_v, hi_v = x.min(axis=0).astype(np.float64), x.max(axis=0).astype(np.float64)
    stats = {"min": lo_v, "max": hi_v, "mean": mean, "std": np.sqrt(np.maximum(var, 0.0)),
             "count": np.array([frames.shape[0]])}  # fmt: skip
    for q, val in zip(STATS_QUANTILES, quant, strict=True):
        stats[f"q{round(q * 100):02d}"] = np.asarray(val, np.float64)
    return stats


def encode_stream(path: Path, frames: list[np.ndarray], spec: StreamSpec, fps: int) -> None:
    """One MP4 from HxWx3 uint8 RGB or HxWx1 float32 depth (metres) frames, encoded as lerobot's
    own encoders do (same codec options, pixel format, time base, depth quantiser)."""
    from fractions import Fraction

    import av

    h, w = frames[0].shape[:2]
    with av.open(str(path), "w") as container:
        stream = container.add_stream(spec.vcodec, fps, options=dict(spec.options))
        stream.pix_fmt, stream.width, stream.height = spec.pix_fmt, w, h
        stream.time_base = Fraction(1, fps)
        for i, img in enumerate(frames):
            if spec.depth:
                codes = quantize_depth(img, spec)
                vf = av.VideoFrame(w, h, spec.pix_fmt)
                plane = vf.planes[0]  # rows are padded to line_size bytes
                np.frombuffer(plane, np.uint16).reshape(h, plane.line_size // 2)[:, :w] = codes
            else:
                vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            vf.pts, vf.time_base = i, Fraction(1, fps)
            container.mux(stream.encode(vf))
        container.mux(stream.encode())


def encode_videos(result: EpisodeResult, recipe: Recipe, workdir: Path, specs: dict | None = None) -> None:
    """Encode ``result``'s camera streams into ``workdir`` and drop them from its frames:
    ``result.videos`` = {feature: (mp4 path, stats)}.  Each MP4 gets a folder of its own (lerobot
    deletes the folder once it has moved the file into the dataset).  ``specs``: from
    :func:`stream_specs` (computed here when not given)."""
    import tempfile

    keys = [k for k in video_keys(recipe) if result.frames and k in result.frames[0]]
    if not keys:
        return
    specs = specs if specs is not None else stream_specs(recipe)
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    videos = {}
    for k in keys:
        frames = [f.pop(k) for f in result.frames]
        d = Path(tempfile.mkdtemp(prefix=f"ep{result.episode_index:06d}_", dir=workdir))
        path = d / f"{k}.mp4"
        encode_stream(path, frames, specs[k], recipe.fps)
        videos[k] = (str(path), image_stats(np.stack(frames)))
        del frames
    result.videos = videos


class PreEncodedVideos:
    """Stands in for lerobot's ``StreamingVideoEncoder`` inside ``DatasetWriter``: ``save_episode``
    asks it for each video feature's (MP4 path, stats) -- here, the ones a worker already made.
    Frames fed through ``add_frame`` are ignored (they are placeholders)."""

    def __init__(self):
        self._next: dict | None = None

    def load(self, videos: dict) -> None:
        self._next = {k: (Path(p), st) for k, (p, st) in videos.items()}

    def start_episode(self, video_keys, temp_dir, depth_video_keys=None) -> None:
        if self._next is None:
            raise RuntimeError("no pre-encoded videos loaded for this episode")
        missing = set(video_keys) - set(self._next)
        if missing:
            raise RuntimeError(f"pre-encoded videos missing for {sorted(missing)}")

    def feed_frame(self, video_key, image) -> None:
        pass

    def finish_episode(self) -> dict:
        out, self._next = self._next, None
        if out is None:
            raise RuntimeError("no pre-encoded videos loaded for this episode")
        return out

    def cancel_episode(self) -> None:
        if self._next:
            for p, _ in self._next.values():
                shutil.rmtree(Path(p).parent, ignore_errors=True)
        self._next = None

    def close(self) -> None:
        self.cancel_episode()


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
        self.work = self.out / f".{recipe.name}.work"  # workers' encoded videos, not yet added
        self.ds = None
        self._videos: PreEncodedVideos | None = None
        self._pending: list[dict] = []
        self.camera_meta: dict | None = None  # meta/flatlab.json's cameras (computed at the first commit)
        # writer seconds (wall, and CPU of this process), for benchmarks
        self.timing = dict.fromkeys(("begin_s", "save_s", "commit_s", "begin_cpu_s", "save_cpu_s", "commit_cpu_s"), 0.0)

    def _clock(self, key: str, t0: float, c0: float) -> None:
        import time

        self.timing[f"{key}_s"] += time.perf_counter() - t0
        self.timing[f"{key}_cpu_s"] += time.process_time() - c0

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
        shutil.rmtree(self.work, ignore_errors=True)  # videos of episodes that were never committed
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
    def begin(self) -> None:
        import time

        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        t0, c0 = time.perf_counter(), time.process_time()
        if self.staging.exists():
            shutil.rmtree(self.staging)
        self._pending = []
        self._n_saved = sum(1 for r in self.records() if r.get("dataset_episode_index") is not None)
        rgb, depth = encoders(self.recipe)
        if self.root.exists():
            _link_or_copy_tree(self.root, self.staging)
            self.ds = LeRobotDataset.resume(
                self.recipe.repo_id, root=self.staging, video_backend="pyav", rgb_encoder=rgb, depth_encoder=depth
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
                rgb_encoder=rgb,
                depth_encoder=depth,
            )
        self._videos = None
        if video_keys(self.recipe):
            # lerobot's streaming-encoder hook (DatasetWriter._streaming_encoder, lerobot 0.6.x):
            # save_episode takes each video's MP4 + stats from it instead of encoding PNG frames.
            if not hasattr(self.ds.writer, "_streaming_encoder"):
                raise RuntimeError("this lerobot version has no streaming-encoder hook; flatlab collect needs 0.6.x")
            self._videos = self.ds.writer._streaming_encoder = PreEncodedVideos()
        self._clock("begin", t0, c0)

    def add(self, result: EpisodeResult) -> None:
        """Append one episode (frames in order).  Camera streams not yet encoded by a worker
        (:func:`encode_videos`) are encoded here."""
        import time

        rec = result.record()
        if result.frames:
            if self._videos is not None:
                if result.videos is None:
                    encode_videos(result, self.recipe, self.work)
                self._videos.load(result.videos)
            t0, c0 = time.perf_counter(), time.process_time()
            ph = _placeholders(self.recipe)
            for f in result.frames:
                self.ds.add_frame({**f, **ph} if ph else f)
            _no_hf_progress_bars()  # lerobot re-enables them after each metadata write
            self.ds.save_episode(parallel_encoding=False)
            self._clock("save", t0, c0)
            rec["dataset_episode_index"] = self._n_saved
            self._n_saved += 1
        else:
            rec["dataset_episode_index"] = None
        self._pending.append(rec)

    def commit(self) -> None:
        import time

        t0, c0 = time.perf_counter(), time.process_time()
        self.ds.finalize()
        self.ds = None
        records = self.records() + self._pending
        if self.camera_meta is None:
            self.camera_meta = camera_meta(self.recipe)
        meta = {
            "format_version": FORMAT_VERSION,
            "generator": "flatlab collect",
            "recipe": self.recipe.to_dict(),
            "recipe_source": portable_name(self.recipe.source),
            "recipe_fingerprint": self.recipe.fingerprint(),
            "cameras": self.camera_meta,
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
        self._clock("commit", t0, c0)

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
CARD_TAGS = ("LeRobot", "FlatLab", "mujoco", "bimanual", "grasping")
CARD_MAX_EPISODE_ROWS = 200  # the card's episode table; every record is in meta/flatlab_episodes.jsonl


def _md_table(header: list[str], rows: list[list]) -> str:
    def cell(v) -> str:
        return str(v).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def _rate(ok: int, n: int) -> str:
    return f"{100 * ok / n:.1f}%" if n else "n/a"


def _size_category(n: int) -> str:
    """The hub's ``size_categories`` value for ``n`` rows (frames)."""
    bounds = ["", "1K", "10K", "100K", "1M", "10M", "100M", "1B", "10B", "100B", "1T"]
    for i in range(1, len(bounds)):
        if n < 10 ** (i + 2):
            return f"n<{bounds[i]}" if i == 1 else f"{bounds[i - 1]}<n<{bounds[i]}"
    return "n>1T"


_CATALOG: list[dict] = []  # the catalog, loaded once per process (~0.3 s; the card is rendered at every commit)


def _catalog_rows(object_ids: list[str]) -> dict[str, dict]:
    """name / category / split / material / label of each object from the current catalog ('?' when gone)."""
    from flatlab_lerobot.catalog import load_objects

    if not _CATALOG:
        try:
            _CATALOG.append(load_objects())
        except Exception:  # noqa: BLE001 -- the card must still render from the dataset's own files
            _CATALOG.append({})
    cat = _CATALOG[0]
    out = {}
    for oid in object_ids:
        o = cat.get(oid)
        out[oid] = (
            {"name": o.name or oid, "category": o.category, "split": o.split, "material": o.material,
             "label": o.strategy}
            if o is not None
            else dict.fromkeys(("name", "category", "split", "material", "label"), "?")
        )  # fmt: skip
    return out


def _group_table(key_rows: list[tuple[str, dict]], records: list[dict], what: str) -> str:
    """``what`` | objects | episodes | successful | rate, one row per distinct key."""
    groups: dict[str, dict] = {}
    for oid, key in key_rows:
        groups.setdefault(key, {"objects": set(), "n": 0, "ok": 0})["objects"].add(oid)
    obj_key = dict(key_rows)
    for r in records:
        g = groups[obj_key[r["object_id"]]] if r["object_id"] in obj_key else None
        if g is not None:
            g["n"] += 1
            g["ok"] += bool(r["success"])
    return _md_table(
        [what, "objects", "episodes", "successful", "success rate"],
        [[k, len(g["objects"]), g["n"], g["ok"], _rate(g["ok"], g["n"])] for k, g in sorted(groups.items())],
    )


def _train_command(recipe: Recipe, repo_id: str, feats: dict) -> str:
    """``lerobot-train`` for act on state + RGB (depth and clouds are not inputs act/diffusion accept)."""
    inputs = {"observation.state": {"type": "STATE", "shape": list(feats["observation.state"]["shape"])}}
    for k, v in feats.items():
        if k.startswith("observation.images.") and v["dtype"] in ("video", "image"):
            h, w, c = v["shape"]
            inputs[k] = {"type": "VISUAL", "shape": [c, h, w]}
    if len(inputs) == 1 and "observation.environment_state" in feats:  # act needs an image or the env state
        inputs["observation.environment_state"] = {
            "type": "ENV", "shape": list(feats["observation.environment_state"]["shape"]),
        }  # fmt: skip
    return " \\\n  ".join(
        [
            "lerobot-train --policy.type=act",
            f"--dataset.repo_id={repo_id} --dataset.video_backend=pyav",
            f"--policy.input_features='{json.dumps(inputs, separators=(',', ':'))}'",
            f"--policy.push_to_hub=false --output_dir=outputs/train/{recipe.name}_act --steps=100000 --batch_size=8",
        ]
    )


def render_card(
    recipe: Recipe,
    meta: dict,
    records: list[dict],
    *,
    repo_id: str | None = None,
    tags: list[str] | tuple[str, ...] = (),
    license: str = "apache-2.0",
    info: dict | None = None,
) -> str:
    """The dataset card (``README.md``): hub YAML header, objects with category / split / strategy,
    splits, strategies, failure-reason histogram, features, cameras, how to load and train, episode
    table, recipe.  ``info`` is ``meta/info.json`` (its features and frame count win when given);
    ``repo_id`` / ``tags`` / ``license`` are the hub target's (``flatlab push``)."""
    from huggingface_hub import DatasetCardData

    p = CARD_TEMPLATE
    template = p.read_text()
    repo_id = repo_id or recipe.repo_id
    saved = [r for r in records if r.get("dataset_episode_index") is not None]
    n_att, n_saved = len(records), len(saved)
    n_ok = sum(1 for r in records if r["success"])
    n_ok_saved = sum(1 for r in saved if r["success"])
    total_frames = int(info["total_frames"]) if info else sum(int(r["num_frames"]) for r in saved)
    feats = info["features"] if info else build_features(recipe)

    # objects: catalog facts + what this dataset holds for each
    object_ids = list(dict.fromkeys([*recipe.objects, *(r["object_id"] for r in records)]))
    cat = _catalog_rows(object_ids)
    obj_rows = []
    for oid in object_ids:
        rs = [r for r in records if r["object_id"] == oid]
        used = ", ".join(sorted({r["strategy"] for r in rs})) or "-"
        ok = sum(1 for r in rs if r["success"])
        c = cat[oid]
        obj_rows.append([f"`{oid}`", c["name"], c["category"], c["split"], c["material"], c["label"], used,
                         len(rs), ok, _rate(ok, len(rs))])  # fmt: skip
    object_table = _md_table(
        ["object", "name", "category", "split", "material", "label", "strategy used", "episodes", "successful",
         "success rate"], obj_rows,
    )  # fmt: skip
    split_table = _group_table([(o, cat[o]["split"]) for o in object_ids], records, "split")
    strat_groups: dict[str, list[int]] = {}
    for r in records:
        g = strat_groups.setdefault(r["strategy"], [0, 0])
        g[0] += 1
        g[1] += bool(r["success"])
    strategy_table = _md_table(
        ["strategy", "episodes", "successful", "success rate"],
        [[s, n, ok, _rate(ok, n)] for s, (n, ok) in sorted(strat_groups.items())],
    )
    reasons: dict[str, int] = {}
    for r in records:
        if not r["success"]:
            key = r.get("failure_reason") or "(no reason recorded)"
            reasons[key] = reasons.get(key, 0) + 1
    failure_table = (
        _md_table(["failure reason", "episodes", "share of attempted"],
                  [[k, n, _rate(n, n_att)] for k, n in sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0]))])
        if reasons else "No failed episode."
    )  # fmt: skip

    ep_rows = [
        ["-" if r["dataset_episode_index"] is None else r["dataset_episode_index"], r["seed"], r["object_id"],
         r["strategy"], r["num_frames"], r["success"], r.get("failure_reason") or ""]
        for r in records[:CARD_MAX_EPISODE_ROWS]
    ]  # fmt: skip
    episode_table = _md_table(["#", "seed", "object", "strategy", "frames", "success", "failure reason"], ep_rows)
    if n_att > CARD_MAX_EPISODE_ROWS:
        episode_table += f"\n\n({n_att - CARD_MAX_EPISODE_ROWS} more in `meta/flatlab_episodes.jsonl`.)"
    feature_table = _md_table(
        ["key", "dtype", "shape"], [[f"`{k}`", v["dtype"], tuple(v["shape"])] for k, v in feats.items()]
    )
    cams = meta.get("cameras") or {}
    camera_table = (
        _md_table(["camera", "width x height", "fx", "fy", "cx", "cy"],
                  [[f"`{c}`", f"{m['width']} x {m['height']}", f"{m['fx']:.2f}", f"{m['fy']:.2f}", f"{m['cx']:.2f}",
                    f"{m['cy']:.2f}"] for c, m in cams.items()])
        if cams else "No camera."
    )  # fmt: skip
    splits = sorted({cat[o]["split"] for o in object_ids})
    has_depth = any(k.startswith("observation.depth.") for k in feats)
    train_note = (
        "The command feeds act the joint state and the RGB cameras only: depth maps are 1-channel images "
        "and point clouds are (N, 3) arrays, which act's and diffusion's image encoders do not take. "
        "Add `--policy.pretrained_backbone_weights=null` on a machine that cannot reach download.pytorch.org."
    )
    if has_depth:
        train_note += " Depth decodes in mm by default (`--dataset.depth_output_unit=m` for metres)."
    dataset_structure = (
        "[meta/info.json](meta/info.json):\n\n<details><summary>meta/info.json</summary>\n\n```json\n"
        + json.dumps(info, indent=2) + "\n```\n\n</details>"
        if info else "See `meta/info.json` (LeRobotDataset v3: `data/`, `videos/`, `meta/`)."
    )  # fmt: skip
    card_data = DatasetCardData(
        license=license,
        task_categories=["robotics"],
        size_categories=[_size_category(total_frames)],
        pretty_name=recipe.name,
        tags=list(dict.fromkeys([*CARD_TAGS, *tags])),
        configs=[{"config_name": "default", "data_files": "data/*/*.parquet"}],
    ).to_yaml()
    duration = total_frames / recipe.fps
    values = {
        "card_data": card_data,
        "name": recipe.name,
        "repo_id": repo_id,
        "codebase_version": (info or {}).get("codebase_version", "v3.0"),
        "description": recipe.description or "Scripted-expert demonstrations of grasping flat objects.",
        "recipe_source": portable_name(meta.get("recipe_source", recipe.source)),
        "package_version": _package_version(),
        "camera_note": _camera_note(feats, bool(cams)),
        "fingerprint": meta.get("recipe_fingerprint", recipe.fingerprint()),
        "fps": recipe.fps,
        "robot_type": recipe.robot_type,
        "cameras": ", ".join(recipe.cameras) or "none",
        "image_size": recipe.image_size,
        "modalities": ", ".join(recipe.modalities) or "state and action only",
        "objects": ", ".join(object_ids),
        "num_objects": len(object_ids),
        "splits": ", ".join(splits),
        "strategy": "per object (catalog label)" if recipe.strategy == "auto" else recipe.strategy,
        "seed": recipe.seed,
        "randomization": _randomization_text(recipe),
        "episodes_attempted": n_att,
        "episodes_saved": n_saved,
        "episodes_successful": n_ok,
        "success_rate": f"{_rate(n_ok, n_att)} ({n_ok} / {n_att})",
        "total_frames": total_frames,
        "duration": f"{duration / 60:.1f} min" if duration >= 60 else f"{duration:.1f} s",
        "object_table": object_table,
        "split_table": split_table,
        "strategy_table": strategy_table,
        "failure_table": failure_table,
        "successful_note": f"{n_ok_saved} of the {n_saved} saved episodes are successful; add "
        "`--dataset.episodes='[...]'` with the `ok` list above to train on those only",
        "train_command": _train_command(recipe, repo_id, feats),
        "train_note": train_note,
        "feature_table": feature_table,
        "camera_table": camera_table,
        "episode_table": episode_table,
        "recipe_yaml": _yaml(recipe.to_dict()),
        "dataset_structure": dataset_structure,
    }
    try:
        return template.format(**values)
    except (KeyError, IndexError, ValueError) as exc:
        raise RecipeError(f"{p}: bad placeholder in the card template: {exc}") from exc


def _camera_note(feats: dict, has_cameras: bool) -> str:
    """What the camera metadata lets one rebuild, naming only the modalities this dataset has."""
    if not has_cameras:
        return "This dataset has no camera."
    note = ("Intrinsics (`fx, fy, cx, cy`, `K`) and extrinsics (`cam_to_world`, 4x4) of every camera are in "
            "`meta/flatlab.json`")  # fmt: skip
    depth = sorted(k for k in feats if k.startswith("observation.depth."))
    if depth:
        note += (f", so point clouds can be rebuilt from {', '.join(f'`{k}`' for k in depth)} "
                 "(see `flatlab_lerobot.collect.writer.depth_to_points`)")  # fmt: skip
    note += "."
    clouds = [k for k in ("observation.pointcloud", "observation.object_pointcloud") if k in feats]
    if clouds:
        note += f" Point clouds are stored per frame in {' and '.join(f'`{k}`' for k in clouds)} (world frame)."
    return note


def _package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("lerobot_env_flatlab")
    except PackageNotFoundError:
        return "unknown"


def _randomization_text(recipe: Recipe) -> str:
    """The recipe's randomization ranges in words (the card's table row)."""
    r = recipe.randomization
    parts = [f"object ±{r.xy_range * 100:g} cm, yaw ±{r.yaw_range_deg:g}°"]
    if r.joint_noise:
        parts.append(f"arm joints ±{r.joint_noise:g} rad")
    if r.camera_pos_jitter or r.camera_rot_jitter_deg:
        parts.append(f"cameras ±{r.camera_pos_jitter * 100:g} cm, ±{r.camera_rot_jitter_deg:g}°")
    for name, (lo, hi) in (("mass", r.mass_scale), ("friction", r.friction_scale)):
        if (lo, hi) != (1.0, 1.0):
            parts.append(f"{name} x [{lo:g}, {hi:g}]")
    return "; ".join(parts) + " (per episode: `domain` in `meta/flatlab_episodes.jsonl`)"


def _yaml(d: dict) -> str:
    import yaml

    return yaml.safe_dump(d, sort_keys=False)

"""The dataset store: LeRobotDataset v3 with crash-safe, resumable commits.

The writer is split by concern: :mod:`.features` (keys, shapes, names, camera metadata),
:mod:`.video` (camera streams encoded by the process that simulated the episode, lerobot's codec
settings, no PNG round trip), :mod:`.card` (the dataset card) and this store: :class:`DatasetStore`
adds each episode through lerobot's ``add_frame`` / ``save_episode``, handing it the finished MP4s
(:class:`~flatlab_lerobot.collect.video.PreEncodedVideos`).

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
import os
import shutil
from pathlib import Path


from flatlab_lerobot.collect.recipe import Recipe
from flatlab_lerobot.collect.runner import EpisodeResult
from flatlab_lerobot.paths import portable_name
from flatlab_lerobot.collect.card import render_card
from flatlab_lerobot.collect.features import CAMERA_CONVENTION, build_features, camera_meta
from flatlab_lerobot.collect.video import PreEncodedVideos, encode_videos, encoders, placeholder_frames, video_keys


READY = ".flatlab_ready"
META_JSON = "meta/flatlab.json"
EPISODES_JSONL = "meta/flatlab_episodes.jsonl"
FORMAT_VERSION = 1
# Files lerobot writes once and never touches again after a resume: hard-linked into staging.
_IMMUTABLE_DIRS = ("data", "videos", "meta/episodes")


class DatasetMismatch(RuntimeError):
    """The folder holds a dataset made from another recipe (or not by FlatLab)."""


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
            ph = placeholder_frames(self.recipe)
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



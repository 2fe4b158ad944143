"""Camera streams -> MP4s, encoded where the episode was simulated, and handed to lerobot as finished files."""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from flatlab_lerobot.collect.recipe import Recipe
from flatlab_lerobot.collect.runner import EpisodeResult

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


def placeholder_frames(recipe: Recipe) -> dict:
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



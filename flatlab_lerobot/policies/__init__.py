"""LeRobot policy types shipped with FlatLab (registered on import of :mod:`flatlab_lerobot.lerobot_plugin`)."""

import numpy as np
from lerobot.configs import NormalizationMode


def identity_normalization() -> dict[str, NormalizationMode]:
    """``normalization_mapping`` of policies that normalize inside the model (or need raw values):
    lerobot's processors pass every feature type through unchanged."""
    return {t: NormalizationMode.IDENTITY for t in ("VISUAL", "STATE", "ENV", "ACTION")}


def seen_points(cloud: np.ndarray) -> np.ndarray:
    """The seen rows (M, 3) of an env cloud (K, 3), as float64: all-zero rows are unseen (the env's padding when
    the cameras see nothing)."""
    pts = np.asarray(cloud, float).reshape(-1, 3)
    return pts[np.abs(pts).sum(1) > 0]


def distinct_indices(points: np.ndarray) -> np.ndarray:
    """Indices of the distinct rows of ``points`` (K, 3), each at its first occurrence, in cloud order.  The
    env repeats its points up to a fixed count when the cameras see fewer (``sim.cameras.sample``)."""
    pts = np.asarray(points)
    if not len(pts):
        return np.zeros(0, np.int64)
    _, first = np.unique(pts.reshape(len(pts), -1), axis=0, return_index=True)
    return np.sort(first).astype(np.int64)


def fps_indices(points: np.ndarray, n: int) -> np.ndarray:
    """Indices of ``n`` of ``points`` (K, 3): farthest-point sampling of the distinct points from the first
    when there are more than ``n`` (so the same cloud always gives the same points), else every distinct point
    once, cycled to ``n``.  A repeated point counts once: FPS of a cloud that repeats its points would take
    every distinct point and then fill up with copies of one of them."""
    import fpsample

    idx = distinct_indices(points)
    k = len(idx)
    if k > n:
        h = int(np.clip(np.log2(k) - 8, 3, 9))  # KD-tree height: buckets of 2**h points
        pts = np.ascontiguousarray(np.asarray(points)[idx], np.float64)
        return idx[np.asarray(fpsample.bucket_fps_kdline_sampling(pts, n, h=h, start_idx=0), np.int64)]
    return np.resize(idx, n)

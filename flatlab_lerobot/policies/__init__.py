"""LeRobot policy types shipped with FlatLab (registered on import of :mod:`flatlab_lerobot.lerobot_plugin`)."""

import numpy as np
from lerobot.configs import NormalizationMode


def identity_normalization() -> dict[str, NormalizationMode]:
    """``normalization_mapping`` of policies that normalize inside the model (or need raw values):
    lerobot's processors pass every feature type through unchanged."""
    return {t: NormalizationMode.IDENTITY for t in ("VISUAL", "STATE", "ENV", "ACTION")}


def fps_indices(points: np.ndarray, n: int) -> np.ndarray:
    """Indices of ``n`` of ``points`` (K, 3): farthest-point sampling from point 0 when K > n (so the
    same cloud always gives the same points), every point once plus repeats of the first when K <= n."""
    import fpsample

    k = len(points)
    if k > n:
        h = int(np.clip(np.log2(k) - 8, 3, 9))  # KD-tree height: buckets of 2**h points
        return np.asarray(fpsample.bucket_fps_kdline_sampling(points, n, h=h, start_idx=0), np.int64)
    return np.resize(np.arange(k), n)

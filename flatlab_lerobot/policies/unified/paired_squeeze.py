"""``--policy.pair_squeeze=true``: strategy B's two hands face each other across the object.

The expert puts B's hands at ``c +- h u`` (``strategies/b_squeeze.py``): on one line along the object's
horizontal axis ``u`` closest to world y, so the squeeze pushes through the object and the lift holds it
between two opposite contacts.  The executor predicts each arm's pose from one shared feature but nothing
ties them together; in closed loop its hands ended B's squeeze up to 2.4 cm apart across that axis
(``box_shoe``, seed 1000, the cosine executor: the box lifted tilted and slipped out; docs/unified.md).

The rule, for every B stage that commands both arms, for the start and the end pose: ``u`` is the axis of
the observed object cloud's minimum-area rectangle closest to world y (the expert's rule, on what the
cameras see); each hand keeps its learned height and its learned position along ``u``, and both take the
learned midpoint's position across ``u``.  Everything else (orientations, widths, timing) stays learned.
Not in the paper: a measured answer to "how much of B's loss is the two hands' disagreement".
"""

from __future__ import annotations

import numpy as np

MIN_POINTS = 10  # fewer seen object points: keep the learned poses


def observed_squeeze_axis(points: np.ndarray) -> np.ndarray | None:
    """Unit (2,) axis of the seen object points' minimum-area rectangle closest to world y, pointing to
    +y; None when fewer than ``MIN_POINTS`` are seen or they span no area."""
    import trimesh

    xy = np.asarray(points, float).reshape(-1, 3)[:, :2]
    if len(xy) < MIN_POINTS:
        return None
    try:
        T, _ = trimesh.bounds.oriented_bounds_2D(xy)
    except Exception:  # degenerate (collinear) clouds: qhull fails
        return None
    axes = np.asarray(T[:2, :2], float)  # rows: the rectangle's axes in world xy
    u = axes[int(np.argmax(np.abs(axes[:, 1])))]
    u = u / np.linalg.norm(u)
    return u if u[1] >= 0 else -u


def pair(p_left: np.ndarray, p_right: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both positions moved across ``u`` (horizontally) onto the line along ``u`` through their midpoint;
    their components along ``u`` and their heights unchanged."""
    n = np.array([-u[1], u[0]])  # across the axis
    mid = (np.asarray(p_left, float)[:2] + np.asarray(p_right, float)[:2]) / 2
    out = []
    for p in (p_left, p_right):
        p = np.asarray(p, float).copy()
        p[:2] -= float((p[:2] - mid) @ n) * n
        out.append(p)
    return out[0], out[1]

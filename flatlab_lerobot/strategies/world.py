"""What every strategy shares: the expert's view of the scene (:class:`World`, parsed from the
privileged state), small pose helpers, and the final ``hold`` stage.

A *stage* is a function ``stage(expert, world, poses, grip, ctx) -> Primitive`` evaluated when the
stage starts, on the state at that moment (``poses``: each arm's TCP pose, ``grip``: gripper widths,
``ctx``: choices that hold for the whole episode).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flatlab_lerobot.primitives import ArmMotion, Primitive
from flatlab_lerobot.sim.core import ENV_STATE_INDEX
from flatlab_lerobot.sim.robot import ARMS

DOWN = np.array([0.0, 0.0, -1.0])
FINGER_TIP_BELOW_TCP = 0.007  # finger tips sit this far beyond the TCP along the approach (m)
FINGER_HALF_WIDTH = 0.01  # half thickness of a finger along the hand x axis (m)


@dataclass(frozen=True)
class StageSpec:
    """What a stage poses besides its poses: the ``primitive``'s name, ``transit`` s for the
    joint-space move to its start pose and ``duration`` s for the Cartesian motion.  With ``speed``
    (m/s), a motion whose length varies takes ``max(duration, length / speed)``, its length measured
    ``along`` "xy" (horizontal) or "z" (rise).  One table per strategy (``SPECS`` beside its
    ``STAGES``) serves the stage functions and the learned policy that executes predicted poses
    under the expert's names and timing.  ``start``: "world" -- the stage's commanded arms start at a
    pose the stage computes from the scene (an approach); "current" -- they start where they are (the
    previous stage's commanded pose: press, slide, squeeze, grasp, lift, ...), so the stage is a motion
    relative to the hand (a test checks this against the stage functions)."""

    primitive: str
    duration: float
    transit: float = 1.0
    speed: float | None = None
    along: str = "xy"
    start: str = "world"

    def seconds(self, length: float = 0.0) -> float:
        """The Cartesian motion's duration for a motion ``length`` m long (s)."""
        return self.duration if self.speed is None else max(self.duration, length / self.speed)

    def for_motion(self, start_pos, end_pos) -> float:
        """:meth:`seconds` of the straight motion ``start_pos`` -> ``end_pos``."""
        d = np.asarray(end_pos, float) - np.asarray(start_pos, float)
        length = float(d[2]) if self.along == "z" else float(np.linalg.norm(d[:2]))
        return self.seconds(length)

    def make(self, motions: dict, length: float = 0.0) -> Primitive:
        """This stage's primitive of ``motions`` (arm -> :class:`ArmMotion`), ``length`` m long."""
        return Primitive(self.primitive, motions, self.seconds(length), transit=self.transit)

@dataclass
class World:
    """The expert's view of the scene, parsed from ``environment_state``."""

    pos: np.ndarray
    yaw: float
    size: np.ndarray
    deformable: bool
    table_height: float
    edge_x: float

    @classmethod
    def from_vector(cls, v) -> "World":
        """From the privileged state (:data:`~flatlab_lerobot.sim.core.ENV_STATE_NAMES`)."""
        v = np.asarray(v, dtype=float)
        i = ENV_STATE_INDEX
        return cls(
            v[[i["obj_x"], i["obj_y"], i["obj_z"]]], float(2 * np.arctan2(v[i["obj_qz"]], v[i["obj_qw"]])),
            v[[i["obj_size_x"], i["obj_size_y"], i["obj_size_z"]]], bool(v[i["deformable"]] > 0.5),
            float(v[i["table_height"]]), float(v[i["table_edge_x"]]),
        )  # fmt: skip

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([c, s, 0.0]), np.array([-s, c, 0.0])

    @property
    def round(self) -> bool:
        """A rigid object with a square footprint (disks, plates, round clocks -- or a square): its
        yaw says nothing useful, so footprint queries treat it as a disk of that diameter."""
        return not self.deformable and abs(self.size[0] - self.size[1]) < 1e-4

    def max_x(self) -> float:
        """Largest x of the footprint (m)."""
        if self.round:
            return float(self.pos[0] + self.size[0] / 2)
        return float(self.corners_xy()[:, 0].max())

    def length_x(self) -> float:
        """Extent of the footprint along world x (m)."""
        if self.round:
            return float(self.size[0])
        c = self.corners_xy()[:, 0]
        return float(c.max() - c.min())

    def front_at(self, y: float) -> float:
        """x where the footprint's front (+x) boundary crosses the line at ``y``."""
        if self.round:
            r = self.size[0] / 2
            return float(self.pos[0] + np.sqrt(max(r * r - (y - self.pos[1]) ** 2, 0.0)))
        hits = _polygon_hits(self.corners_xy(), 1, y)
        return max(hits) if hits else self.max_x()

    def corners_xy(self) -> np.ndarray:
        ex, ey = self.axes()
        hx, hy = self.size[0] / 2, self.size[1] / 2
        return np.array([self.pos + sx * hx * ex + sy * hy * ey for sx in (-1, 1) for sy in (-1, 1)])[:, :2]

    def squeeze_axis(self) -> tuple[np.ndarray, float]:
        """The object's horizontal axis closest to world y (pointing to +y), and the half extent along it."""
        ex, ey = self.axes()
        if abs(ex[1]) > abs(ey[1]):
            u, half = ex, self.size[0] / 2
        else:
            u, half = ey, self.size[1] / 2
        return (u if u[1] >= 0 else -u), float(half)


def vec(*xyz) -> np.ndarray:
    """A float vector of the given components."""
    return np.array(xyz, dtype=float)


def shifted(pose, dp):
    """``pose`` (position, rotation) moved by ``dp`` (m), same rotation."""
    return (pose[0] + np.asarray(dp, float), pose[1])


def _polygon_hits(corners: np.ndarray, axis: int, value: float) -> list[float]:
    """Other coordinate of the points where the footprint polygon crosses ``coord[axis] = value``."""
    order = [0, 1, 3, 2]
    hits = []
    for i in range(4):
        a, b = corners[order[i]], corners[order[(i + 1) % 4]]
        if (a[axis] - value) * (b[axis] - value) <= 0 and abs(b[axis] - a[axis]) > 1e-9:
            t = (value - a[axis]) / (b[axis] - a[axis])
            hits.append(a[1 - axis] + t * (b[1 - axis] - a[1 - axis]))
    return hits


def hold_all(poses, grip, duration: float) -> Primitive:
    """Both arms hold their pose and gripper for ``duration`` seconds."""
    return Primitive("hold", {a: ArmMotion.still(poses[a], grip[a]) for a in ARMS}, duration)


HOLD = StageSpec("hold", 2.6, start="current")  # the final hold of every strategy


def hold(ex, w: World, poses, grip, ctx) -> Primitive:
    return hold_all(poses, grip, HOLD.seconds())


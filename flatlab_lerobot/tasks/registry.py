"""Task registry: the sub-skills of flat-object grasping as separately judged tasks.

MuJoCo-Playground style: one explicit dict, :data:`TASKS`, maps a task id to a :class:`TaskSpec`
holding a description, a success predicate ``success(sim, ctx) -> bool`` (called once after
every control step; the episode succeeds the first time it returns True), a reset
distribution (planar offset and yaw of the object), an episode length (control steps) and the
expert strategy + stages that complete it (what the tests and the scripted baseline run).

Every predicate reads only the simulation (:class:`~flatlab_lerobot.sim.core.FlatLabSim`) and
the episode context (:class:`TaskContext`: the object's start pose and the task target), and
every one can fail (see ``tests/test_tasks.py``).

A task episode runs in the env (``FlatLabEnv(task=...)``) through the one episode loop,
:func:`flatlab_lerobot.rollout.run_task_episode`; its record's ``metrics()`` are the per-episode
metrics (success, time/steps to completion, TCP jerk (:func:`mean_squared_jerk`), primitives executed).
:data:`SCENARIOS` chains several objects in ONE cell (``clear_desk``: a cluttered desk of five
Test-beta objects cleared one after another, :mod:`flatlab_lerobot.tasks.clear_desk`); :func:`run_scenario`
runs one with the scripted expert and returns its metrics.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import mujoco
import numpy as np

from flatlab_lerobot.tasks.clear_desk import (
    CARRY_SQUEEZE,
    DeskConfig,
    DeskLayout,
    desk_cleared,
    run_desk_episode,
    sample_desk,
)
from flatlab_lerobot.sim.core import HOLD_TIME, LIFT_HEIGHT, FlatLabSim
from flatlab_lerobot.sim.robot import ARMS

# thresholds (SI units) ------------------------------------------------------------------------
PRESS_FORCE = 5.0  # N: downward normal force of one arm's fingers on the object
PRESS_NORMAL_Z = 0.7  # a contact counts as pressing when its normal points this much downward
PINCH_COS = -0.5  # both fingers touch, with mean contact normals at least this opposed
OVERHANG = 0.03  # m: the object's farthest point beyond the usable edge (slide_to_edge)
SLIDE_OFFSET = 0.10  # m: slide target = start + this along +x (towards the usable edge)
SLIDE_POS_TOL = 0.05  # m
SLIDE_YAW_TOL = np.radians(30.0)
RIDGE_HEIGHT = 0.03  # m: cloth fold height above the table (squeeze_edge)
ON_TABLE_CLEARANCE = 0.01  # m: "still on the table": lowest point at most this high + table contact


# ------------------------------------------------------------------------------- specs
DEFAULT_PLANAR = 0.05  # m: the benchmark's reset distribution, planar offset of the object in x and y ...
DEFAULT_YAW_DEG = 30.0  # ... and its yaw (degrees), both uniform in +-


@dataclass(frozen=True)
class ResetDistribution:
    """Object placement at reset: uniform planar offset in ±``planar`` m (x and y) and yaw in
    ±``yaw_deg`` degrees.  The env samples it (:meth:`sample` on its seeded ``np_random``), so
    ``sample(seed)`` is the placement of ``env.reset(seed=seed)``.

    ``scenes``: optional scene ids (``envs/scenes``) an episode's cell is drawn from, uniformly, by
    :meth:`scene` (its own random stream, so the placement of a seed does not change); empty (the
    default) = the plain default cell."""

    planar: float = DEFAULT_PLANAR
    yaw_deg: float = DEFAULT_YAW_DEG
    scenes: tuple[str, ...] = ()

    def scene(self, seed: int) -> str | None:
        """The scene of episode ``seed`` (None: the default cell)."""
        if not self.scenes:
            return None
        return self.scenes[int(np.random.default_rng([seed, 7]).integers(len(self.scenes)))]

    def sample(self, rng: np.random.Generator | int) -> tuple[float, float, float]:
        """(x, y, yaw in rad) drawn from ``rng`` (a Generator, or a seed for ``default_rng``)."""
        if not isinstance(rng, np.random.Generator):
            rng = np.random.default_rng(rng)
        x, y = rng.uniform(-self.planar, self.planar, size=2)
        yaw_range = np.deg2rad(float(self.yaw_deg))
        return float(x), float(y), float(rng.uniform(-yaw_range, yaw_range))


@dataclass
class TaskContext:
    """Per-episode state a predicate may read: start pose of the object and the task target."""

    start_pos: np.ndarray
    start_yaw: float
    target_pos: np.ndarray | None = None
    target_yaw: float | None = None
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class TaskSpec:
    id: str
    description: str
    success: Callable[[FlatLabSim, TaskContext], bool]
    expert_strategy: str  # the strategy whose stages complete the task
    expert_stages: tuple[str, ...]  # primitive names of that strategy during which it completes
    reference_object: str  # the object the tests run it on
    episode_length: int  # control steps (10 Hz)
    reset: ResetDistribution = ResetDistribution()
    material: str = "any"  # rigid | deformable | any: the objects it is defined for
    make_target: Callable[[FlatLabSim, TaskContext], None] | None = None


# ------------------------------------------------------------------------------- measurements
def _yaw(quat) -> float:
    return float(2 * np.arctan2(quat[3], quat[0]))


def finger_contacts(sim: FlatLabSim, arm: str) -> list[tuple[str, np.ndarray, float]]:
    """Contacts between ``arm``'s fingers and the object: (finger body name, unit normal
    pointing from the finger into the object (world), normal force (N, >= 0))."""
    m, d = sim.model, sim.data
    fingers = {int(g) for g in sim.finger_geoms[arm]}
    out = []
    f6 = np.zeros(6)
    for i in range(d.ncon):
        c = d.contact[i]
        g1, g2 = int(c.geom[0]), int(c.geom[1])
        obj = sim.is_object(np.array([g1, g2]), np.array([c.flex[0], c.flex[1]]))
        if g1 in fingers and obj[1]:
            finger, sign = g1, 1.0  # frame normal points from geom1 (finger) to geom2 (object)
        elif g2 in fingers and obj[0]:
            finger, sign = g2, -1.0
        else:
            continue
        mujoco.mj_contactForce(m, d, i, f6)
        n = sign * c.frame[:3].copy()
        out.append((m.body(m.geom_bodyid[finger]).name, n, float(f6[0])))
    return out


def touches(sim: FlatLabSim, arm: str) -> bool:
    return sim.object_contacts(sim.finger_geoms[arm])


def press_force(sim: FlatLabSim, arm: str) -> float:
    """Downward normal force (N) that ``arm``'s fingers apply to the object through contacts
    whose normal points down into it (sideways squeezing does not count)."""
    return float(sum(f * -n[2] for _, n, f in finger_contacts(sim, arm) if n[2] <= -PRESS_NORMAL_Z))


def pinches(sim: FlatLabSim, arm: str) -> bool:
    """Both fingers of ``arm`` touch the object, on opposite faces (mean normals opposed)."""
    per_finger: dict[str, list[np.ndarray]] = {}
    for name, n, _ in finger_contacts(sim, arm):
        per_finger.setdefault(name, []).append(n)
    if len(per_finger) < 2:
        return False
    a, b = (np.mean(v, axis=0) for v in list(per_finger.values())[:2])
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    return bool(na > 0 and nb > 0 and a @ b / (na * nb) <= PINCH_COS)


def overhang(sim: FlatLabSim) -> float:
    """How far the object's farthest point lies beyond the usable edge (m; negative: inside)."""
    return float(sim.object_points()[:, 0].max() - sim.cell.edge_x)


def on_table(sim: FlatLabSim) -> bool:
    clearance = float(sim.object_points()[:, 2].min() - sim.cell.table_height)
    return clearance <= ON_TABLE_CLEARANCE and sim.object_contacts(np.array([sim.table_geom]))


def ridge_height(sim: FlatLabSim) -> float:
    """Highest object point above the table (m): for a cloth lying on the table, its fold height."""
    return float(sim.object_points()[:, 2].max() - sim.cell.table_height)


def _held_by(sim: FlatLabSim, n_arms: int) -> bool:
    """The core success rule (>= LIFT_HEIGHT, no table contact, slip < 1 cm, HOLD_TIME s) with
    exactly ``n_arms`` holding arms.  The sim restarts its hold timer whenever the set of
    holding arms changes, so the count held for the whole hold."""
    return sim.is_success() and len(sim.holding_arms()) == n_arms


# ------------------------------------------------------------------------------- predicates
def _touch(sim, ctx):
    return any(touches(sim, a) for a in ARMS)


def _touch_dual(sim, ctx):
    return all(touches(sim, a) for a in ARMS)


def _slide_target(sim, ctx):
    ctx.target_pos = ctx.start_pos[:2] + np.array([SLIDE_OFFSET, 0.0])
    ctx.target_yaw = ctx.start_yaw


def _slide(sim, ctx):
    pos, quat = sim.object_pose()
    dyaw = (_yaw(quat) - ctx.target_yaw + np.pi) % (2 * np.pi) - np.pi
    return bool(
        np.linalg.norm(pos[:2] - ctx.target_pos) <= SLIDE_POS_TOL and abs(dyaw) <= SLIDE_YAW_TOL and on_table(sim)
    )


def _slide_to_edge(sim, ctx):
    return overhang(sim) >= OVERHANG and on_table(sim)


def _grasp_single(sim, ctx):
    return any(pinches(sim, a) for a in ARMS)


def _press(sim, ctx):
    return any(press_force(sim, a) >= PRESS_FORCE for a in ARMS)


def _squeeze_edge(sim, ctx):
    return sim.obj.deformable and ridge_height(sim) >= RIDGE_HEIGHT and on_table(sim)


def _pick_up(sim, ctx):
    return _held_by(sim, 1)


def _lift_coop(sim, ctx):
    return _held_by(sim, 2)


def _grasp(sim, ctx):
    return sim.is_success()


TASKS: dict[str, TaskSpec] = {
    "touch": TaskSpec(
        "touch", "Single-arm touching: a finger of either arm touches the object.",
        _touch, "A", ("touch", "press", "slide"), "ref_book", 80, material="rigid",
    ),
    "slide": TaskSpec(
        "slide", f"Sliding on the tabletop: move the object {SLIDE_OFFSET * 100:.0f} cm towards the usable edge "
        f"(target pose within {SLIDE_POS_TOL * 100:.0f} cm / {np.degrees(SLIDE_YAW_TOL):.0f} deg), keeping it on the table.",
        _slide, "A", ("slide",), "ref_book", 120, material="rigid", make_target=_slide_target,
    ),
    "slide_to_edge": TaskSpec(
        "slide_to_edge", f"Sliding to the table edge: the object overhangs the usable edge by >= {OVERHANG * 100:.0f} cm "
        "while still lying on the table.",
        _slide_to_edge, "A", ("slide",), "ref_book", 140, material="rigid",
    ),
    "press": TaskSpec(
        "press", f"Pressing: one arm's fingers press down on the object with >= {PRESS_FORCE:.0f} N (normal force).",
        _press, "A", ("press", "slide"), "ref_book", 80, material="rigid",
    ),
    "grasp_single": TaskSpec(
        "grasp_single", "Grasping: both fingers of one arm touch the object on opposite faces.",
        _grasp_single, "A", ("grasp", "lift"), "ref_book", 200, material="rigid",
    ),
    "pick_up": TaskSpec(
        "pick_up", f"Picking up: one arm holds the object >= {LIFT_HEIGHT * 100:.0f} cm above the table, off the table, "
        f"slipping < 1 cm, for {HOLD_TIME:.0f} s.",
        _pick_up, "A", ("lift", "hold"), "ref_book", 250, material="rigid",
    ),
    "touch_dual": TaskSpec(
        "touch_dual", "Dual-arm touching: fingers of both arms touch the object at the same time.",
        _touch_dual, "B", ("touch", "squeeze"), "ref_box", 60, material="any",
    ),
    "lift_coop": TaskSpec(
        "lift_coop", f"Cooperative lifting: both arms hold the object >= {LIFT_HEIGHT * 100:.0f} cm above the table "
        f"for {HOLD_TIME:.0f} s.",
        _lift_coop, "B", ("lift", "hold"), "ref_box", 100, material="rigid",
    ),
    "squeeze_edge": TaskSpec(
        "squeeze_edge", f"Squeezing the edge: raise a fold/ridge >= {RIDGE_HEIGHT * 100:.0f} cm high in the cloth while it "
        "still lies on the table.",
        _squeeze_edge, "C", ("squeeze",), "ref_towel", 80, material="deformable",
    ),
    "grasp_edge": TaskSpec(
        "grasp_edge", "Grasping the edge: one arm's fingers pinch the cloth from both sides.",
        _grasp_single, "C", ("grasp", "lift"), "ref_towel", 150, material="deformable",
    ),
    "grasp": TaskSpec(
        "grasp", "Full grasp (the benchmark's success rule): the object held >= 5 cm above the table, off the table, "
        "fingers touching, slip < 1 cm, for 2 s, by any arms.",
        _grasp, "B", ("lift", "hold"), "ref_box", 250, material="any",
    ),
}
"""Task id -> spec.  ``expert_strategy``/``expert_stages`` say which scripted stages complete it."""


@dataclass(frozen=True)
class Scenario:
    """A chained scenario: several objects in ONE cell, cleared one after another in the same
    physics episode (:mod:`flatlab_lerobot.tasks.clear_desk`).  ``success(sim, ctx)`` is its predicate,
    checked after every control step like a task's; ``reset`` the layout distribution (which
    objects, planar poses and yaws, clearing order; per-object step budgets)."""

    id: str
    description: str
    success: Callable[[FlatLabSim, TaskContext], bool]
    reset: DeskConfig = field(default_factory=DeskConfig)
    make_target: Callable[[FlatLabSim, TaskContext], None] | None = None  # (as TaskSpec; none needed)

    @property
    def episode_length(self) -> int:
        """Control steps (10 Hz): the sum of the per-object budgets."""
        return self.reset.episode_length

    def layout(self, seed: int, split: str | None = None) -> DeskLayout:
        """The layout of ``seed``; ``split``: the catalog split its objects come from (default
        ``reset.split``, Test-beta: the benchmark's desk; ``train``: a development desk on which
        a policy's switches can be chosen without looking at test objects)."""
        return sample_desk(seed, self.config(split))

    def config(self, split: str | None = None) -> DeskConfig:
        return self.reset if split in (None, self.reset.split) else replace(self.reset, split=split)


def _clear_desk(sim, ctx):
    return desk_cleared(sim)


SCENARIOS: dict[str, Scenario] = {
    "clear_desk": Scenario(
        "clear_desk",
        "Clear the cluttered desk: five rigid Test-beta objects of five categories (three labelled A, two "
        "labelled B) lie in one cell; lift each one (the 2-s hold rule), carry it past the usable edge and "
        "drop it into the bin, until none is left on the table.",
        _clear_desk,
    ),
}
"""Scenario id -> spec (``clear_desk``).  Success: every object was lifted by the robot (the hold
rule was met for it) and none is left on the table (each centre >= 10 cm below the table top)."""


def get_task(task_id: str) -> TaskSpec:
    if task_id not in TASKS:
        raise KeyError(f"unknown task {task_id!r}; known: {sorted(TASKS)}")
    return TASKS[task_id]


# ------------------------------------------------------------------------------- episodes
def task_context(task: TaskSpec, sim: FlatLabSim) -> TaskContext:
    """The per-episode context of ``task`` for the object as it lies now (right after a reset)."""
    pos, quat = sim.object_pose()
    ctx = TaskContext(start_pos=pos, start_yaw=_yaw(quat))
    if task.make_target is not None:
        task.make_target(sim, ctx)
    return ctx


def mean_squared_jerk(tcp: np.ndarray, dt: float) -> float:
    """Mean over steps and arms of |d³p/dt³|² (m²/s⁶), finite differences of TCP positions
    sampled every control step; NaN with fewer than 4 samples."""
    p = np.asarray(tcp, dtype=float)
    if len(p) < 4:
        return float("nan")
    jerk = np.diff(p, n=3, axis=0) / dt**3
    return float(np.mean(np.sum(jerk**2, axis=-1)))


def run_scenario(scenario_id: str, seed: int = 0, strategy: str | None = "expert", split: str | None = None,
                 carry_squeeze: float | None = CARRY_SQUEEZE) -> dict:
    """One episode of a scenario on the layout of ``seed``, with the scripted expert ("expert":
    each object's labelled strategy; "A"/"B": that one for every object; None: no action).
    ``split``: the catalog split of the desk's objects (default the scenario's, Test-beta).
    ``carry_squeeze``: the expert's two-hand carry re-bases its squeeze this far (m) past the measured
    hands (default CARRY_SQUEEZE; None: the commanded squeeze as it is).
    Returns plain-JSON metrics: success, objects cleared / in the layout, per-object results
    (lifted, cleared, steps), time/steps to completion, TCP jerk, wall time."""
    sc = SCENARIOS[scenario_id]
    config = sc.config(split)
    ep = run_desk_episode(seed, strategy, config, carry_squeeze=carry_squeeze)
    success = any(ep.success)
    n = ep.success.index(True) + 1 if success else len(ep.success)
    return {
        "scenario": scenario_id,
        "seed": seed,
        "split": config.split,
        "strategy": strategy,
        "carry_squeeze": carry_squeeze,
        "object_ids": ep.object_ids,
        "success": success,
        "cleared": sum(o["cleared"] for o in ep.per_object),
        "n_objects": len(ep.object_ids),
        "objects": ep.per_object,
        "steps_to_completion": n if success else None,
        "time_to_completion_s": round(n * ep.dt, 3) if success else None,
        "steps": len(ep.success),
        "episode_length": sc.episode_length,
        "mean_squared_jerk": mean_squared_jerk(ep.tcp[:n], ep.dt),
        "failure": ep.failure,
        "wall_s": round(ep.wall_s, 3),
    }

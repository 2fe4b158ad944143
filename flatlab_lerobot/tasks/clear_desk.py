"""A cluttered desk: several rigid objects in ONE cell, cleared one after another.

This is the ``clear_desk`` scenario of :mod:`flatlab_lerobot.tasks`:

* :func:`sample_desk` draws a seeded layout: objects of different categories from one split
  (default: 5 rigid Test-beta objects, 3 labelled A and 2 labelled B), each small enough to fit,
  placed by rejection sampling so that their footprints stay inside the table's usable region
  and at least ``gap`` apart, and so that a clearing order exists (:func:`clearing_order`: front
  to back, and nothing still on the table lies in the corridor an A push sweeps towards the
  usable edge, or in the room where a B squeeze's open fingers come down).
* :func:`make_desk_sim` builds the cell: the first object of the order is the sim's main
  object, the others are clutter (:class:`~flatlab_lerobot.sim.core.FlatLabSim`), plus the
  drop bin in front of the usable edge.
* :func:`run_desk_episode` runs one physics episode: for every object in turn it makes it the
  sim's target, runs the object's labelled strategy with the scripted expert until the core
  success rule holds (lifted >= 5 cm, no table contact, held 2 s, slip < 1 cm), carries it past
  the usable edge, lets go so it drops into the bin, and goes home.  Every object has its own
  step budget (by strategy, :attr:`DeskConfig.budget`); the episode length is their sum.

Success predicate (:func:`desk_cleared`): every object was lifted by the robot (the hold rule
was met for it) and none remains on the table: each object's centre lies at least
``OFF_TABLE_DROP`` below the table top (:meth:`FlatLabSim.off_table`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from flatlab_lerobot.catalog import ObjectSpec, load_objects
from flatlab_lerobot.sim.core import FailureReason, FlatLabSim, SimulationDiverged
from flatlab_lerobot.sim.robot import ARMS, GRIPPER_MAX_WIDTH, HOME_Q
from flatlab_lerobot.sim.scene import CellConfig

CARRY_MARGIN = 0.04  # m: how far past the usable edge the held object is carried (see carry_candidates)
CARRY_SPEED = 0.10  # m/s, mean
# m: before a two-hand carry each hand's commanded position is moved back, along the line between
# the hands, to where the hand is measured plus this much inward (see rebase_squeeze).  B commands
# each hand B_SQUEEZE (2.5 cm) past the face it touched; the object stops the hands and the error
# lands on the weakest joint: the wrists (joint 6, 12 Nm) saturate and a hand holds the object bent
# up to 0.2 rad off its commanded angle.  A thin 2.2-kg board (cutboard_marble) pitched out of such
# hands mid-carry on 6 of the oracle's 8 failed Test-beta desks (stop 73).  Re-based, the command is
# 1 cm past where the hands are: the object stays clamped and the wrists keep their angles.
CARRY_SQUEEZE = 0.01
REBASE_STEPS = 5  # control steps of that move
HOME_STEPS = 20  # control steps of the joint-space move home after each object


@dataclass(frozen=True)
class DeskConfig:
    """Reset distribution and budgets of the cluttered desk.

    per_strategy: how many objects of each strategy label, every object of a different category
    (default 3 A + 2 B = 5: two B objects already fill the band near the centre line where the B
    expert lifts, see ``b_y_max``).  split: the catalog split they come from (rigid objects
    only).  max_extent: longest footprint side of an eligible object (m).  x_range / y_range: the region (m, table frame) every footprint corner must lie in;
    edge_x: the usable edge of the cell the layout is for (the default cell: table 0.6 x 0.9 m).
    yaw_deg: yaw uniform in +-this.  gap: minimum free distance between two footprints (m).
    squeeze_room: extra free room (m) on both sides of a strategy-B object along its squeeze
    axis (the one closest to world y), where the open fingers come down: their outer faces
    reach 6 cm past the object's side (4 cm approach offset + the 2-cm finger), + 1 cm margin.
    b_y_max: |y| bound of a strategy-B object's centre (m): further out the B expert fails
    (measured: a 25 cm chessboard lifts at |y| = 0.21, at x = 0 and 0.12 not at |y| = 0.25).
    draws / layout_tries / place_tries: rejection sampling: object draws, layouts per draw,
    positions per object.
    budget: control steps (10 Hz) per object by strategy, including carrying it off and going home.
    """

    per_strategy: dict = field(default_factory=lambda: {"A": 3, "B": 2})
    split: str = "test_beta"
    max_extent: float = 0.30
    x_range: tuple[float, float] = (-0.27, 0.27)
    y_range: tuple[float, float] = (-0.38, 0.38)
    edge_x: float = 0.30
    yaw_deg: float = 20.0
    gap: float = 0.02
    squeeze_room: float = 0.07
    b_y_max: float = 0.20
    draws: int = 50
    layout_tries: int = 30
    place_tries: int = 200
    budget: dict = field(default_factory=lambda: {"A": 350, "B": 200})

    @property
    def n_objects(self) -> int:
        return int(sum(self.per_strategy.values()))

    @property
    def episode_length(self) -> int:
        """Control steps of a whole episode: the sum of the per-object budgets."""
        return int(sum(n * self.budget[st] for st, n in self.per_strategy.items()))


@dataclass(frozen=True)
class DeskItem:
    """One object of a desk layout and its planar pose (x, y in m, yaw in rad)."""

    obj: ObjectSpec
    x: float
    y: float
    yaw: float

    def corners(self, pad: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """Footprint corners (4, 2), the rectangle grown by ``pad`` (along the object's x, y) on both sides."""
        hx, hy = self.obj.size[0] / 2 + pad[0], self.obj.size[1] / 2 + pad[1]
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        return local @ np.array([[c, s], [-s, c]]) + [self.x, self.y]

    def room(self, config: DeskConfig) -> np.ndarray:
        """The footprint plus the room its strategy needs free (B: ``squeeze_room`` along the squeeze axis)."""
        if self.obj.strategy != "B":
            return self.corners()
        x_is_squeeze = abs(np.sin(self.yaw)) > abs(np.cos(self.yaw))  # object x closer to world y
        r = config.squeeze_room
        return self.corners((r, 0.0) if x_is_squeeze else (0.0, r))


@dataclass(frozen=True)
class DeskLayout:
    """A sampled desk: the objects in clearing order."""

    seed: int
    items: tuple[DeskItem, ...]

    @property
    def object_ids(self) -> list[str]:
        return [it.obj.id for it in self.items]

    def episode_length(self, config: DeskConfig | None = None) -> int:
        """The sum of the per-object budgets of these objects."""
        budget = (config or DeskConfig()).budget
        return int(sum(budget[it.obj.strategy] for it in self.items))


def _separated(a: np.ndarray, b: np.ndarray, gap: float) -> bool:
    """Rectangles ``a`` and ``b`` (4 corners in order, (4, 2)) are at least ``gap`` apart along
    one of their edge normals (separating-axis test; sufficient for a distance >= gap)."""
    e = np.stack([a[1] - a[0], a[2] - a[1], b[1] - b[0], b[2] - b[1]])
    n = np.stack([-e[:, 1], e[:, 0]], axis=1) / np.linalg.norm(e, axis=1, keepdims=True)
    pa, pb = a @ n.T, b @ n.T  # (4 corners, 4 axes)
    return bool(max((pb.min(0) - pa.max(0)).max(), (pa.min(0) - pb.max(0)).max()) >= gap)


def eligible_objects(config: DeskConfig, objects: dict[str, ObjectSpec] | None = None) -> dict[str, list[ObjectSpec]]:
    """Category -> the rigid objects of ``config.split`` whose footprint fits and whose (grounded)
    label is a strategy the desk chains (A or B), sorted by id.  (Every object of a category
    carries the same paper label; categories are drawn by that label.)"""
    objects = objects if objects is not None else load_objects()
    out: dict[str, list[ObjectSpec]] = {}
    for o in sorted(objects.values(), key=lambda o: o.id):
        if (o.split == config.split and not o.deformable and max(o.size[:2]) <= config.max_extent
                and o.strategy in config.per_strategy):
            out.setdefault(o.category, []).append(o)
    return out


def sample_desk(
    seed: int, config: DeskConfig | None = None, objects: dict[str, ObjectSpec] | None = None
) -> DeskLayout:
    """A seeded desk layout (see the module docstring).  Raises ``ValueError`` when the split has
    too few eligible categories and ``RuntimeError`` when no non-overlapping placement is found.

    Rejection sampling: draw ``n_objects`` categories and one fitting object of each; place them
    one by one (biggest first), each at a uniform yaw and a uniform position where its footprint
    lies in the region (a B object's centre within ``b_y_max`` of the centre line), until one
    keeps every footprint (+ the room its strategy needs) ``gap`` apart from those placed;
    ``layout_tries`` placements per draw, ``draws`` draws (a draw of big objects may not fit)."""
    config = config or DeskConfig()
    by_cat = eligible_objects(config, objects)
    cats_of = {st: sorted(c for c, objs in by_cat.items() if objs[0].paper_strategy == st) for st in config.per_strategy}
    for st, n in config.per_strategy.items():
        if len(cats_of[st]) < n:
            raise ValueError(
                f"DeskConfig.per_strategy: split {config.split!r} has {len(cats_of[st])} rigid categories of strategy "
                f"{st} with objects of footprint <= {config.max_extent} m ({cats_of[st]}), {n} requested"
            )
    rng = np.random.default_rng(seed)
    for _ in range(config.draws):
        cats = [c for st, n in config.per_strategy.items() for c in rng.choice(cats_of[st], size=n, replace=False)]
        chosen = [by_cat[c][rng.integers(len(by_cat[c]))] for c in cats]
        chosen.sort(key=lambda o: -o.size[0] * o.size[1])  # biggest first: easier to fit
        for _ in range(config.layout_tries):
            placed = _place(chosen, config, rng)
            if placed is not None:
                return DeskLayout(seed, tuple(clearing_order(placed, config)))
    raise RuntimeError(
        f"DeskConfig: no placement of {config.n_objects} {config.split} objects with gap {config.gap} m in "
        f"x {config.x_range}, y {config.y_range} after {config.draws} draws x {config.layout_tries} layouts"
    )


def _place(chosen: list[ObjectSpec], config: DeskConfig, rng: np.random.Generator) -> list[DeskItem] | None:
    """One placement attempt: each object at a uniform yaw and the first of ``place_tries``
    uniform candidate positions that keeps ``gap`` to those placed and leaves a clearing order."""
    (x0, x1), (y0, y1) = config.x_range, config.y_range
    yaw_max = np.radians(config.yaw_deg)
    placed: list[DeskItem] = []
    for o in chosen:
        yaw = float(rng.uniform(-yaw_max, yaw_max))
        local = DeskItem(o, 0.0, 0.0, yaw).corners()
        half = np.abs(local).max(axis=0)  # AABB half extents
        lo, hi = np.array([x0, y0]) + half, np.array([x1, y1]) - half
        if o.strategy == "B":
            lo[1], hi[1] = max(lo[1], -config.b_y_max), min(hi[1], config.b_y_max)
        if np.any(lo > hi):
            return None
        cand = rng.uniform(lo, hi, size=(config.place_tries, 2))
        free = np.ones(len(cand), dtype=bool)
        for p in placed:  # vectorised separating-axis test of every candidate against p
            pc = p.corners()
            sep = np.zeros(len(cand), dtype=bool)
            for e in (local[1] - local[0], local[2] - local[1], pc[1] - pc[0], pc[2] - pc[1]):
                n = np.array([-e[1], e[0]]) / np.linalg.norm(e)
                a, b, shift = local @ n, pc @ n, cand @ n
                sep |= (b.min() - (a.max() + shift) >= config.gap) | ((a.min() + shift) - b.max() >= config.gap)
            free &= sep
        for x, y in cand[free][:10]:
            it = DeskItem(o, float(x), float(y), yaw)
            if clearing_order([*placed, it], config):
                placed.append(it)
                break
        else:
            return None
    return placed


def _blocked(it: DeskItem, others: list[DeskItem], config: DeskConfig) -> bool:
    """Would one of ``others`` (still on the table) be in the way of clearing ``it``?  A: in the
    corridor its push sweeps (its y band + ``gap``, from its back end to the usable edge).
    B: in the room its open fingers come down into (:meth:`DeskItem.room`)."""
    if it.obj.strategy == "B":
        zone = it.room(config)
    else:
        c = it.corners()
        (x0, y0), (_, y1) = c.min(axis=0), c.max(axis=0)
        x1, g = config.edge_x, config.gap
        zone = np.array([[x0, y0 - g], [x1, y0 - g], [x1, y1 + g], [x0, y1 + g]])
    return any(not _separated(zone, o.corners(), 1e-9) for o in others)


def clearing_order(items: list[DeskItem], config: DeskConfig) -> list[DeskItem]:
    """An order in which every object can be cleared without the others in its way
    (:func:`_blocked`): greedily the front-most unblocked object first.  [] when there is none."""
    rest = sorted(items, key=lambda it: -it.corners()[:, 0].max())  # front to back
    order: list[DeskItem] = []
    while rest:
        for it in rest:
            if not _blocked(it, [o for o in rest if o is not it], config):
                order.append(it)
                rest = [o for o in rest if o is not it]
                break
        else:
            return []
    return order


def make_desk_sim(layout: DeskLayout, cell: CellConfig | None = None, control_dt: float = 0.1) -> FlatLabSim:
    """The cell holding every object of ``layout`` (``objects[i]`` = ``layout.items[i]``), reset."""
    first, rest = layout.items[0], layout.items[1:]
    sim = FlatLabSim(
        first.obj, cell, control_dt, clutter=[(it.obj, (it.x, it.y, it.yaw)) for it in rest], drop_bin=True
    )
    sim.reset(first.x, first.y, first.yaw)
    return sim


# ----------------------------------------------------------------------------- predicate
def cleared(sim: FlatLabSim) -> np.ndarray:
    """Per object: lifted by the robot (the hold rule was met for it) and off the table now."""
    return np.array([bool(sim.lifted[i]) and sim.off_table(i) for i in range(len(sim.objects))])


def desk_cleared(sim: FlatLabSim) -> bool:
    """The ``clear_desk`` success predicate: every object lifted by the robot and none left on the table."""
    return bool(cleared(sim).all())


def advance_target(sim: FlatLabSim) -> int:
    """Once the target is off the table, make the first object (in clearing order) still on it
    the target, so the privileged state and the object cloud follow the next object (for
    policies run in the env).  Returns the target index."""
    if sim.off_table(sim.target_index):
        for i in range(len(sim.objects)):
            if not sim.off_table(i):
                sim.set_target(i)
                break
    return sim.target_index


# ----------------------------------------------------------------------------- the expert
def _smooth(n: int):
    for k in range(1, n + 1):
        yield 0.5 - 0.5 * np.cos(np.pi * k / n)


def carry_candidates(sim: FlatLabSim, arms: tuple[str, ...]) -> list[np.ndarray]:
    """Displacements (3,) that carry the held target past the usable edge, for every holding
    hand, preferred first (:func:`carry_off` takes the first the arms can follow): the expert's
    call, from the simulation's object; :func:`carry_displacements` is the geometry."""
    return carry_displacements(sim.object_points(), sim.object_pose()[0], sim.cell.edge_x, arms)


def carry_displacements(points: np.ndarray, centre: np.ndarray, edge_x: float, arms: tuple[str, ...]) -> list[np.ndarray]:
    """Displacements (3,) that carry an object with these ``points`` (K, 3) and ``centre`` (3,),
    held by ``arms``, past the usable edge at ``edge_x``, preferred first.  The expert passes the
    simulation's object; a learned policy its observed object cloud (:mod:`flatlab_lerobot.policies.unified`).

    Two hands (strategy B, the object squeezed between them: the shorter the carry, the less it
    creeps in the grip): the object's centre goes CARRY_MARGIN past the edge (it tips off when let
    go), straight on, else moving half / all the way to y = 0 (near the centre line both arms reach
    furthest); failing those, the whole footprint CARRY_MARGIN past the edge, the same ways.  One hand (A: it pinches the object's front edge, the
    object trails towards the table): the object's centre goes 2 x CARRY_MARGIN past the edge
    and the hand 10 cm towards its own arm's side, or straight on."""
    pts = np.asarray(points, float).reshape(-1, 3)
    pos = np.asarray(centre, float)
    edge = float(edge_x)
    if len(arms) == 2:
        full = max(0.0, edge + CARRY_MARGIN - float(pts[:, 0].min()))
        tip = max(0.0, edge + CARRY_MARGIN - float(pos[0]))
        return [np.array([dx, f * -float(pos[1]), 0.03]) for dx in (full, tip) for f in (1.0, 0.5, 0.0)]
    side = 1.0 if arms[0] == "left" else -1.0
    dx = max(0.0, edge + 2 * CARRY_MARGIN - float(pos[0]))
    return [np.array([dx, side * 0.10, 0.03]), np.array([dx, 0.0, 0.03])]


def _plan_carry(expert, arms, poses, dp: np.ndarray, q: np.ndarray, grip: dict[str, float]) -> tuple[list, float]:
    """The actions that move the hands of ``arms`` from ``poses`` by ``dp`` with a smooth
    (cosine) velocity profile -- no jerk at the start, where a friction hold is most fragile --
    computed on the expert's kinematic model, and how badly the arms would follow them (m):
    the worst of the end-pose error and the drift of the distance between two holding hands;
    inf when the joints jump (the IK lost its branch)."""
    n = max(10, int(np.ceil(float(np.linalg.norm(dp)) / CARRY_SPEED / expert.control_dt)))
    acts, qs = [], [q]
    for s in _smooth(n):
        q = expert.ik({a: (poses[a][0] + s * dp, poses[a][1]) for a in arms}, q)
        qs.append(q)
        acts.append(("move", np.r_[q[:7], grip["left"], q[7:], grip["right"]]))
    qs = np.array(qs)
    if np.abs(np.diff(qs, axis=0)).max() > 0.2:
        return acts, float("inf")
    err = max(float(np.linalg.norm(expert.fk(qs[-1])[a][0] - poses[a][0] - dp)) for a in arms)
    if len(arms) == 2:
        gaps = [np.linalg.norm(np.subtract(*(expert.fk(qk)[a][0] for a in arms))) for qk in qs[:: max(1, n // 10)]]
        err = max(err, float(np.ptp(gaps)))
    return acts, err


def _horizontal_unit(v: np.ndarray) -> np.ndarray:
    v = np.array([v[0], v[1], 0.0])
    return v / (np.linalg.norm(v) + 1e-9)


def carry_off(expert, sim: FlatLabSim, q: np.ndarray, grip: dict[str, float], squeeze: float | None = CARRY_SQUEEZE):
    """After a successful lift: carry the target past the usable edge, let go, go home (the
    expert's call: holding arms, object and its centre from the simulation; :func:`carry_and_release`,
    ``squeeze``: a two-hand carry's re-based squeeze, :func:`squeeze_backoff`).  Yields (stage, action (16,))."""
    arms = sim.holding_arms() or ARMS
    back = None
    if squeeze is not None and len(arms) == 2:
        measured = sim.joint_positions()
        back = squeeze_backoff(expert, q, np.r_[measured[0:7], measured[8:15]], squeeze)
    yield from carry_and_release(expert, arms, carry_candidates(sim, arms), lambda: sim.object_pose()[0], q, grip,
                                 back)  # fmt: skip


def _inward(cmd: dict) -> dict[str, np.ndarray]:
    """Per arm, the horizontal unit vector from its hand (``cmd``: ``expert.fk`` poses) towards the other hand."""
    u = _horizontal_unit(cmd["left"][0] - cmd["right"][0])  # right hand -> left hand
    return {"left": -u, "right": u}


def squeeze_backoff(expert, q: np.ndarray, measured: np.ndarray, squeeze: float) -> dict[str, float]:
    """Per arm, how far (m) :func:`rebase_squeeze` moves its commanded position back: how far it lies
    past the measured hand (``measured`` joints (14,)) along the horizontal line between the hands,
    less ``squeeze``; never negative."""
    cmd, now = expert.fk(q), expert.fk(measured)
    inward = _inward(cmd)
    return {a: max(0.0, float(np.dot(cmd[a][0] - now[a][0], inward[a])) - squeeze) for a in ARMS}


def rebase_squeeze(expert, q: np.ndarray, grip: dict[str, float], back: dict[str, float]):
    """Two hands holding an object between them: move each hand's commanded position ``back[arm]`` (m,
    :func:`squeeze_backoff`: to where the hand is measured plus the squeeze kept) outward along the
    horizontal line between the hands (orientations as commanded), in REBASE_STEPS smooth steps on
    the expert's kinematic model.  Yields ("move", action (16,)); returns the last commanded joints (14,)."""
    cmd = expert.fk(q)
    inward = _inward(cmd)
    qk = q
    for s in _smooth(REBASE_STEPS):
        qk = expert.ik({a: (cmd[a][0] - inward[a] * back[a] * s, cmd[a][1]) for a in ARMS}, qk)
        yield "move", np.r_[qk[:7], grip["left"], qk[7:], grip["right"]]
    return qk


def carry_and_release(expert, arms: tuple[str, ...], candidates: list[np.ndarray], centre, q: np.ndarray,
                      grip: dict[str, float], backoff: dict[str, float] | None = None):
    """Carry the hands of ``arms`` by the first of ``candidates`` (:func:`carry_displacements`) whose
    plan the arms can follow within 5 mm (else the best one), let go, go home.  Yields (stage,
    action (16,)).  ``q`` (14,) / ``grip`` are the last commanded joints / gripper widths;
    ``centre()`` is the object's centre once carried (the hands back away from it), asked when
    the release is planned.  ``backoff`` (both hands hold; :func:`squeeze_backoff`, see CARRY_SQUEEZE): first
    re-base the squeeze on where the hands are (:func:`rebase_squeeze`); None: carry the commanded
    squeeze as it is.  Plans on ``expert``'s kinematic model only."""
    from flatlab_lerobot.primitives import ArmMotion, Primitive

    if backoff is not None:
        q = yield from rebase_squeeze(expert, q, grip, backoff)
    poses = expert.fk(q)
    best, best_err = None, float("inf")
    for dp in candidates:
        acts, err = _plan_carry(expert, arms, poses, dp, q, grip)
        if best is None or err < best_err:
            best, best_err = acts, err
        if err < 5e-3:
            break
    yield from best
    q = np.r_[best[-1][1][0:7], best[-1][1][8:15]]
    # let go: open the grippers in place, then pull each hand 10 cm away from the object
    # (horizontally): an A object rests on the lower finger until that finger slides out.
    poses = expert.fk(q)
    release = {a: ArmMotion(poses[a], poses[a], (grip[a], GRIPPER_MAX_WIDTH)) for a in arms}
    yield from expert.runner.actions(Primitive("release", release, 0.5), q, grip)
    q, grip = expert.runner.q, expert.runner.grip
    c = np.asarray(centre(), float)
    motions = {}
    for a in arms:
        away = _horizontal_unit(poses[a][0] - c) * 0.10
        motions[a] = ArmMotion(poses[a], (poses[a][0] + away, poses[a][1]), (GRIPPER_MAX_WIDTH,) * 2)
    yield from expert.runner.actions(Primitive("move", motions, 1.0), q, grip)
    q, grip = expert.runner.q, expert.runner.grip
    yield from go_home(q, grip)


def go_home(q: np.ndarray, grip: dict[str, float]):
    """Joint-space move of both arms to the home posture in HOME_STEPS, grippers opening.  Yields (stage, action)."""
    goal = np.r_[HOME_Q, HOME_Q]
    g0 = dict(grip)
    for s in _smooth(HOME_STEPS):
        qk = q + (goal - q) * s
        gk = {a: g0[a] + (GRIPPER_MAX_WIDTH - g0[a]) * s for a in ARMS}
        yield "move", np.r_[qk[:7], gk["left"], qk[7:], gk["right"]]


@dataclass
class DeskEpisode:
    """What one ``clear_desk`` episode recorded (per control step, and per object)."""

    seed: int
    object_ids: list[str]
    strategies: list[str | None]
    dt: float
    tcp: list = field(default_factory=list)  # (2, 3) TCP positions per step
    stage: list = field(default_factory=list)
    target: list = field(default_factory=list)  # index of the target object per step
    success: list = field(default_factory=list)  # the predicate per step
    per_object: list = field(default_factory=list)  # one dict per object (see run_desk_episode)
    failure: str = ""
    wall_s: float = 0.0


def run_desk_episode(
    seed: int = 0,
    strategy: str | None = "expert",
    config: DeskConfig | None = None,
    layout: DeskLayout | None = None,
    cell: CellConfig | None = None,
    on_step: Callable[[FlatLabSim, str, int], None] | None = None,
    carry_squeeze: float | None = CARRY_SQUEEZE,
) -> DeskEpisode:
    """One ``clear_desk`` episode on ``layout`` (default: ``sample_desk(seed, config)``).

    ``strategy``: "expert" (each object's labelled strategy), "A"/"B" (that strategy for every
    object), or None (no action: the arms hold home for the whole episode length).
    ``carry_squeeze``: a two-hand carry first re-bases its squeeze on the measured hands, this far (m)
    past them (CARRY_SQUEEZE; None: the commanded squeeze as it is, the carry up to stop 72).
    Per object it records: id, strategy, lifted (the hold rule was met within its budget), cleared
    (lifted and off the table at the end), steps used, steps until lifted."""
    config = config or DeskConfig()
    layout = layout or sample_desk(seed, config)
    sim = make_desk_sim(layout, cell)
    strategies = [
        None if strategy is None else it.obj.strategy if strategy == "expert" else strategy for it in layout.items
    ]
    ep = DeskEpisode(seed, layout.object_ids, strategies, sim.control_dt)

    def record(stage: str) -> None:
        ep.tcp.append(np.stack([sim.tcp_pose(a)[0] for a in ARMS]))
        ep.stage.append(stage)
        ep.target.append(sim.target_index)
        ep.success.append(desk_cleared(sim))
        if on_step is not None:
            on_step(sim, stage, sim.target_index)

    t0 = time.perf_counter()
    try:
        if strategy is None:
            hold = sim.joint_positions()
            for _ in range(layout.episode_length(config)):
                sim.step(hold)
                record("none")
        else:
            from flatlab_lerobot.strategies import Expert

            expert = Expert(sim.cell, sim.control_dt)
            for i, it in enumerate(layout.items):
                ep.per_object.append(_clear_one(sim, expert, i, strategies[i], config.budget[it.obj.strategy], record,
                                                  carry_squeeze))
    except SimulationDiverged as exc:
        ep.failure = FailureReason.DIVERGED.text(str(exc))
    ok = cleared(sim)
    for i in range(len(ep.per_object), len(ep.object_ids)):  # no action, or not reached (diverged)
        ep.per_object.append(
            {
                "object_id": ep.object_ids[i],
                "strategy": strategies[i],
                "lifted": False,
                "steps_to_lift": None,
                "steps": 0,
            }
        )
    for i, rec in enumerate(ep.per_object):
        rec["lifted"] = rec["lifted"] or bool(sim.lifted[i])
        rec["cleared"] = bool(ok[i])
    if not ep.failure and not any(ep.success):
        ep.failure = FailureReason.TIMEOUT.text(f"cleared {int(ok.sum())}/{len(ok)}")
    ep.wall_s = time.perf_counter() - t0
    return ep


def _clear_one(sim: FlatLabSim, expert, index: int, strategy: str, budget: int, record, squeeze: float | None) -> dict:
    """Lift ``objects[index]`` with ``strategy``, carry it off (``squeeze``: :func:`carry_off`) and
    go home, within ``budget`` steps (the lift gets all but HOME_STEPS of them, so a failed attempt
    still ends at home)."""
    sim.set_target(index)
    rec = {"object_id": sim.obj.id, "strategy": strategy, "lifted": False, "steps_to_lift": None, "steps": 0}
    gen = expert.episode(strategy, lambda: (sim.joint_positions(), sim.environment_state()))
    action = None
    steps = 0
    while steps < budget - HOME_STEPS:
        stage, _, action = next(gen)
        sim.step(action)
        steps += 1
        record(stage)
        if sim.is_success():
            rec["lifted"], rec["steps_to_lift"] = True, steps
            break
    q = np.r_[action[0:7], action[8:15]]
    grip = {"left": float(action[7]), "right": float(action[15])}
    after = carry_off(expert, sim, q, grip, squeeze) if rec["lifted"] else go_home(q, grip)
    for stage, action in after:
        if steps >= budget:
            break
        sim.step(action)
        steps += 1
        record(stage)
    rec["steps"] = steps
    return rec

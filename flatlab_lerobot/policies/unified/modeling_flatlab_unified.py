"""``FlatLabUnifiedPolicy``: the learned strategy generator and action execution module run per step,
one state machine per batch element (as ``flatlab_scripted`` runs the scripted expert).

Per episode of batch element ``i``, on what the robot observes only:

1. **strategy** (first step): argmax of the generator on ``observation.object_pointcloud``
   (``FlatLabStrategyPolicy.predict_logits``: its own centring / unit-sphere scaling / size
   embedding), unless ``config.strategy`` fixes it.
2. **each stage** ``k`` of ``strategies.STRATEGIES[strategy]``, when the previous one has finished:
   the executor's poses from the scene cloud observed *now* (``observation.pointcloud``), the object
   cloud (the executor's frame centre) and the proprioception -- per arm the TCP pose by forward
   kinematics of the observed joints in the cell of ``observation.cell`` (``Expert.fk``) and the
   observed finger opening -- conditioned on (strategy, ``k``, the stage's primitive name from
   ``strategies.STAGE_SPECS``), exactly the encoding the primitive set was exported with.
3. the stage becomes a :class:`~flatlab_lerobot.primitives.Primitive`: ``ArmMotion(start, end,
   gripper)`` for each arm whose predicted ``active`` probability exceeds ``config.active_threshold``
   (the more probable arm when none does); the other arm holds still.  Its duration and transit are
   the expert's for that stage (``StageSpec``: slides and lifts scale with the predicted motion's
   length as the expert's do).  The expert's :class:`~flatlab_lerobot.primitives.PrimitiveRunner`
   (joint-space transit to the start, then a Cartesian line with IK at every control step, on
   commanded joints as the expert keeps them) turns it into joint targets.
4. strategy A's later push passes: pass ``p >= 1`` runs only while the object still needs to go
   further past the edge by the expert's rule (``a_push_to_edge.overhang_missing`` /
   ``pass_needed``), measured on the **object cloud** (its largest x and its extent along x) against
   the table edge of ``observation.cell``; a skipped pass's four stages are not executed (the
   primitive set drops them: no arm moves in them), and at most ``config.max_push_passes`` run.
   Which arm pushes / grasps comes from the executor's ``active`` head.
5. the final ``hold`` stage (never a training sample: no arm moves) holds still for the expert's
   2.6 s; then the last action is repeated -- or, with ``config.clear_all`` (the ``clear_desk``
   scenario), the object is carried off and the state machine starts over (:meth:`_Episode._after_hold`);
   with ``config.retry_failed``, an object not seen aloft sends the arms home and a new attempt starts.

``strategies`` / ``stages`` / ``stage_indices`` expose, per batch element, the chosen strategy (``flatlab
eval`` fills column S from it), the primitive the last action belongs to ("move" during a transit) and
the stage index.  ``observation.environment_state`` is never read: only the four inputs above are
taken out of the batch.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import mujoco
import numpy as np
import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import OBS_STATE
from torch import Tensor, nn

from flatlab_lerobot.lerobot_env import OBS_CELL, OBS_OBJECT_POINTCLOUD, OBS_POINTCLOUD
from flatlab_lerobot.policies import seen_points
from flatlab_lerobot.policies.executor.modeling_flatlab_executor import FlatLabExecutorPolicy
from flatlab_lerobot.policies.strategy.modeling_flatlab_strategy import FlatLabStrategyPolicy
from flatlab_lerobot.policies.unified.configuration_flatlab_unified import FlatLabUnifiedConfig
from flatlab_lerobot.policies.unified.observed_contact import (
    C_PINCH_STAGES,
    GRIP_CLOSED_STRATEGIES,
    MIN_POINTS,
    a_side_arm,
    a_side_arms,
    apply_heights,
    apply_xy,
    b_aligned,
    b_centred,
    c_pinch_xy,
    cap_slide,
    contact_heights,
    contact_xy,
    continued_motion,
    mirror_pose,
    object_footprint_x,
    observed_motion,
    press_floor,
    seen_centre,
    seen_width,
    sheet_lift_end,
    slide_cap,
    squeeze_end,
    turned_from_hand,
)
from flatlab_lerobot.primitives import ArmMotion, Primitive, Unreachable, joint_action
from flatlab_lerobot.sim.robot import ARMS, GRIPPER_MAX_WIDTH
from flatlab_lerobot.strategies import STAGE_SPECS, STRATEGIES
from flatlab_lerobot.strategies.expert import ExpertCache
from flatlab_lerobot.strategies.a_push_to_edge import (
    A_PASSES,
    A_PREAPPROACH,
    PASS_STAGES,
    overhang_missing,
    pass_needed,
    pusher_backoff,
)
from flatlab_lerobot.tasks.clear_desk import carry_and_release, carry_displacements, go_home, squeeze_backoff

ALOFT_CLEARANCE = 0.03  # m: the object cloud's lowest point this far above the table top = held aloft
RETRY_SAME_OBJECT = 0.05  # m: retry_next_strategy: a seen centre this close to the last attempt's is the same object
REACH_TOL = 0.03  # m: reach_check: a stage whose start pose the IK misses by more is not run
RETRY_TRACK_JUMP = 0.08  # m: retry_track: the seen centre moving this far in one control step is another object
ON_TABLE_BELOW = 0.05  # m: an object whose highest seen point is within this of the table top (or above) lies on it
LIFTED_RISE = 0.05  # m: retry_failed: the seen top risen less than this since the attempt started = nothing lifted
STALL_TOL = 0.01  # m: continue_press_stalled: a push pass that changed the seen missing overhang by less moved nothing
RESPONSE_FOLD_RISE = 0.02  # m: retry_on_response: C's squeeze raised the seen top less than this = no fold (rigid)
RESPONSE_DROOP = 0.03  # m: retry_on_response: the object cloud this far below the table top after a push = a sheet
HOLD_STILL_S = 2.0  # s: hold_still: how long the seen object must keep still in the hands (the benchmark's hold time)
C_SQUEEZED = next(i for i, s in enumerate(STAGE_SPECS["C"]) if s.primitive == "squeeze") + 1  # C's stage after its squeeze
C_STRADDLE = next(i for i, s in enumerate(STAGE_SPECS["C"]) if s.primitive == "press")  # C's hand straddles the fold
C_PINCH = next(i for i, s in enumerate(STAGE_SPECS["C"]) if s.primitive == "grasp")  # ... then pinches it


@dataclass
class Observed:
    """One batch element's observation, as the policy reads it (nothing else reaches the state machine)."""

    state: np.ndarray  # (16,) per arm 7 joints + finger opening
    cell: np.ndarray  # (7,) calibration
    cloud: np.ndarray  # (N, 3) scene cloud, world frame
    object_cloud: np.ndarray  # (K, 3) object cloud, world frame (zeros: not seen)

    @property
    def table_top(self) -> float:
        return float(self.cell[0])  # CellConfig.calibration: table top height first

    @property
    def edge_x(self) -> float:
        return float(self.cell[1]) / 2  # table depth / 2: the usable edge (CellConfig.edge_x)

    @property
    def object_points(self) -> np.ndarray:
        """The seen object points (M, 3) (all-zero rows are unseen)."""
        return seen_points(self.object_cloud)

    @property
    def q14(self) -> np.ndarray:
        return np.r_[self.state[0:7], self.state[8:15]]

    @property
    def fingers(self) -> dict[str, float]:
        return {a: float(self.state[8 * i + 7]) for i, a in enumerate(ARMS)}


def _quat(R: np.ndarray) -> np.ndarray:
    """wxyz, w >= 0 (the primitive set's convention)."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(R, float).reshape(-1))
    return -q if q[0] < 0 else q


def _rotmat(q) -> np.ndarray:
    q = np.asarray(q, float)
    q = q / max(np.linalg.norm(q), 1e-12)
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, q)
    return R.reshape(3, 3)


_UNTAKEN = object()


def _points_mean(pts: np.ndarray) -> np.ndarray:
    """The mean of a cloud's points (3,)."""
    return np.asarray(pts, float).mean(0)


def _extent_middle(pts: np.ndarray) -> np.ndarray:
    """The middle of a cloud's extent in x and y, its mean height (3,): unlike the mean, not pulled towards
    where the cameras see the object densest (``carry_box_centre``)."""
    pts = np.asarray(pts, float)
    return np.r_[(pts[:, :2].min(0) + pts[:, :2].max(0)) / 2, pts[:, 2].mean()]


class _Lookahead:
    """An iterator that can say whether it has a next item (by taking that item one call early)."""

    def __init__(self, items):
        self._it, self._next = iter(items), _UNTAKEN

    def __iter__(self):
        return self

    def __next__(self):
        if self._next is _UNTAKEN:
            return next(self._it)
        item, self._next = self._next, _UNTAKEN
        if item is StopIteration:
            raise StopIteration
        return item

    def has_next(self) -> bool:
        if self._next is _UNTAKEN:
            self._next = next(self._it, StopIteration)
        return self._next is not StopIteration


class _Episode:
    """One batch element's episode: the strategy, the stage being executed and the commanded joints.
    With ``clear_all`` an episode holds several attempts (one per object, or retries), one after another."""

    def __init__(self, policy: FlatLabUnifiedPolicy, expert, strategy: str | None):
        self.policy, self.expert = policy, expert
        self.fixed = strategy  # None: learned
        self.strategy = strategy  # None until the first observation (learned)
        self.index = -1  # stage index in STRATEGIES[strategy]
        self.stage: str | None = None  # primitive name of the last action ("move": a transit)
        self.q: np.ndarray | None = None  # commanded arm joints (14,)
        self.grip: dict[str, float] = {}
        self.last: np.ndarray | None = None
        self.actions = None
        self.after = None  # clear_all: the carry-off / go-home / settle actions after the final hold
        self.lift_arms: tuple[str, ...] = ()  # the arms the last posed stage commanded (they hold what was lifted)
        self.a_side: str | None = None  # contact_a_grasp: A's grasp arm by the seen side, decided at the pre-approach
        # contact_a_pusher_side / a_side_arms: A's pushing arm by the seen side, decided at the first touch
        self.a_pusher: str | None = None
        self.obs: Observed | None = None
        self.started = False  # the current attempt has its strategy
        self.attempts: list[str] = []  # clear_all: the strategy of every attempt so far
        self.tried: list[str] = []  # retry_next_strategy: the strategy of each attempt on the object seen at tried_at
        self.tried_at: np.ndarray | None = None  # its seen centre (x, y) when the last attempt started
        self.first_ranked: list[str] | None = None  # retry_rank=first_sight: the ranking at the first attempt on it
        self.track_at: np.ndarray | None = None  # retry_track: the object cloud's seen centre (x, y) at the last step
        self.track_jumped = False  # retry_track: it jumped (the env shows another object) since the attempt started
        self.log: list[dict] = []  # per stage: what was decided (tests, debugging)
        self.first_press_z: dict[str, float] = {}  # continue_press_repeat: per arm, where A's first press ended (z)
        self.last_missing: float | None = None  # A: the seen missing overhang at the start of the last push pass
        self.stalled = 0  # continue_press_stalled: push passes in a row that found the object where the last one did
        self.start_top: float | None = None  # retry_failed: the object cloud's seen top when the attempt started
        self.hold_checked = False  # retry_failed: the attempt's final hold ended and was judged
        self.hold_rel: list[np.ndarray] = []  # hold_still: per step of the final hold, the seen object centre - hands
        self.hold_extra = 0  # hold_still: control steps the final hold has gone on past its own length
        self.hold_slid = False  # hold_still: the object was still seen sliding in the hands when the hold ran out

    def act(self, obs: Observed) -> np.ndarray:
        self.obs = obs
        if self.policy.config.retry_track:
            self._track(obs)
        if self.q is None:
            self.q, self.grip = obs.q14.copy(), obs.fingers
            self.last = joint_action(self.q, self.grip)
        if not self.started:
            if (self.policy.config.clear_all or self.policy.config.retry_failed) and not self._object_on_table(obs):
                self.stage = "hold"  # nothing (more) on the table to start on
                return self.last
            if self.strategy is None:
                self.strategy = self._next_strategy(obs)
            self.started = True
            pts = obs.object_points
            self.start_top = float(pts[:, 2].max()) if len(pts) else None
            self.attempts.append(self.strategy)
        n_stages = len(STRATEGIES[self.strategy])
        if self.policy.config.hold_still is not None and self.index == n_stages - 1 and self.after is None:
            self._record_hold(obs)
        while True:
            if self.after is not None:
                if self._emit(self.after):
                    return self.last
                self.after = None
                self._restart()
                return self.act(obs)
            if self.actions is not None:
                try:
                    if self._emit(self.actions):
                        return self.last
                except Unreachable as miss:  # reach_check: the arm never moved towards it
                    self._unreachable(obs, miss, n_stages)
                    continue
                self.actions = None
                self.q, self.grip = self.expert.runner.q.copy(), dict(self.expert.runner.grip)
            if self.index + 1 >= n_stages:
                if self.policy.config.clear_all:
                    if self._hold_on(obs):  # hold_still: the object is still seen moving in the hands
                        self.stage = "hold"
                        return self.last
                    self.after = self._after_hold(obs)
                    continue
                if self._failed_after_hold(obs):  # retry_failed: not aloft after the hold, go home and try again
                    self.after = self._after_hold(obs, settle=False)
                    continue
                self.stage = "hold"
                return self.last
            self.index += 1
            if self._response_failed(obs, n_stages):  # retry_on_response: the object answers as another kind
                continue
            if self._skip_pass(obs):
                continue
            if self._failed_before_hold(obs, n_stages):  # quick_retry: nothing aloft to hold, go home now
                self.after = self._after_hold(obs, settle=False)
                continue
            reach = REACH_TOL if self.policy.config.reach_check else None
            self.actions = _Lookahead(self.expert.runner.actions(self._primitive(obs), self.q, self.grip,
                                                                 reach_tol=reach))

    def reads_next_clouds(self) -> bool:
        """Whether the next :meth:`act` may read the clouds: False only while the current stage's actions
        go on (the next one is already computed; a stage reads its observation when it is planned).
        ``clear_all`` / ``retry_track`` / ``quick_retry`` follow or check the object cloud at every step."""
        cfg = self.policy.config
        if cfg.clear_all or cfg.retry_track or cfg.quick_retry or self.after is not None:
            return True
        return self.actions is None or not self.actions.has_next()

    def _emit(self, steps) -> bool:
        """Take the next (stage, action) of ``steps`` as the last action; False when it is exhausted."""
        step = next(steps, None)
        if step is None:
            return False
        self.stage, self.last = step
        return True

    # -------------------------------------------------------------- several objects (clear_all)
    @staticmethod
    def _object_on_table(obs: Observed) -> bool:
        pts = obs.object_points
        return bool(len(pts)) and float(pts[:, 2].max()) > obs.table_top - ON_TABLE_BELOW

    @staticmethod
    def _aloft(obs: Observed) -> bool:
        pts = obs.object_points
        return bool(len(pts)) and float(pts[:, 2].min()) > obs.table_top + ALOFT_CLEARANCE

    def _failed_before_hold(self, obs: Observed, n_stages: int) -> bool:
        """``quick_retry`` (with ``clear_all``): the final hold is about to begin and the object cloud is not
        aloft -- the lift visibly failed, and arms that stand still will not lift it.  ``retry_failed``: the
        same, but only when nothing was lifted at all (the seen top has not risen LIFTED_RISE since the attempt
        started); an object lifted but not yet aloft (a cloth whose hem still touches the table, a pair of hands
        still settling) gets its hold, and is judged at its end (:meth:`_failed_after_hold`)."""
        cfg = self.policy.config
        if self.index != n_stages - 1 or not (cfg.quick_retry or cfg.retry_failed) or self._aloft(obs):
            return False
        if cfg.retry_failed:
            pts = obs.object_points
            rise = float(pts[:, 2].max()) - self.start_top if len(pts) and self.start_top is not None else 0.0
            if rise >= LIFTED_RISE:
                return False
            self.log.append({"index": self.index, "retry_failed": "nothing lifted", "rise": round(rise, 4)})
            return True
        self.log.append({"index": self.index, "quick_retry": True})
        return True

    def _record_hold(self, obs: Observed) -> None:
        """``hold_still``: one step of the final hold: the mean of the object cloud relative to the mean of the lifting
        hands (forward kinematics of the observed joints)."""
        pts = obs.object_points
        if len(pts):
            fk = self.expert.fk(obs.q14)
            hands = np.mean([fk[a][0] for a in (self.lift_arms or ARMS)], axis=0)
            self.hold_rel.append(np.asarray(pts, float).mean(0) - hands)

    def _hold_on(self, obs: Observed) -> bool:
        """``hold_still``: whether the final hold, at its end, goes on one more step.  The benchmark counts an object
        lifted once it was held aloft for 2 s in which it moved less than 1 cm relative to the holding hands; an object
        carried off the table before that is off it uncounted, for good.  So the carry waits until the object cloud,
        relative to the lifting hands, has stayed within ``hold_still`` of where it was HOLD_STILL_S earlier (each
        step's sample against the window's first), for at most ``hold_still_max_s`` past the hold's own length.  An
        object still seen sliding then is not carried (``hold_slid``): the arms let go and go home, as after a failed
        lift, and the next attempt starts from where it falls.  An object not seen aloft is not held on (the carry or
        the way home decides, as without the switch)."""
        cfg = self.policy.config
        if cfg.hold_still is None or not self._aloft(obs):
            return False
        n = round(HOLD_STILL_S / cfg.control_dt)
        window = self.hold_rel[-n:]
        moved = max((float(np.linalg.norm(r - window[0])) for r in window), default=0.0)
        still = len(window) >= n and moved < cfg.hold_still
        if still or self.hold_extra >= round(cfg.hold_still_max_s / cfg.control_dt):
            self.hold_slid = not still
            if self.hold_extra or not still:
                self.log.append({"index": self.index, "hold_still": {"extra_steps": self.hold_extra, "still": still,
                                                                     "moved": round(moved, 4)}})
            return False
        self.hold_extra += 1
        return True

    def _failed_after_hold(self, obs: Observed) -> bool:
        """``retry_failed``: the final hold has just ended (judged once per attempt) and the object cloud is not
        aloft.  An object seen aloft is held on for the rest of the episode, as without the switch."""
        if not self.policy.config.retry_failed or self.hold_checked:
            return False
        self.hold_checked = True
        if self._aloft(obs):
            return False
        self.log.append({"index": self.index, "retry_failed": "not aloft after the hold"})
        return True

    def _response_failed(self, obs: Observed, n_stages: int) -> bool:
        """How the object answered the stage that has just ended, logged at two points of every attempt: C's
        squeeze (the seen top's rise since the attempt started: a sheet folds up, a rigid object does not) and each
        of A's push passes (how far the object cloud hangs below the table top: a sheet pushed over the edge
        droops, a rigid object stays level).  With the strategy's letter in ``retry_on_response`` an answer of
        another kind of object (no fold at the first attempt, on the object as it was placed; a droop) ends the
        attempt: the arms go home at once and the strategies it rules out count as tried ``retry_switch_after``
        times, so the next attempt takes the generator's most probable other one.  A sheet that a failed A left
        hanging over the edge folds less (Train's ``shorts_denim``: 0.8 and 1.4 cm), hence C's first attempt only.
        A third reading, C's fold (the seen top's rise since the attempt started) as the pinching hand is about to
        straddle it and again as it is about to pinch: a stiff pad folds under the squeeze and lies back down flat
        once let go, often only while the hand comes down (Train's ``mousepad_large``, stops 71-72); with
        ``retry_on_fold_lost`` a fold lower than that as the pinch begins, at C's first attempt, rules C out the same
        way.  A cloth's fold mostly stands, but the pinch also gathers and lifts a cloth whose fold has lain flat (the
        unseen scarves, stop 72), so no row uses that switch."""
        pts, i, cfg = obs.object_points, self.index, self.policy.config
        if not len(pts) or self.start_top is None:
            return False
        if self.strategy == "C" and i in (C_SQUEEZED, C_STRADDLE, C_PINCH):
            rise = float(pts[:, 2].max()) - self.start_top
            ruled_out = ("C",)
            if i == C_SQUEEZED:
                on, limit, key = "C" in cfg.retry_on_response, RESPONSE_FOLD_RISE, "fold_rise"
            else:  # the straddle's reading is only logged
                on, limit, key = bool(cfg.retry_on_fold_lost) and i == C_PINCH, cfg.retry_on_fold_lost, "fold_kept"
            other = rise < limit and self.tried == ["C"]  # the first attempt on this object
            entry = {"index": i, key: round(rise, 4)}
        elif self.strategy == "A" and 0 < i <= A_PREAPPROACH and i % PASS_STAGES == 0:
            droop = obs.table_top - float(pts[:, 2].min())
            on, other, ruled_out = "A" in cfg.retry_on_response, droop > RESPONSE_DROOP, ("A", "B")
            entry = {"index": i, "droop": round(droop, 4)}
        else:
            return False
        entry["response_failed"] = fire = bool(on and other)
        self.log.append(entry)
        if fire:
            self._end_attempt(obs, n_stages, ruled_out)
        return fire

    def _unreachable(self, obs: Observed, miss: Unreachable, n_stages: int) -> None:
        """``reach_check``: the stage's start pose is out of the arm's reach (its IK, on the robot's kinematic
        model, misses it by more than REACH_TOL), so the attempt ends before the arm moves.  With
        ``clear_all`` the arms go home and the next attempt takes another strategy (with
        ``retry_next_strategy`` this one counts as tried ``retry_switch_after`` times on the object); without,
        they hold.  The left arm sent for B to a pad in the table's right-hand corner (desk 48: its touch
        25 cm across the centre line at the table's back) ended 54 cm from the touch, below the table top,
        and the squeeze that followed threw the laptop beside the pad off the table."""
        self.log.append({"index": self.index, "unreachable": miss.miss})
        self._end_attempt(obs, n_stages, self.tried[-1:])

    def _end_attempt(self, obs: Observed, n_stages: int, ruled_out) -> None:
        """End the attempt before its next stage (``reach_check``, ``retry_on_response``): with retries on the object
        (``retry_next_strategy``, ``retry_failed``) the strategies ``ruled_out`` count as tried ``retry_switch_after``
        times on it; where another attempt follows (``clear_all``, ``retry_failed``) the arms go home at once,
        without, they hold."""
        self.actions, self.index = None, n_stages - 1
        cfg = self.policy.config
        if cfg.retry_next_strategy or cfg.retry_failed:
            for s in ruled_out:
                self.tried += [s] * (int(cfg.retry_switch_after) - self.tried.count(s))
        if cfg.clear_all or cfg.retry_failed:
            self.after = self._after_hold(obs, settle=False)

    def _after_hold(self, obs: Observed, settle: bool = True):
        """After the final hold: if the object cloud is aloft, carry it past the usable edge with the
        arms that lifted it and let go (``tasks.clear_desk.carry_and_release``: the expert's carry, planned
        on the kinematic model from the observed cloud and cell instead of the simulation); else go home.
        Then (``settle``) hold ``settle_s`` (the object falls off the table).  Yields (stage, action)."""
        pts = obs.object_points
        aloft = self._aloft(obs) and not self.hold_slid  # hold_still: an object still sliding is let go, not carried
        arms = self.lift_arms or ARMS
        self.log.append({"index": self.index, "after": "carry" if aloft else "home", "arms": list(arms)})
        if aloft:
            middle = _extent_middle if self.policy.config.carry_box_centre else _points_mean
            cands = carry_displacements(pts, middle(pts), obs.edge_x, arms)
            centre = lambda: middle(self.obs.object_points if len(self.obs.object_points) else pts)  # noqa: E731
            squeeze, back = self.policy.config.carry_squeeze, None
            if squeeze is not None and len(arms) == 2:
                measured = np.r_[obs.state[0:7], obs.state[8:15]]  # the arms' joints, as observed
                back = squeeze_backoff(self.expert, self.q, measured, squeeze)
                self.log[-1]["squeeze_backoff"] = {a: round(v, 4) for a, v in back.items()}
            actions = carry_and_release(self.expert, arms, cands, centre, self.q, self.grip, back)
        else:
            actions = go_home(self.q, self.grip)
        last = None
        for step in actions:
            last = step[1]
            yield step
        last = self.last if last is None else last
        for _ in range(round(self.policy.config.settle_s / self.policy.config.control_dt) if settle else 0):
            yield "hold", last

    def _next_strategy(self, obs: Observed) -> str:
        """The generator's strategy; with ``retry_next_strategy``, when the object cloud is seen where the last
        attempt started (within RETRY_SAME_OBJECT: the same object, left on the table; with ``retry_track``: the
        object the last attempt ended on, followed step by step, wherever it was moved), its most probable
        strategy not yet tried ``retry_switch_after`` times there (all three tried that often: from the top again).
        With ``retry_failed`` (one object per episode) every attempt after the first is on the same object.  With
        ``retry_rank=first_sight`` a retry on the same object keeps the ranking of the cloud seen as the first
        attempt on it started, instead of ranking the cloud seen now."""
        cfg = self.policy.config
        forced = cfg.first_attempt if not self.attempts else ""  # diagnostic: ranked first on the first sight
        if not (cfg.retry_next_strategy or cfg.retry_failed):
            return forced or self.policy.choose_strategy(obs.object_cloud)
        k = int(cfg.retry_switch_after)
        pts = obs.object_points
        here = seen_centre(pts)[:2] if len(pts) else None
        same = here is not None and self.tried_at is not None
        if cfg.retry_failed:  # one object per episode: every attempt is on it
            same = bool(self.tried)
        elif cfg.retry_track:
            same, self.track_jumped = same and not self.track_jumped, False
        else:
            same = same and float(np.linalg.norm(here - self.tried_at)) < RETRY_SAME_OBJECT
        if not same or len(self.tried) >= 3 * k:
            self.tried = []
        if same and cfg.retry_rank == "first_sight" and self.first_ranked is not None:
            ranked = list(self.first_ranked)
        else:
            ranked = self.policy.rank_strategies(obs.object_cloud)
            if forced:
                ranked = [forced] + [s for s in ranked if s != forced]
        if not same:
            self.first_ranked = list(ranked)
        choice = next(s for s in ranked if self.tried.count(s) < k)
        self.log.append({"retry": {"same_object": bool(same), "tried": list(self.tried), "ranked": ranked,
                                   "chosen": choice}})  # fmt: skip
        self.tried.append(choice)
        self.tried_at = here
        return choice

    def _track(self, obs: Observed) -> None:
        """``retry_track``: follow the object cloud's seen centre from step to step.  A push moves the object
        (A's slide carries it 20-40 cm towards the edge), so where a failed A attempt started no longer finds
        it and A never counts as tried on it; a jump of RETRY_TRACK_JUMP in one step (0.8 m/s, eight times
        the carry's speed) is the env showing the next object."""
        pts = obs.object_points
        if len(pts) < MIN_POINTS:
            return
        here = seen_centre(pts)
        if self.track_at is not None and float(np.linalg.norm(here - self.track_at)) > RETRY_TRACK_JUMP:
            self.track_jumped = True
        self.track_at = here

    def _restart(self) -> None:
        """Start a new attempt from the joints commanded last (the strategy is chosen again)."""
        self.q = np.r_[self.last[0:7], self.last[8:15]].copy()
        self.grip = {"left": float(self.last[7]), "right": float(self.last[15])}
        self.strategy, self.index, self.lift_arms, self.started, self.a_side = self.fixed, -1, (), False, None
        self.a_pusher, self.first_press_z = None, {}
        self.last_missing, self.stalled = None, 0
        self.start_top, self.hold_checked = None, False
        self.hold_rel, self.hold_extra, self.hold_slid = [], 0, False

    # -------------------------------------------------------------- decisions from observations
    def _skip_pass(self, obs: Observed) -> bool:
        """Strategy A at a later pass's first stage: skip the whole pass (and advance past it) when the
        object cloud already overhangs the edge enough, or when ``max_push_passes`` have run.  At every pass's first
        stage (the first pass's too) the missing overhang is kept, and a later pass that finds it within STALL_TOL of
        the last one counts as stalled (``continue_press_stalled``)."""
        p = self.index // PASS_STAGES
        if self.strategy != "A" or self.index % PASS_STAGES or not 0 <= p < A_PASSES:
            return False
        foot = object_footprint_x(obs.object_cloud)
        missing = None if foot is None else overhang_missing(foot[0], foot[1], obs.edge_x)
        last, self.last_missing = self.last_missing, missing
        if p == 0:  # the first pass always runs; what it finds is what the next pass compares with
            return False
        stalled = missing is not None and last is not None and abs(missing - last) < STALL_TOL
        self.stalled = self.stalled + 1 if stalled else 0
        skip = p >= self.policy.config.max_push_passes or (missing is not None and not pass_needed(missing))
        self.log.append({"index": self.index, "pass": p, "missing": missing, "skipped": bool(skip),
                         **({"stalled": self.stalled} if self.stalled else {})})
        if skip:
            self.index += PASS_STAGES - 1
        return skip

    def _primitive(self, obs: Observed) -> Primitive:
        spec = STAGE_SPECS[self.strategy][self.index]
        if self.index == len(STRATEGIES[self.strategy]) - 1:  # the final hold: no arm moves
            self.log.append({"index": self.index, "primitive": spec.primitive, "arms": []})
            return Primitive(spec.primitive, {}, spec.seconds(), transit=spec.transit)
        executor, members = self.policy.executor_for(self.strategy, self.index)
        posed_as = self._posed_as()
        poses = executor.predict_poses(
            obs.cloud, self.strategy, posed_as, spec.primitive, self._proprio(obs), object_cloud=obs.object_cloud,
            tta=self.policy.config.executor_tta or None, members=members,
        )
        thr = self.policy.config.active_threshold
        prob = {a: float(poses[a]["active"][0]) for a in ARMS}
        arms = [a for a in ARMS if prob[a] > thr] or [max(ARMS, key=prob.get)]
        motions, duration, heights = {}, 0.0, {}
        # the observed rules pose this strategy's stages (contact=observed, the strategy in contact_strategies)
        observed = self.policy.config.contact == "observed" and self.strategy in self.policy.config.contact_strategies
        a_grasp = observed and self.policy.config.contact_a_grasp
        source, y_centre, arm_log = None, None, {}  # contact_a_grasp: the learned arm mirrored onto the rule's arm
        if a_grasp and self.strategy == "A" and self.index >= A_PREAPPROACH:  # A's pre-approach and after
            arms, source, y_centre, arm_log = self._a_grasp_arms(arms, prob, obs)
        elif observed and self.policy.config.contact_a_pusher_side and self.strategy == "A" and self.index < A_PREAPPROACH:
            arms, source, y_centre, arm_log = self._a_pusher_arms(arms, prob, obs)
        elif self.policy.config.a_side_arms and self.strategy == "A":  # learned poses, the arm on the seen side
            side_arms = self._a_grasp_arms if self.index >= A_PREAPPROACH else self._a_pusher_arms
            arms, source, y_centre, arm_log = side_arms(arms, prob, obs)
        commanded_fk = functools.cache(lambda: self.expert.fk(self.q))  # once per stage, only if a rule asks
        continued = self.strategy in self.policy.config.continue_from_hand and spec.start == "current"  # learned only
        ruled = self.strategy == "C" and bool(self.policy.config.continue_c_heights)  # heights by a rule (learned only)
        if ruled and spec.primitive in C_PINCH_STAGES and self.policy.config.continue_c_heights != "all":
            ruled = False  # "press": the pressing hands' touch and squeeze only
        if self.strategy == "A" and self.policy.config.continue_a_grasp_heights and self.index >= A_PREAPPROACH:
            ruled = True  # A's approach and grasp at the seen overhang's mid height
        if observed:
            pts = obs.object_points
        pinch_centre = self.strategy == "C" and self.policy.config.continue_c_pinch_centre and spec.primitive == "press"
        if observed or ruled or pinch_centre:
            pincher = min(arms, key=lambda a: float(poses[a]["gripper"][1][0]))  # the arm whose gripper closes most
        for a in arms:
            src = source or a
            (p0, q0), (p1, q1) = poses[src]["start"], poses[src]["end"]
            p0, p1 = p0[0].astype(float), p1[0].astype(float)
            R0, R1 = _rotmat(q0[0]), _rotmat(q1[0])
            if source is not None:
                (p0, R0), (p1, R1) = mirror_pose(p0, R0, y_centre), mirror_pose(p1, R1, y_centre)
            turn = None
            if observed and self.policy.config.contact_b_align and self.strategy == "B" and spec.primitive == "touch":
                p0, p1, R0, R1, turn = b_aligned(p0, p1, R0, R1, pts)  # the fingers along the seen side
            if observed and self.policy.config.contact_b_centred and self.strategy == "B" and spec.primitive == "touch":
                p0, p1 = b_centred(p0, p1, R1, pts)  # the hand faces the seen centre
            if observed:  # contact heights, A's slide, C's squeeze and pinch from the clouds (observed_contact.py)
                hand = lambda a=a: commanded_fk()[a][0]  # noqa: E731  the commanded hand's position
                p0, p1, heights[a] = observed_motion(self.strategy, self.index, spec.primitive, p0, p1, pts,
                                                     obs.table_top, obs.edge_x, a == pincher, hand,
                                                     from_hand=self.policy.config.contact_from_hand,
                                                     b_face=self.policy.config.contact_b_face,
                                                     a_grasp=a_grasp,
                                                     a_sheet_lift=self.policy.config.contact_a_sheet_lift,
                                                     b_steady=self.policy.config.contact_b_steady,
                                                     a_slide_full=self.policy.config.contact_a_slide_full,
                                                     a_touch=self.policy.config.contact_a_touch)  # fmt: skip
                if turn is not None:
                    heights[a]["b_align_deg"] = math.degrees(turn)
                if heights[a].get("from_hand"):  # the hand's orientation, turned as learned: no transit first
                    R0, R1 = turned_from_hand(R0, R1, commanded_fk()[a][1])
                if heights[a].get("still") or heights[a].get("steady"):  # A's grasp (contact_a_grasp): the
                    R1 = R0  # fingers close, the hand stays; B's squeeze, lift (contact_b_steady): no turn
            elif (self.policy.config.continue_a_preapproach_line and self.strategy == "A"
                  and self.index == A_PREAPPROACH):  # from the hand (continue_from_hand holds A: the config checks)
                p0 = np.array(commanded_fk()[a][0], float)
                heights[a] = {"line": True}
            elif continued:  # continue_from_hand: from the commanded hand, by the learned displacement and turn
                cfg = self.policy.config
                level = (cfg.continue_level_slide and spec.primitive == "slide") or (
                    cfg.continue_level_squeeze and spec.primitive == "squeeze")
                deeper = cfg.continue_press_deeper if spec.primitive == "press" else 0.0
                if spec.primitive == "press" and self.strategy == "A" and cfg.continue_press_stalled:
                    deeper += self.stalled * float(cfg.continue_press_stalled)  # the last pass slid over it
                (p0, R0), (p1, R1) = continued_motion(p0, R0, p1, R1, *commanded_fk()[a], level=level, deeper=deeper)
                heights[a] = {"from_hand": True, **({"level": True} if level else {}), **({"deeper": deeper} if deeper else {})}
                if cfg.continue_press_floor and self.strategy == "A" and spec.primitive == "press":
                    p1, raised = press_floor(p1, obs.object_points, cfg.continue_press_floor)
                    if raised:
                        heights[a]["floor"] = round(raised, 4)  # raised by (m)
                if cfg.continue_press_repeat and self.strategy == "A" and spec.primitive == "press":
                    self._repeat_press(a, p1, heights[a])
                if cfg.continue_slide_cap and self.strategy == "A" and spec.primitive == "slide":
                    cap = slide_cap(obs.object_points, obs.edge_x)
                    capped = cap_slide(p0, p1, cap)
                    if not np.allclose(capped, p1):
                        heights[a]["cap"] = round(float(p1[0] - capped[0]), 4)  # how much shorter than learned
                    p1 = capped
                if cfg.continue_c_squeeze_end and self.strategy == "C" and spec.primitive == "squeeze":
                    end = squeeze_end(p0, p1, obs.object_points)  # 2.5 cm short of the seen cloth's centre
                    heights[a]["squeeze_end"] = round(float(np.linalg.norm(end[:2] - p1[:2])), 4)  # moved by (m)
                    p1 = end
                if cfg.continue_a_sheet_lift and self.strategy == "A" and spec.primitive == "lift":
                    p1, heights[a]["sheet_lift"] = sheet_lift_end(p0, p1, obs.object_points, obs.table_top, obs.edge_x)
            if heights.get(a, {}).get("line"):  # a Cartesian line from the hand to the learned pose, in transit time
                R0 = commanded_fk()[a][1]  # (contact_a_grasp, continue_a_preapproach_line): the runner makes no transit
                duration = max(duration, spec.transit)
            if ruled and not observed:  # C's heights over the observed table, A's grasp at the seen overhang
                p0, p1 = self._rule_heights(spec, p0, p1, continued, a == pincher, obs, heights.setdefault(a, {}))
            if pinch_centre and a == pincher and not observed:  # C's straddle over the seen cloth's centre
                xy = c_pinch_xy(spec.primitive, obs.object_points, None)
                if xy is not None:
                    heights.setdefault(a, {})["pinch_centre"] = round(float(np.linalg.norm(xy - p0[:2])), 4)  # moved by
                    p0, p1 = apply_xy(p0, p1, xy)
            g0, g1 = (float(np.clip(g[0], 0.0, GRIPPER_MAX_WIDTH)) for g in poses[src]["gripper"])
            if (observed and self.policy.config.contact_grip_closed and self.strategy in GRIP_CLOSED_STRATEGIES and a == pincher
                    and spec.primitive in ("grasp", "lift")):  # the pinch closes fully and stays closed
                g0, g1 = (g0 if spec.primitive == "grasp" else 0.0), 0.0
                heights[a]["closed"] = True
            motions[a] = ArmMotion((p0, R0), (p1, R1), (g0, g1))
            duration = max(duration, spec.for_motion(p0, p1))
        side_grasp = a_grasp or self.policy.config.a_side_arms  # the config holds a_side_arms to contact=learned
        if side_grasp and self.policy.config.contact_a_backoff and self.strategy == "A" and self.index == A_PREAPPROACH:
            arms, duration = self._pusher_backoff(arms, motions, heights, duration, obs, commanded_fk, spec)
        self.lift_arms = tuple(arms)
        self.log.append({"index": self.index, "primitive": spec.primitive, "arms": arms, "active": prob,
                         "duration": duration, **({"heights": heights} if observed or continued or ruled or heights else {}),
                         **arm_log,
                         **({"posed_as": posed_as} if posed_as != self.index else {})})  # fmt: skip
        return Primitive(spec.primitive, motions, duration, transit=spec.transit)

    def _rule_heights(self, spec, p0: np.ndarray, p1: np.ndarray, continued: bool, pinching: bool, obs: Observed,
                      log: dict) -> tuple[np.ndarray, np.ndarray]:
        """``continue_c_heights`` (C's stages) and ``continue_a_grasp_heights`` (A's approach and grasp): one arm's
        learned motion ``p0 -> p1`` of stage ``spec`` with the heights of contact=observed's rule for that strategy: for
        C the expert's pressing and pinching heights above ``obs.table_top``, for A the seen overhang's mid height.  A
        stage continued from the hand keeps its start (the hand, so no transit) and gets the rule's end height only; a
        lift keeps its learned rise."""
        z0, z1 = contact_heights(self.strategy, self.index, spec.primitive, obs.object_points,
                                 contact_xy(spec.primitive, p0, p1), obs.table_top, obs.edge_x, pinching=pinching)
        if continued:
            z0, z1 = None, (z1 if spec.primitive != "lift" else None)
        if z0 is None and z1 is None:  # a stage the rule gives no height (a release, a move; the other arm's pinch)
            return p0, p1
        if continued:
            p1 = np.array(p1, float)
            p1[2] = z1
        else:
            p0, p1 = apply_heights(p0, p1, z0, z1)
        log["rule_heights"] = [z0, z1]
        return p0, p1

    def _posed_as(self) -> int:
        """The stage index the executor poses this stage as: the stage itself, or with ``a_passes_as_first`` a later
        push pass's stage as the same stage of the first pass (its primitive is the same: touch, press, slide,
        release)."""
        later_pass = PASS_STAGES <= self.index < A_PASSES * PASS_STAGES
        if self.policy.config.a_passes_as_first and self.strategy == "A" and later_pass:
            return self.index % PASS_STAGES
        return self.index

    def _repeat_press(self, arm: str, p1: np.ndarray, log: dict) -> None:
        """``continue_press_repeat``: A's first press of ``arm`` is remembered; a later pass's press (``p1``, changed
        in place) ends no higher than it.  Traces of Train trials (stop 50, ``disk_cork_coaster``): the learned
        press of the second pass ended 1.5 cm above the first's, the hand slid over the coaster, which stayed
        3.5 cm short of the overhang the grasp needs."""
        if self.index < PASS_STAGES:
            self.first_press_z[arm] = float(p1[2])
        elif arm in self.first_press_z and p1[2] > self.first_press_z[arm]:
            log["repeat"] = round(float(p1[2]) - self.first_press_z[arm], 4)  # how much lower than learned
            p1[2] = self.first_press_z[arm]

    def _pusher_backoff(self, arms, motions, heights, duration, obs: Observed, commanded_fk, spec):
        """``contact_a_backoff`` at A's pre-approach: the arm off the seen side (the pusher) backs off from
        its commanded hand as the expert's does (``pusher_backoff``), replacing any learned motion of it;
        otherwise it stays where its release left it, 13 cm above the table, in the lifted object's way.  With
        ``contact_a_grasp`` (observed contact) or ``a_side_arms`` (learned poses): both decide the pusher and the
        grasping arm by the seen side.  Learned desk 22 (stop 74): the lifted CD case rose into the pusher's idle
        hand, the env's hold rule restarted, and the carry took it off the table before the rule was met.
        Returns (arms, duration)."""
        if self.a_side is None or self.a_pusher == self.a_side:  # the pusher grasps too: nothing to back off
            return arms, duration
        pusher = next(a for a in ARMS if a != self.a_side)
        hand, R = commanded_fk()[pusher]
        back = pusher_backoff(pusher, hand)
        motions[pusher] = ArmMotion((np.array(hand, float), R), (back, R), (obs.fingers[pusher],) * 2)
        heights[pusher] = {"backoff": [float(v) for v in back]}
        return [a for a in ARMS if a in arms or a == pusher], max(duration, spec.transit, spec.for_motion(hand, back))

    def _a_grasp_arms(self, learned: list[str], prob: dict[str, float], obs: Observed):
        """``contact_a_grasp`` in A's grasp stages (:meth:`_side_arms`).  The side is decided once, at the
        pre-approach, from the object cloud seen then (observed_contact.a_side_arm)."""
        if self.index == A_PREAPPROACH:
            self.a_side = a_side_arm(obs.object_points)
        return self._side_arms(self.a_side, learned, prob, obs, preapproach=self.index == A_PREAPPROACH)

    def _a_pusher_arms(self, learned: list[str], prob: dict[str, float], obs: Observed):
        """``contact_a_pusher_side`` in A's push passes (:meth:`_side_arms`), for the pushing arm, decided
        once per attempt at its first touch from the object cloud seen then, as the expert's ``_a_arm``.  The
        executor chose the arm off the object's side for a CD case 24 cm to the right (desk 8): reaching across,
        the hand stopped short of the case and three passes moved nothing."""
        if self.a_pusher is None:
            self.a_pusher = a_side_arm(obs.object_points)
        return self._side_arms(self.a_pusher, learned, prob, obs)

    def _side_arms(self, side: str | None, learned: list[str], prob: dict[str, float], obs: Observed,
                   preapproach: bool = False):  # fmt: skip
        """(arms, the learned arm mirrored onto the arm on ``side`` or None, the seen centre line's y it is
        mirrored across, the stage log's entry) for one of A's stages run by the arm on the seen side."""
        arms, source = a_side_arms(learned, prob, side, preapproach=preapproach)
        y_centre = None if source is None else float(seen_centre(obs.object_points)[1])
        return arms, source, y_centre, {"a_arm": {"learned": learned, "side": side, "mirrored_from": source}}

    def _proprio(self, obs: Observed) -> np.ndarray:
        """(16,) per arm TCP position, quaternion wxyz (forward kinematics of the observed joints) and
        finger opening: the executor's ``observation.tcp_state``."""
        fk = self.expert.fk(obs.q14)
        fingers = obs.fingers
        return np.concatenate([np.r_[fk[a][0], _quat(fk[a][1]), fingers[a]] for a in ARMS]).astype(np.float32)


class FlatLabUnifiedPolicy(PreTrainedPolicy):
    config_class = FlatLabUnifiedConfig
    name = "flatlab_unified"

    def __init__(self, config: FlatLabUnifiedConfig, dataset_stats=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        config.fill_sub_features()
        self.config = config
        self.generator = FlatLabStrategyPolicy(config.generator)
        self.executor = FlatLabExecutorPolicy(config.executor)
        # a second executor for some strategies (None: ``executor`` poses every stage)
        self.alt_executor = FlatLabExecutorPolicy(config.alt_executor) if config.alt_executor is not None else None
        # ensemble members averaged with executor / alt_executor (empty: a single executor each)
        self.executor_members = nn.ModuleList(FlatLabExecutorPolicy(c) for c in config.executor_members)
        self.alt_executor_members = nn.ModuleList(FlatLabExecutorPolicy(c) for c in config.alt_executor_members)
        self._experts = ExpertCache(config.control_dt)
        self._episodes: list[_Episode] | None = None

    # ------------------------------------------------------------------ lerobot API
    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self):
        self._episodes = None

    @property
    def strategies(self) -> list[str | None]:
        """Per batch element, the strategy of the current episode (``flatlab eval``'s column S); with
        ``retry_failed``, the first attempt's: the generator's choice, not the retry that followed it."""
        return [e.attempts[0] if e.policy.config.retry_failed and e.attempts else e.strategy
                for e in self._episodes or []]

    @property
    def stages(self) -> list[str | None]:
        """Per batch element, the primitive the last action belongs to ("move": a joint-space transit)."""
        return [e.stage for e in self._episodes or []]

    @property
    def stage_indices(self) -> list[int]:
        """Per batch element, the stage index in ``strategies.STRATEGIES[strategy]`` (-1: not started)."""
        return [e.index for e in self._episodes or []]

    @property
    def reads_next_clouds(self) -> bool:
        """Whether the next :meth:`select_action` may read ``observation.pointcloud`` / ``object_pointcloud``
        (True before the first step).  ``flatlab eval`` lets the env skip rendering them when it will not
        (``FlatLabEnv.skip_clouds``): the episode is the same, the stage's steps between its decisions
        render nothing."""
        return self._episodes is None or any(e.reads_next_clouds() for e in self._episodes)

    @property
    def attempts(self) -> list[list[str]]:
        """Per batch element, the strategy of every attempt of the episode (one, unless ``clear_all`` or
        ``retry_failed``)."""
        return [list(e.attempts) for e in self._episodes or []]

    @property
    def decisions(self) -> list[list[dict]]:
        """Per batch element, what each stage decided (arms, active probabilities, skipped passes)."""
        return [list(e.log) for e in self._episodes or []]

    def executor_for(self, strategy: str, index: int) -> tuple[FlatLabExecutorPolicy, tuple[FlatLabExecutorPolicy, ...]]:
        """The executor that poses stage ``index`` of ``strategy`` and its ensemble members: ``alt_executor`` for
        the strategies in ``alt_executor_strategies`` (with ``alt_executor_stages=push``, A's push passes only),
        else ``executor``."""
        alt = self.alt_executor is not None and strategy in self.config.alt_executor_strategies
        if alt and self.config.alt_executor_stages == "push" and strategy == "A" and index >= A_PREAPPROACH:
            alt = False  # A's grasp stages
        if alt:
            return self.alt_executor, tuple(self.alt_executor_members)
        return self.executor, tuple(self.executor_members)

    def _expert(self, i: int, cell: np.ndarray):
        """Batch element ``i``'s kinematic model (IK, FK, primitive runner) of the observed cell."""
        return self._experts.get(i, cell)

    def choose_strategy(self, object_cloud: np.ndarray) -> str:
        """The generator's strategy (A/B/C) for one object cloud (K, 3): the most probable of
        :meth:`rank_strategies`."""
        return self.rank_strategies(object_cloud)[0]

    @torch.no_grad()
    def rank_strategies(self, object_cloud: np.ndarray) -> list[str]:
        """The generator's strategies (A/B/C), most probable first, for one object cloud (K, 3):
        :meth:`FlatLabStrategyPolicy.rank_cloud` with ``generator_cloud_points`` and ``generator_tta``; with
        ``b_min_width``, B last when the seen object is narrower than that."""
        ranked = self.generator.rank_cloud(object_cloud, self.config.generator_cloud_points, self.config.generator_tta or None)
        if self.config.b_min_width and "B" in ranked:
            width = seen_width(seen_points(np.asarray(object_cloud, float)))
            if width is not None and width < self.config.b_min_width:
                ranked = [s for s in ranked if s != "B"] + ["B"]
        return ranked

    @staticmethod
    def observed(batch: dict[str, Tensor]) -> list[Observed]:
        """The batch's per-element observations: the four inputs the policy reads, and nothing else."""

        def arr(key: str) -> np.ndarray:
            if key not in batch:
                raise KeyError(f"flatlab_unified: the batch has no {key!r}; the env must give it "
                               "(--env.obs_pointcloud=true for the clouds)")  # fmt: skip
            return batch[key].detach().cpu().numpy().astype(np.float64)

        state = arr(OBS_STATE)
        if state.ndim == 1:
            state = state[None]
        b = len(state)
        cell = arr(OBS_CELL).reshape(b, -1)
        cloud = arr(OBS_POINTCLOUD).reshape(b, -1, 3)
        obj = arr(OBS_OBJECT_POINTCLOUD).reshape(b, -1, 3)
        return [Observed(state[i], cell[i], cloud[i], obj[i]) for i in range(b)]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        obs = self.observed(batch)
        if self._episodes is None or len(self._episodes) != len(obs):
            fixed = None if self.config.strategy == "learned" else self.config.strategy
            self._episodes = [_Episode(self, self._expert(i, o.cell), fixed) for i, o in enumerate(obs)]
        actions = np.stack([ep.act(o) for ep, o in zip(self._episodes, obs)])
        return torch.as_tensor(actions, dtype=torch.float32, device=batch[OBS_STATE].device)

    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        return self.select_action(batch).unsqueeze(1)

    def forward(self, batch: dict[str, Tensor]):
        raise NotImplementedError(
            "flatlab_unified is assembled from trained sub-models, not trained itself: train the generator "
            "(--policy.type=flatlab_strategy) and the executor (--policy.type=flatlab_executor) with lerobot-train, "
            "then `flatlab unified-build --generator ... --executor ... --out ...`"
        )

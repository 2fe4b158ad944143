"""Config of the ``flatlab_unified`` policy type: the paper's unified FlatLab policy (§3, App. B) --
a trained strategy generator (``flatlab_strategy``) and a trained action execution module
(``flatlab_executor``) in one artifact, run per step inside ``select_action``.

One folder (``config.json`` + ``model.safetensors`` + processor files, as ``save_pretrained`` writes)
holds both sub-models: their configs are the nested fields ``generator`` and ``executor`` here, their
weights the ``generator.*`` / ``executor.*`` entries of ``model.safetensors``.  ``flatlab unified-build``
assembles it from two trained ``pretrained_model`` folders; ``--policy.path=<folder>`` reloads it
(``lerobot-eval``, ``flatlab eval``), and ``push_to_hub`` pushes it like any LeRobot policy.

Per episode and batch element (see :mod:`.modeling_flatlab_unified`): the strategy from the object
cloud (or fixed by ``strategy``), then for each stage of that strategy -- the expert's stage list and
primitive names (``strategies.STRATEGIES`` / ``STAGE_SPECS``) -- the executor's poses from the scene
cloud observed when the stage starts, executed by the expert's primitive runner and IK with the
expert's timing.

``strategy``: ``learned`` (the generator chooses; the unified policy), or ``A`` / ``B`` / ``C`` for
every object: ``A`` is the learned Slide baseline and ``B`` the learned Lift baseline of the paper's
tables (the same executor, the strategy fixed).

``clear_all``: several objects per episode (the ``clear_desk`` scenario, ``--env.task=clear_desk``):
after the final hold the policy carries the lifted object past the usable edge and lets go (or goes
home when the object cloud shows it still on the table), then starts over on the object cloud the env
shows next; every decision again from observations only.

Inputs it reads (and keeps as its only ``input_features``): ``observation.state`` (16: joints +
finger widths), ``observation.cell`` (7: table and arm-base calibration -> its kinematic model),
``observation.pointcloud`` (scene, N x 3) and ``observation.object_pointcloud`` (K x 3).  It never
reads ``observation.environment_state``.  No normalization: the sub-models normalize their own clouds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, NormalizationMode, PolicyFeature, PreTrainedConfig
from lerobot.optim import AdamConfig
from lerobot.utils.constants import ACTION, OBS_STATE

from flatlab_lerobot.lerobot_env import OBS_CELL, OBS_OBJECT_POINTCLOUD, OBS_POINTCLOUD
from flatlab_lerobot.policies import identity_normalization
from flatlab_lerobot.policies.executor.configuration_flatlab_executor import (
    ACTION_DIM as EXECUTOR_ACTION_DIM,
    OBS_OBJECT_CLOUD,
    OBS_PRIMITIVE,
    OBS_TCP_STATE,
    PRIMITIVE_DIM,
    TCP_STATE_DIM,
    FlatLabExecutorConfig,
)
from flatlab_lerobot.policies.strategy.configuration_flatlab_strategy import FlatLabStrategyConfig
from flatlab_lerobot.policies.unified.observed_contact import CONTACT_CHOICES
from flatlab_lerobot.strategies.a_push_to_edge import A_PASSES
from flatlab_lerobot.strategies.b_squeeze import B_SQUEEZE

STRATEGY_CHOICES = ("learned", "A", "B", "C")
C_HEIGHTS_CHOICES = ("", "press", "all")  # continue_c_heights: off, the pressing hands, the pinching hand too
INPUTS = (OBS_STATE, OBS_CELL, OBS_POINTCLOUD, OBS_OBJECT_POINTCLOUD)
"""The only observations the policy reads."""
STATE_DIM, CELL_DIM, ACTION_DIM = 16, 7, 16
GENERATOR_INPUT = "observation.object_pointcloud"  # the generator must read the object cloud


ALT_EXECUTOR_STAGES = ("all", "push")  # the stages of alt_executor_strategies the second executor poses


def distinct_strategies(strategies) -> bool:
    """Whether ``strategies`` (a list, or a string of letters) are distinct letters of A / B / C."""
    return len(set(strategies)) == len(strategies) and set(strategies) <= set(STRATEGY_CHOICES[1:])


def check_alt_strategies(strategies: list[str], has_alt: bool, flag: str = "--policy.alt_executor_strategies") -> None:
    """Raise (naming ``flag``) unless ``strategies`` are distinct letters of A / B / C, given exactly when a
    second executor is: the one rule of the config and of ``flatlab unified-build --alt-strategies``."""
    if not distinct_strategies(strategies):
        raise ValueError(f"{flag}: distinct strategies of {list(STRATEGY_CHOICES[1:])}, got {list(strategies)!r}")
    if bool(strategies) != has_alt:
        raise ValueError(f"{flag}: names the strategies the second executor poses; give both or neither "
                         f"(second executor {'given' if has_alt else 'absent'}, strategies {list(strategies)!r})")


def executor_input_mismatch(a: FlatLabExecutorConfig, b: FlatLabExecutorConfig) -> str:
    """Why executor ``b`` cannot share ``a``'s input batch ("" when it can): the fields that decide which
    inputs ``predict_poses`` builds, and the cloud sizes."""
    for f in ("use_proprio", "frame_center", "n_points", "n_object_points"):
        if getattr(a, f) != getattr(b, f):
            return f"{f} is {getattr(b, f)!r}, the executor's {getattr(a, f)!r}"
    return ""


@PreTrainedConfig.register_subclass("flatlab_unified")
@dataclass
class FlatLabUnifiedConfig(PreTrainedConfig):
    # the trained sub-models' configs (flatlab unified-build copies them from their pretrained_model folders)
    generator: FlatLabStrategyConfig = field(default_factory=FlatLabStrategyConfig)
    executor: FlatLabExecutorConfig = field(default_factory=FlatLabExecutorConfig)
    # optionally a second trained executor (`flatlab unified-build --alt-executor`), which poses every stage
    # of the strategies in ``alt_executor_strategies`` (``executor`` poses the others); its weights are the
    # ``alt_executor.*`` entries of ``model.safetensors``.  It must read the same clouds as ``executor``.
    alt_executor: FlatLabExecutorConfig | None = None
    alt_executor_strategies: list[str] = field(default_factory=list)
    # which of those strategies' stages the second executor poses: "all" (default), or "push": only A's push passes
    # (touch, press, slide, release; stages before A's pre-approach), so that A's grasp stages stay with ``executor``.
    # An executor whose frame sits on the object's seen top places A's press on a thin object's top, where the grasp
    # under the overhang is a height above the table (stop 63, docs/unified.md)
    alt_executor_stages: str = "all"
    # an ensemble: further executors (the same recipe trained with other seeds; `flatlab unified-build
    # --executor DIR DIR ...`) whose predictions are averaged with ``executor``'s at every stage it poses;
    # weights ``executor_members.<i>.*``.  ``alt_executor_members`` likewise for ``alt_executor``.
    executor_members: list[FlatLabExecutorConfig] = field(default_factory=list)
    alt_executor_members: list[FlatLabExecutorConfig] = field(default_factory=list)
    # learned: the generator picks the strategy per episode; A / B / C: fixed (A = learned Slide, B = learned Lift)
    strategy: str = "learned"
    control_dt: float = 0.1  # s: must match the env's 1/fps
    # strategy A: push passes at most (the expert's A_PASSES); a later pass runs only while the object
    # cloud overhangs the table edge (observation.cell) by less than the expert's target
    max_push_passes: int = A_PASSES
    # an arm is commanded by a stage when the executor's "active" probability exceeds this; when no
    # arm does, the more probable one (every trained sample commands at least one moving arm)
    active_threshold: float = 0.5
    # the observed object cloud's distinct seen points are farthest-point resampled to this many before the
    # generator reads them, as the strategy set's clouds are (FPS of all object pixels to 2048); 0: all of them
    generator_cloud_points: int = 2048
    # the executor's test-time augmentation passes per stage (flatlab_executor `tta`: k rotations about z
    # and point subsets, predictions averaged); 0: the executor config's own value
    executor_tta: int = 0
    # the generator's test-time augmentation passes (flatlab_strategy `tta`: k fixed point subsets, the
    # cloud turned by 2*pi*j/k about z, probabilities averaged); 0: the generator config's own value
    generator_tta: int = 0
    # several objects per episode (the clear_desk scenario): after the final hold, carry what the lifting
    # arms hold past the usable edge (observation.cell) and let go, or, when the object cloud is not
    # aloft, go home; wait ``settle_s``; then start again -- a new strategy from the object cloud the env
    # shows now (the next object, or the same one after a failed attempt), while it lies on the table
    clear_all: bool = False
    settle_s: float = 1.0
    # with clear_all or retry_failed: the carry-off takes the held object's centre as the middle of the object
    # cloud's extent (x, y), not the mean of its points.  The seen points crowd where the cameras see the object
    # best: on a Train development desk (desk 6, stop 70) a B-held keyboard_compact's cloud spanned its true extent
    # within 3 mm but its mean lay 4 cm behind its centre, so B's carry let go of it short of the edge and it fell
    # back onto the table, twice
    carry_box_centre: bool = False
    # with clear_all or retry_failed: before a two-hand carry-off, each hand's commanded position moves back, along the
    # line between the hands, to where the hand is measured (observation.state) plus this much inward (m;
    # tasks.clear_desk.rebase_squeeze; the expert's desk uses CARRY_SQUEEZE, 0.01).  A squeeze commanded 2.5 cm past the
    # object's faces saturates the wrists (joint 6, 12 Nm), which then hold the object bent up to 0.2 rad off their
    # commanded angle: the thin 2.2-kg cutboard_marble pitched out of such hands mid-carry (stop 73).  None: the
    # commanded squeeze is carried as it is
    carry_squeeze: float | None = None
    # with clear_all: the final hold goes on while the object is seen moving in the lifting hands.  The carry-off
    # begins once the object cloud's mean, relative to the hands (forward kinematics of observation.state), has
    # stayed within this distance (m) for 2 s (the benchmark's hold), or hold_still_max_s past the hold's own length.
    # The benchmark counts an object as lifted after 2 s aloft in which it slid less than 1 cm in the hands: a carry
    # that takes off an object still sliding leaves it off the table uncounted, for good (stop 74: on the learned
    # Test-beta desk 28 a one-hand laptop sank 2.6 cm in the grasp during the hold).  None: off
    hold_still: float | None = None
    hold_still_max_s: float = 2.0
    # with clear_all: an attempt on an object seen where the last attempt started (it was left on the table)
    # takes the generator's most probable strategy not yet tried on it, instead of asking again for the same one
    retry_next_strategy: bool = False
    # with retry_next_strategy or retry_failed: the attempts one strategy gets on an object left in place before
    # the next most probable one is tried (1: switch after every failed attempt)
    retry_switch_after: int = 1
    # with retry_next_strategy or retry_failed: what ranks the strategies of a retry on the same object.  current:
    # the object cloud seen as the retry starts; first_sight: the cloud seen as the first attempt on this object
    # started (the object as it lay before anything touched it, like every cloud the generator was trained on; a
    # cloth dropped from a failed C lies folded and is ranked B or A: Train's shorts_sport at seed 1001, stop 67)
    retry_rank: str = "current"
    # with retry_next_strategy: the object is the same as the last attempt's when the object cloud, followed from
    # step to step, never jumped since (wherever the attempt moved it), not when it is seen where that attempt
    # started (A's push moves it, so a strategy that pushes never counted as tried twice)
    retry_track: bool = False
    # a stage whose start pose the arm cannot reach (the transit's IK on the robot's kinematic model misses it by
    # more than 3 cm) is not run: the attempt ends there, before the arm moves (with clear_all the arms go home
    # and, with retry_next_strategy, the next attempt takes another strategy; without, they hold)
    reach_check: bool = False
    # with clear_all: when the object cloud is not aloft as the final hold begins (the lift visibly failed),
    # skip the hold and the settle and go home at once, to retry sooner
    quick_retry: bool = False
    # one object per episode (not with clear_all, whose retries are the switches above): an attempt whose lift
    # visibly failed -- the object cloud not aloft when the final hold ends, or, already as it begins, its seen
    # top not risen 5 cm above where it lay when the attempt started -- lets go, goes home and starts again,
    # with the generator's most probable strategy not yet tried retry_switch_after times (a fixed strategy:
    # the same one); nothing is tried while the object cloud is off the table.  Not in the paper
    retry_failed: bool = False
    # with retry_failed (or, on the desk, retry_next_strategy), for the strategies whose letters it holds (C, A,
    # AC; empty: off): an attempt whose object answers as another kind of object ends there, and the strategies that
    # answer rules out count as tried retry_switch_after times.  C: the squeeze of the first attempt on the object
    # has just ended and the seen top has not risen RESPONSE_FOLD_RISE above where it lay (no fold: a rigid object)
    # -> C ruled out.  A: one of A's push passes has just ended and the object cloud hangs RESPONSE_DROOP below the
    # table top (a sheet drooping over the edge) -> A and B ruled out.  Spares the episode a whole wrong attempt.
    # Not in the paper
    retry_on_response: str = ""
    # with retry_failed (or, on the desk, retry_next_strategy): the first C attempt on the object ends, and C counts
    # as tried retry_switch_after times, when the fold it raised has sunk below this height (m; the seen top's rise
    # since the attempt started) as the pinching hand, straddling it, is about to pinch: a stiff pad that folded under
    # the squeeze and lay back down flat once let go (Train's mousepad_large, stop 71).  0: off.  Chosen on Train
    # (stop 72): 0.01 (the mouse pads' first-C readings were 0.0 in 10 of 10 trials, the cloths' 0.0 in 1 of 40 and
    # 1.6-2.0 cm in 2).  Measured on all splits (one build): Train +2 trials, Test-alpha -1, Test-beta -13 (the
    # unseen scarves are lifted from a fold that has lain flat), so no row uses it (docs/unified.md).  Not in the paper
    retry_on_fold_lost: float = 0.0
    # B ranked last (tried only after A and C) when the seen object's shorter horizontal side is below this (m; the
    # smallest rectangle around the object cloud seen from above); 0: off.  B's two hands cannot squeeze a narrow
    # object: the scripted B, on square and oblong calibration slabs that are not benchmark objects, lifts none
    # narrower than 8 cm, 1 in 5 at 8.5 cm, 2 in 5 at 9 cm, every one from 9.5 cm (docs/unified.md, stop 76).  No
    # Train object is that narrow, so Train cannot choose it; 0.09 comes from the calibration alone.  On the benchmark
    # it moves one object's ranking (Test-beta's 7.6-cm pad of sticky notes).  Not in the paper
    b_min_width: float = 0.0
    # diagnostic (stress tests of the retries on Train): the first sight's ranking has this strategy (A, B or C)
    # moved to its top, as if the generator ranked it first, so the first attempt takes it and, with retry_rank=
    # first_sight, the retries keep that ranking.  Column S then reports this strategy.  Empty: off
    first_attempt: str = ""
    # learned: every pose as the executor predicts it (the paper's method); observed: the heights of the
    # stages that touch the object (A's press passes and side grasp, B's squeeze) and the length of A's
    # slide by the expert's rules on the observed object cloud and table, the rest learned (not in the
    # paper; observed_contact.py)
    contact: str = "learned"
    # with contact=observed: the strategies whose stages the rules pose (their contact_* switches act); a strategy
    # left out runs as contact=learned does, every pose as the executor predicts it.  The B rules were chosen in
    # stops 38-42 on an executor that no longer poses B; on Train, unified_cpu_one_rot15's learned B lifts the
    # B-labelled objects 79 of 80 times, its B with the observed rules 71 (the keyboards 6 of 15; stop 52)
    contact_strategies: str = "ABC"
    # with contact=learned, for the strategies whose letters it holds (e.g. AC; empty: off): every stage that
    # the expert starts where the hand is (StageSpec.start == "current": A's press, slide, release, grasp, lift; B's
    # squeeze, lift; C's squeeze, release, moves, grasp, lift) starts at the commanded hand (the policy's own
    # joint targets, by forward kinematics) and moves by the executor's predicted displacement and turn,
    # instead of a joint-space transit to the learned start first; nothing read from the clouds changes
    # (contact=observed has its own contact_from_hand, with the observed heights).  Measured on Train (stop 48,
    # docs/unified.md): A and C gain, B loses (its learned squeeze, no longer relaxed by the transit, presses
    # too far into a board)
    continue_from_hand: str = ""
    # with continue_from_hand: a slide continued from the hand keeps the hand's height (the learned
    # displacement's vertical part dropped), as the expert's slide along the table is level in every demo
    continue_level_slide: bool = False
    # with continue_from_hand: a squeeze continued from the hand (C's; B is not continued) keeps the hand's
    # height, as the expert's squeeze is level in every demo (dz = 0 in all 154 C arm-samples of the Train
    # primitive set). Measured on the Train C objects (stop 60): 10 -> 11 of 20, 4 won / 3 lost: not adopted
    # (docs/unified.md)
    continue_level_squeeze: bool = False
    # with continue_from_hand: a press continued from the hand ends this much (m) lower than learned, so the
    # hand presses into a thin object instead of resting a few mm above it (>= 0)
    continue_press_deeper: float = 0.0
    # with continue_from_hand (A): a later push pass's continued press ends no higher than the arm's press of
    # the first pass ended (commanded, world z): the object's thickness and the table do not change between
    # passes, and the first pass's press is the one that pushed it (reads no cloud: the policy's own commands)
    continue_press_repeat: bool = False
    # with continue_from_hand (A): a later push pass that finds the object cloud where the previous pass found it
    # (its footprint's missing overhang changed by less than STALL_TOL, 1 cm: that pass's press slid over the object)
    # presses this much deeper than the learned press (and continue_press_deeper), once more for each such pass in a
    # row (m, >= 0; reads the object cloud and cell, as the rule that decides the pass does).  Traces of Train trials
    # (stop 65): mousepad_standard and disk_compact_disc at seed 1004 pressed at 0.768-0.770 m, 0.8 cm above the presses
    # that pushed, and three passes left the object where it lay
    continue_press_stalled: float = 0.0
    # with continue_from_hand (A): a continued press ends with the fingertips at most this far (m) below the seen
    # object top under them (the object cloud, as contact=observed's rule reads it; the expert presses 1 mm below;
    # 0: off).  Applied after continue_press_deeper and continue_press_stalled, so it bounds them on thick objects
    # and leaves thin ones alone (their floor lies below the table).  Traced on Train desk 88 (stop 75): the deepened
    # press drove the fingertips through an 8-mm cork coaster to the table, the slide stalled, and the release swept
    # the coaster off the table.  With 0.003 on 60 Train desks: 59 -> 58 (wins desk 88, loses 3 and 82), so off
    continue_press_floor: float = 0.0
    # with continue_from_hand (A): a slide continued from the hand advances along +x at most the expert's
    # ``slide_distance`` for the overhang still missing, measured on the object cloud seen as the slide is planned
    # (the rule that already decides another push pass; contact=observed caps its slide the same way): a slide
    # that ran longer once the press held the object pushed it off the table (reads the object cloud and cell)
    continue_slide_cap: bool = False
    # A's later push passes (pass p >= 1, when the rule above runs them) posed by the executor as its first pass
    # (stage k - 4p: touch, press, slide, release), from the scene cloud seen now: the primitive set holds 191 Train
    # arm-samples of the first pass, 56 of the second and 4 of the third; the first pass's poses are those of a push
    # from behind the object as it lies to the overhang (learned only; reads the clouds it always reads). Alone it
    # pushes objects off the table (a whole first push); with continue_slide_cap the FlatLab row since stop 61 (Train A
    # objects, strategy A: 63 -> 77 of 100 lifted at two seed sets; docs/unified.md)
    a_passes_as_first: bool = False
    # with C in continue_from_hand: C's heights by the expert's rule on the table top of observation.cell (no cloud;
    # the rule contact=observed applies to C): "press" sets the pressing hands' touch end and squeeze end at the
    # expert's pressing height (finger tips 1 mm above the table, leaning), "all" also the pinching hand's straddle
    # and grasp at its pinching height; x, y, orientations and grippers stay learned.  The learned C squeeze ran
    # 1-6 mm lower than the expert's and stopped after 2 cm in the cloth (stop 60, docs/unified.md)
    continue_c_heights: str = ""
    # with C in continue_from_hand: C's squeeze, continued from the hand along its learned direction, ends C_END_HALF_GAP
    # (2.5 cm) short of the seen cloth's centre, as the expert's squeeze ends 2.5 cm from the sheet's centre
    # (contact=observed's C squeeze rule, observed_contact.squeeze_end; reads the object cloud).  Traces of Train trials
    # (stop 65): on shorts_sport at seeds 1001 and 1004 the learned squeeze left the hands 9-10 cm apart where the
    # expert's leaves them 5-6 cm apart, the fold stayed low and the pinch rose empty
    continue_c_squeeze_end: bool = False
    # C's straddle (the pinching hand's press, the arm whose learned gripper closes most) comes down over the seen
    # cloth's centre: the learned motion shifted so that it starts there, heights and orientation kept, as the expert
    # straddles the fold at the sheet's current centre (contact=observed's C rule, observed_contact.c_pinch_xy; reads
    # the object cloud).  Traces of Train trials (stop 65): with the longer squeeze above, the learned left-hand moves
    # dragged the taller fold 4-5 cm (shorts_denim seed 2000) and the learned straddle came down beside it
    continue_c_pinch_centre: bool = False
    # with A in continue_from_hand: A's lift of an object whose seen overhang droops (a sheet) rises at least the seen
    # length + 8 cm, as the expert lifts a sheet (contact_a_sheet_lift's rule, observed_contact.sheet_lift_end; reads the
    # object cloud and cell); a rigid object's learned lift stands
    continue_a_sheet_lift: bool = False
    # with A in continue_from_hand: A's approach and grasp at the mid height of the seen overhang (the object cloud's
    # points past the table edge; contact=observed's A rule), the learned height where fewer than 10 points overhang
    continue_a_grasp_heights: bool = False
    # with A in continue_from_hand: A's pre-approach runs as a Cartesian line from each commanded hand (position and
    # orientation) to its learned pose, in the stage's transit time, instead of a joint-space transit (contact_a_grasp's
    # line for contact=observed; reads nothing).  Traces of Train trials (stop 67): from the pusher's release 11 cm above
    # book_paperback_novel (seed 1001) and disk_vinyl_lp (seed 1001), the transit's joint-space path swung the turning
    # hand down onto the pushed object and swept it off the table, where the expert's transit passed above it
    continue_a_preapproach_line: bool = False
    # A's stages run by the arm on the seen object's side (right at y <= 0, as the expert's pusher and grasping arm):
    # the pusher decided at the attempt's first touch, the grasping arm at its pre-approach, from the object cloud seen
    # then; the executor's arm where it chose that one, else its most active arm's motion mirrored across the seen
    # centre line (contact=observed's contact_a_pusher_side and contact_a_grasp arms, observed_contact.a_side_arms;
    # learned poses otherwise; reads the object cloud).  On the desk (stop 69) every learned A attempt whose touch was
    # out of reach had the executor's arm on the far side of an object 18-31 cm off the centre line, where single
    # objects lie within 5 cm of it
    a_side_arms: bool = False
    # with contact=observed: A's and B's stages that the expert starts where the hand is (A's press, slide,
    # release, grasp, lift; B's squeeze, lift) start at the commanded hand with their learned displacement,
    # so no transit moves a hand that presses or holds the object (observed_contact.py)
    contact_from_hand: bool = False
    # with contact=observed: B's touch ends just outside the face of the seen object cloud it approaches
    # (observed_contact.py)
    contact_b_face: bool = False
    # with contact=observed: A's grasp stages use the arm on the seen object's side (the expert's rule; a
    # learned motion of the other arm is mirrored across the object's centre line) and the pre-approach
    # runs as a Cartesian line from the hand instead of a joint-space transit (observed_contact.py)
    contact_a_grasp: bool = False
    # with contact_a_grasp (observed contact) or a_side_arms (learned poses): at A's pre-approach the other arm (the
    # pusher) backs off from where its hand is, as the expert's does (5 cm back, 15 cm to its side, 5 cm up), out of
    # the lifted object's way
    contact_a_backoff: bool = False
    # with contact=observed: A's lift of an object whose seen overhang droops (a sheet) rises at least the
    # seen length + 8 cm, as the expert lifts a sheet (observed_contact.py)
    contact_a_sheet_lift: bool = False
    # with contact_from_hand: B's squeeze and lift keep the hand's orientation (translations only), as the
    # expert's do; the learned turn while the hands clamp the object is dropped (observed_contact.py)
    contact_b_steady: bool = False
    # with contact=observed: B's touch turned about the vertical so the fingers lie along the seen object's
    # side, as the expert's lie along the object's side (observed_contact.py)
    contact_b_align: bool = False
    # with contact=observed: the pinching hand of A's and C's grasp closes fully and its lift keeps it
    # closed, as the expert's do (observed_contact.py)
    contact_grip_closed: bool = False
    # with contact=observed: A's slide goes the expert's whole slide_distance for the overhang the cloud still
    # misses, straight along +x, instead of the learned slide capped at it (observed_contact.py)
    contact_a_slide_full: bool = False
    # with contact=observed: A's push-pass touch comes straight down 2 cm behind the seen object's centre, the
    # expert's press point, instead of at the learned point (observed_contact.py)
    contact_a_touch: bool = False
    # with contact=observed: A's push passes are pushed by the arm on the seen object's side (right at y <= 0),
    # chosen once per attempt at its first touch, as the expert's pusher; the executor's arm where it chose
    # that one, else its most active arm's motion mirrored across the seen centre line (observed_contact.py)
    contact_a_pusher_side: bool = False
    # with contact=observed: B's touch shifted along its fingers so each hand faces the seen object's centre,
    # as the expert's two hands face each other across it (observed_contact.py)
    contact_b_centred: bool = False
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=identity_normalization)

    def __post_init__(self):
        super().__post_init__()
        if self.strategy not in STRATEGY_CHOICES:
            raise ValueError(f"--policy.strategy: must be one of {list(STRATEGY_CHOICES)}, got {self.strategy!r}")
        if self.contact not in CONTACT_CHOICES:
            raise ValueError(f"--policy.contact: must be one of {list(CONTACT_CHOICES)}, got {self.contact!r}")
        for flag in ("contact_from_hand", "contact_b_face", "contact_a_grasp", "contact_a_sheet_lift",
                     "contact_b_align", "contact_grip_closed", "contact_a_slide_full",
                     "contact_a_touch", "contact_a_pusher_side", "contact_b_centred"):
            if getattr(self, flag) and self.contact != "observed":
                raise ValueError(f"--policy.{flag}=true needs --policy.contact=observed, got {self.contact!r}")
        if not self.contact_strategies or not distinct_strategies(self.contact_strategies):
            raise ValueError(f"--policy.contact_strategies: distinct letters of {''.join(STRATEGY_CHOICES[1:])} "
                             f"(e.g. AC), got {self.contact_strategies!r}")
        if set(self.contact_strategies) != set(STRATEGY_CHOICES[1:]) and self.contact != "observed":
            raise ValueError(f"--policy.contact_strategies={self.contact_strategies} needs --policy.contact=observed, "
                             f"got {self.contact!r}")
        if not distinct_strategies(self.continue_from_hand):
            raise ValueError(f"--policy.continue_from_hand: distinct letters of {''.join(STRATEGY_CHOICES[1:])} "
                             f"(e.g. AC; empty: off), got {self.continue_from_hand!r}")
        if self.continue_from_hand and self.contact != "learned":
            raise ValueError(f"--policy.continue_from_hand={self.continue_from_hand} needs --policy.contact=learned "
                             f"(with observed, use --policy.contact_from_hand), got {self.contact!r}")
        if self.continue_press_repeat and "A" not in self.continue_from_hand:
            raise ValueError("--policy.continue_press_repeat=true needs A in --policy.continue_from_hand (e.g. AC)")
        if self.continue_c_heights not in C_HEIGHTS_CHOICES:
            raise ValueError(f"--policy.continue_c_heights: one of {list(C_HEIGHTS_CHOICES)}, got {self.continue_c_heights!r}")
        if self.continue_c_heights and "C" not in self.continue_from_hand:
            raise ValueError("--policy.continue_c_heights needs C in --policy.continue_from_hand (e.g. AC)")
        if self.continue_a_grasp_heights and "A" not in self.continue_from_hand:
            raise ValueError("--policy.continue_a_grasp_heights=true needs A in --policy.continue_from_hand (e.g. AC)")
        if self.carry_box_centre and not (self.clear_all or self.retry_failed):
            raise ValueError("--policy.carry_box_centre=true acts on the carry-off after a lift: it needs "
                             "--policy.clear_all=true or --policy.retry_failed=true")
        if self.carry_squeeze is not None and not 0.0 <= self.carry_squeeze <= B_SQUEEZE:
            raise ValueError(f"--policy.carry_squeeze: 0 to {B_SQUEEZE} m (B's own squeeze past the faces it touched), "
                             f"got {self.carry_squeeze}")
        if self.carry_squeeze is not None and not (self.clear_all or self.retry_failed):
            raise ValueError("--policy.carry_squeeze acts on the carry-off after a lift: it needs "
                             "--policy.clear_all=true or --policy.retry_failed=true")
        if self.hold_still is not None and not (0.0 < self.hold_still <= 0.05 and self.clear_all):
            raise ValueError(f"--policy.hold_still: metres in (0, 0.05], with --policy.clear_all=true (it delays the "
                             f"carry-off), got {self.hold_still} (clear_all={self.clear_all})")
        if not 0.0 <= self.hold_still_max_s <= 10.0:
            raise ValueError(f"--policy.hold_still_max_s: seconds in [0, 10], got {self.hold_still_max_s!r}")
        if self.a_side_arms and self.contact != "learned":
            raise ValueError("--policy.a_side_arms=true is for --policy.contact=learned (with observed, use "
                             f"--policy.contact_a_pusher_side and --policy.contact_a_grasp), got {self.contact!r}")
        if self.continue_a_preapproach_line and "A" not in self.continue_from_hand:
            raise ValueError("--policy.continue_a_preapproach_line=true needs A in --policy.continue_from_hand (e.g. AC)")
        if self.continue_a_sheet_lift and "A" not in self.continue_from_hand:
            raise ValueError("--policy.continue_a_sheet_lift=true needs A in --policy.continue_from_hand (e.g. AC)")
        if self.continue_c_squeeze_end and "C" not in self.continue_from_hand:
            raise ValueError("--policy.continue_c_squeeze_end=true needs C in --policy.continue_from_hand (e.g. AC)")
        if self.continue_press_stalled and "A" not in self.continue_from_hand:
            raise ValueError("--policy.continue_press_stalled needs A in --policy.continue_from_hand (e.g. AC)")
        if not 0.0 <= float(self.continue_press_stalled) <= 0.02:
            raise ValueError(f"--policy.continue_press_stalled: must be in [0, 0.02] m, got {self.continue_press_stalled!r}")
        if self.continue_press_floor and "A" not in self.continue_from_hand:
            raise ValueError("--policy.continue_press_floor needs A in --policy.continue_from_hand (e.g. AC)")
        if not 0.0 <= float(self.continue_press_floor) <= 0.02:
            raise ValueError(f"--policy.continue_press_floor: must be in [0, 0.02] m, got {self.continue_press_floor!r}")
        if self.continue_slide_cap and "A" not in self.continue_from_hand:
            raise ValueError("--policy.continue_slide_cap=true needs A in --policy.continue_from_hand (e.g. AC)")
        continued = self.continue_level_slide or self.continue_press_deeper or self.continue_level_squeeze
        if continued and not self.continue_from_hand:
            raise ValueError("--policy.continue_level_slide / --policy.continue_press_deeper / "
                             "--policy.continue_level_squeeze need "
                             "--policy.continue_from_hand (the stages they change start at the hand)")
        if not 0.0 <= self.continue_press_deeper <= 0.02:
            raise ValueError(f"--policy.continue_press_deeper: metres in [0, 0.02], got {self.continue_press_deeper}")
        if self.contact_a_backoff and not (self.contact_a_grasp or self.a_side_arms):
            raise ValueError("--policy.contact_a_backoff=true needs --policy.contact_a_grasp=true or "
                             "--policy.a_side_arms=true (the arms by the seen side)")
        if self.retry_next_strategy and not self.clear_all:
            raise ValueError("--policy.retry_next_strategy=true needs --policy.clear_all=true (desk retries)")
        if self.retry_track and not self.retry_next_strategy:
            raise ValueError("--policy.retry_track=true needs --policy.retry_next_strategy=true (what it tracks for)")
        if self.retry_rank not in ("current", "first_sight"):
            raise ValueError(f"--policy.retry_rank: one of current, first_sight, got {self.retry_rank!r}")
        if not 1 <= int(self.retry_switch_after) <= 10:
            raise ValueError(f"--policy.retry_switch_after: must be in [1, 10], got {self.retry_switch_after!r}")
        if self.quick_retry and not self.clear_all:
            raise ValueError("--policy.quick_retry=true needs --policy.clear_all=true (desk retries)")
        if set(self.retry_on_response) - set("AC"):
            raise ValueError(f"--policy.retry_on_response: letters of A, C (or empty), got {self.retry_on_response!r}")
        if not 0.0 <= self.retry_on_fold_lost <= 0.2:
            raise ValueError(
                f"--policy.retry_on_fold_lost: a height in [0, 0.2] m (0: off), got {self.retry_on_fold_lost!r}")
        for name in ("retry_on_response", "retry_on_fold_lost"):  # both end an attempt in a retry
            if getattr(self, name) and not (self.retry_failed or self.retry_next_strategy):
                raise ValueError(f"--policy.{name} needs --policy.retry_failed=true or, with clear_all, "
                                 "--policy.retry_next_strategy=true (the retry it ends in)")
        if not 0.0 <= float(self.b_min_width) <= 0.3:
            raise ValueError(f"--policy.b_min_width: a width in [0, 0.3] m (0: off), got {self.b_min_width!r}")
        if self.first_attempt not in ("", "A", "B", "C"):
            raise ValueError(f"--policy.first_attempt: one of A, B, C or empty, got {self.first_attempt!r}")
        if self.retry_failed and self.clear_all:
            raise ValueError("--policy.retry_failed=true is for one object per episode; with --policy.clear_all=true "
                             "use its own retries (--policy.quick_retry, --policy.retry_next_strategy)")
        if self.contact_b_steady and not self.contact_from_hand:
            raise ValueError("--policy.contact_b_steady=true needs --policy.contact_from_hand=true (hand orientation)")
        if not 0 <= int(self.generator_tta) <= 64:
            raise ValueError(f"--policy.generator_tta: must be in [0, 64] (0: the generator's own), got {self.generator_tta}")
        if self.generator_tta:
            self.generator.check_tta(self.generator_tta, "--policy.generator_tta")
        if not 0 <= int(self.executor_tta) <= 64:
            raise ValueError(f"--policy.executor_tta: must be in [0, 64] (0: the executor's own), got {self.executor_tta}")
        if not 1 <= int(self.max_push_passes) <= A_PASSES:
            raise ValueError(f"--policy.max_push_passes: must be in [1, {A_PASSES}], got {self.max_push_passes!r}")
        if self.generator_cloud_points < 0:
            raise ValueError(f"--policy.generator_cloud_points: must be >= 0, got {self.generator_cloud_points!r}")
        if not 0.0 < self.active_threshold < 1.0:
            raise ValueError(f"--policy.active_threshold: must be in (0, 1), got {self.active_threshold!r}")
        if not 0.0 <= self.settle_s <= 10.0:
            raise ValueError(f"--policy.settle_s: must be in [0, 10] s, got {self.settle_s!r}")
        if not 0.0 < self.control_dt <= 1.0:
            raise ValueError(f"--policy.control_dt: must be in (0, 1] s, got {self.control_dt!r}")
        check_alt_strategies(self.alt_executor_strategies, self.alt_executor is not None)
        if self.alt_executor_stages not in ALT_EXECUTOR_STAGES:
            raise ValueError(f"--policy.alt_executor_stages: one of {list(ALT_EXECUTOR_STAGES)}, got {self.alt_executor_stages!r}")
        if self.alt_executor_stages == "push" and "A" not in self.alt_executor_strategies:
            raise ValueError("--policy.alt_executor_stages=push: A's push passes, so A must be in "
                             f"--policy.alt_executor_strategies (got {self.alt_executor_strategies!r})")
        if self.alt_executor_members and self.alt_executor is None:
            raise ValueError("--policy.alt_executor_members: given without --policy.alt_executor (members average "
                             "with the executor they belong to)")
        for name, lead, members in (("executor_members", self.executor, self.executor_members),
                                    ("alt_executor_members", self.alt_executor, self.alt_executor_members)):  # fmt: skip
            for i, m in enumerate(members):
                why = executor_input_mismatch(lead, m)
                if why:
                    raise ValueError(f"--policy.{name}[{i}]: {why}; an ensemble's members must read the same inputs")
        if self.generator.input_key != GENERATOR_INPUT:
            raise ValueError(
                f"--policy.generator.input_key={self.generator.input_key!r}: the unified policy feeds the generator "
                f"the env's object cloud ({GENERATOR_INPUT!r}); ablations A-7 / A-8 cannot be used here"
            )

    @property
    def observation_delta_indices(self) -> None:
        return None

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamConfig:
        return AdamConfig(lr=0.0)

    def get_scheduler_preset(self) -> None:
        return None

    def validate_features(self) -> None:
        """Keep :data:`INPUTS` as the only input features (so ``observation.environment_state`` is no
        feature of the policy) and check their shapes and the joint action (16,)."""
        feats = self.input_features or {}
        if feats:
            missing = [k for k in INPUTS if k not in feats]
            if missing:
                raise ValueError(
                    f"flatlab_unified needs input features {missing} (have {sorted(feats)}); the env gives the clouds "
                    "with --env.obs_pointcloud=true"
                )
            self.input_features = {k: feats[k] for k in INPUTS}
            for key, dim in ((OBS_STATE, STATE_DIM), (OBS_CELL, CELL_DIM)):
                if tuple(self.input_features[key].shape) != (dim,):
                    raise ValueError(f"flatlab_unified: {key} has shape {tuple(self.input_features[key].shape)}, "
                                     f"expected ({dim},)")  # fmt: skip
            for key in (OBS_POINTCLOUD, OBS_OBJECT_POINTCLOUD):
                shape = tuple(self.input_features[key].shape)
                if len(shape) != 2 or shape[1] != 3:
                    raise ValueError(f"flatlab_unified: {key} has shape {shape}, expected (N, 3)")
        act = (self.output_features or {}).get(ACTION)
        if act is not None and tuple(act.shape) != (ACTION_DIM,):
            raise ValueError(
                f"flatlab_unified outputs joint targets ({ACTION_DIM},), the env wants {tuple(act.shape)}: "
                "use --env.action_mode=joint"
            )

    def fill_sub_features(self) -> None:
        """Give a sub-config without features (a policy made from scratch, not by ``flatlab
        unified-build``) the features it would have been trained on, sized like this policy's clouds."""
        cloud = self.input_features.get(OBS_POINTCLOUD)
        obj = self.input_features.get(OBS_OBJECT_POINTCLOUD)
        n = tuple(cloud.shape) if cloud is not None else (max(self.executor.n_points, 16), 3)
        k = tuple(obj.shape) if obj is not None else (256, 3)
        for ex in (self.executor, self.alt_executor, *self.executor_members, *self.alt_executor_members):
            if ex is None:
                continue
            if not ex.input_features:
                ex.input_features = {
                    OBS_POINTCLOUD: PolicyFeature(FeatureType.STATE, n),
                    OBS_PRIMITIVE: PolicyFeature(FeatureType.STATE, (PRIMITIVE_DIM,)),
                    OBS_TCP_STATE: PolicyFeature(FeatureType.STATE, (TCP_STATE_DIM,)),
                    OBS_OBJECT_CLOUD: PolicyFeature(FeatureType.STATE, k),
                }
            if not ex.output_features:
                ex.output_features = {ACTION: PolicyFeature(FeatureType.ACTION, (EXECUTOR_ACTION_DIM,))}
        if not self.generator.input_features:
            self.generator.input_features = {GENERATOR_INPUT: PolicyFeature(FeatureType.STATE, k)}
        if not self.generator.output_features:
            self.generator.output_features = {ACTION: PolicyFeature(FeatureType.ACTION, (3,))}

"""``flatlab primitive-set``: the action execution module's learning set (paper §3.3, App. B).

The paper's execution module maps the *scene point cloud* (PointNet++) to the start and end 6-D
gripper pose of each action primitive; its training set is "50 demonstrations per object, each
a scene point cloud and the corresponding 6-DoF gripper pose".  This module builds that set from
the scripted expert: for every object (default: the Train split) it runs ``--demos`` expert
demonstrations with a randomized placement and writes **one sample per executed primitive**.

A sample (one row of ``samples.parquet``, one entry of each ``.npy`` at ``sample_index``):

* ``scene_clouds.npy`` (M, N, 3) float32: world-frame cloud from the depth of ``--cameras``,
  cropped to the env's workspace box (``FlatLabEnv.workspace``), sampled to N points (without
  replacement; a random permutation repeated when fewer are seen).  Includes the arms.
* ``object_clouds.npy`` (M, K, 3) float32: the segmented object (rigid geoms / cloth flex), same
  cameras and crop; all zeros when the object is not seen (``object_points_seen == 0``).
* primitive name, ``primitive_index`` (the stage index in the strategy), strategy, object id,
  category, split, demo index and seed, placement, control step and sim time of the capture.
* per arm (``left_*`` / ``right_*``): ``active`` (the primitive commands this arm), commanded
  ``start_*`` and ``end_*`` TCP pose as ``pos`` (3, m), ``rot6d`` (6: the first two *columns*
  of the rotation matrix, Zhou et al. 2019: R[:,0] then R[:,1]), ``quat`` (4, wxyz, w >= 0) and
  ``rotmat`` (9, row-major 3x3); ``gripper_start`` / ``gripper_end`` (commanded width, m); and
  what the sim measured at the capture: ``tcp_pos``, ``tcp_quat``, ``gripper_measured``,
  ``contact`` (fingers touch the object).  An arm the primitive does not command keeps its
  commanded pose and width (start = end).  ``arms``: the commanded arms; ``moving_arms``: those
  whose commanded pose or width changes (transit to the start pose included).
* ``environment_state`` (14, privileged; names in ``sim.core.ENV_STATE_NAMES``) at the capture.
* ``demo_success`` / ``demo_failure_reason``: the demo's outcome.  Failed demos are kept;
  filter on ``demo_success`` to train on successful demonstrations only.

The poses are the *commanded* ones (what :class:`~flatlab_lerobot.primitives.PrimitiveRunner`
executes).  Under contact they differ from the measured TCP by design: a squeeze is commanded
2.5 cm into the box, so the following lift starts at that commanded pose, not where the blocked
hand is (see ``*_tcp_pos``).

When a sample is captured (``--capture``):

* ``decision`` (default): when the expert poses the primitive, i.e. before the joint-space
  transit to its start pose -- the state a learned executor sees when it must predict the
  primitive.  (Capturing after the transit would show the gripper already at the start pose
  in the cloud: a label leak.)
* ``start``: when the arm has reached the start pose, right before the Cartesian motion.

Files under ``--out`` (default ``outputs/learning/primitive_set``): ``scene_clouds.npy``,
``object_clouds.npy``, ``samples.parquet`` and ``meta.json`` (settings, seed, counts, column
descriptions, per-demo records with wall time).  ``meta.json`` is written last: its presence
marks a complete set.  Work is sharded per object: ``shards/<object_id>/`` is written under a
temporary name and renamed when all its demos are done, so a re-run skips finished objects
and then merges all shards again (in the requested object order, so the merged set does not
depend on ``--workers``).  A shard made with other settings is an error (``--overwrite``).

Determinism: demo ``k`` of object ``o`` uses the seed ``SeedSequence([seed, crc32(o), k])``
for its placement (``tasks.ResetDistribution``) and its cloud sampling, in a fresh env and
expert, so a sample depends only on (settings, object, k).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import shutil
import sys
import time
import zlib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from flatlab_lerobot.atomic import replacing, write_json
from flatlab_lerobot.learning import int_at_least
from flatlab_lerobot.paths import OUTPUTS_DIR
from flatlab_lerobot.tasks import DEFAULT_PLANAR, DEFAULT_YAW_DEG

ARM_NAMES = ("left", "right")  # = sim.robot.ARMS (not imported here: keeps `--help` light)
CAPTURE_MODES = ("decision", "start")
CAMERA_NAMES = ("front", "top", "left", "right")
FILES = ("scene_clouds.npy", "object_clouds.npy", "samples.parquet")
META = "meta.json"
SHARDS = "shards"
FORMAT = "flatlab_primitive_set"
VERSION = 1
DONE_GRACE_S = 2.0  # after the expert's last primitive, wait this long for the 2-s hold rule
STRATEGY_COST = {"C": 0, "A": 1, "B": 2}  # shard scheduling order: slowest (cloth) first


class PrimitiveSetError(ValueError):
    """Bad settings or an incompatible existing output; the message names the field / file."""


# ------------------------------------------------------------------------------ settings
@dataclass(frozen=True)
class PrimitiveSetConfig:
    """Settings of one primitive set.

    objects: catalog ids (resolved from ``--objects``).  demos: demonstrations per object
    (paper: 50).  seed: base seed (see module doc).  n_points / n_object_points: fixed cloud
    sizes.  cameras: views fused into the clouds.  image_size: depth image side (px) per camera.
    capture: ``decision`` | ``start`` (module doc).  strategy: ``auto`` (catalog label) or A/B/C
    for every object.  max_steps: control steps per demo at most.  xy_range / yaw_range_deg:
    placement randomization (±m, ±deg).  control_dt: control period (s).
    """

    objects: tuple[str, ...]
    demos: int = 5
    seed: int = 0
    n_points: int = 4096
    n_object_points: int = 1024
    cameras: tuple[str, ...] = CAMERA_NAMES
    image_size: int = 128
    capture: str = "decision"
    strategy: str = "auto"
    max_steps: int = 600
    xy_range: float = DEFAULT_PLANAR
    yaw_range_deg: float = DEFAULT_YAW_DEG
    control_dt: float = 0.1

    def __post_init__(self):
        def bad(field, msg):
            raise PrimitiveSetError(f"primitive-set settings: field '{field}': {msg}")

        if not self.objects:
            bad("objects", "no objects selected")
        for name, lo in (("demos", 1), ("n_points", 1), ("n_object_points", 1), ("image_size", 16), ("max_steps", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                bad(name, f"must be an integer >= {lo}, got {v!r}")
        if self.capture not in CAPTURE_MODES:
            bad("capture", f"must be one of {CAPTURE_MODES}, got {self.capture!r}")
        if self.strategy not in ("auto", "A", "B", "C"):
            bad("strategy", f"must be auto, A, B or C, got {self.strategy!r}")
        unknown = [c for c in self.cameras if c not in CAMERA_NAMES]
        if not self.cameras or unknown:
            bad("cameras", f"must be a non-empty subset of {CAMERA_NAMES}, got {list(self.cameras)}")
        if not (0 <= self.xy_range <= 0.2) or not (0 <= self.yaw_range_deg <= 180) or not (0 < self.control_dt <= 1):
            bad("xy_range/yaw_range_deg/control_dt", "out of range (0-0.2 m, 0-180 deg, 0-1 s)")

    def shard_settings(self) -> dict:
        """Everything that determines a shard's content (all but the object list)."""
        d = dataclasses.asdict(self)
        d.pop("objects")
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    def fingerprint(self) -> str:
        return hashlib.sha256(json.dumps(self.shard_settings(), sort_keys=True).encode()).hexdigest()[:16]


def demo_seed(seed: int, object_id: str, demo_index: int) -> int:
    """The seed of demo ``demo_index`` of ``object_id``: independent of the other objects."""
    ss = np.random.SeedSequence([int(seed), zlib.crc32(object_id.encode()), int(demo_index)])
    return int(ss.generate_state(1, np.uint32)[0])


def resolve_objects(spec: str) -> tuple[str, ...]:
    """``ref_box,box_gift`` / ``split:train`` / a mix -> catalog ids (order kept, no duplicates)."""
    from flatlab_lerobot.catalog import SPLITS, load_objects

    catalog = load_objects()
    out: list[str] = []
    for item in (s.strip() for s in spec.split(",")):
        if not item:
            continue
        if item.startswith("split:"):
            split = item.split(":", 1)[1]
            if split not in SPLITS:
                raise PrimitiveSetError(f"--objects: unknown split {split!r} in {item!r}; known: {list(SPLITS)}")
            out += sorted(o.id for o in catalog.values() if o.split == split)
        elif item not in catalog:
            raise PrimitiveSetError(f"--objects: unknown object id {item!r} (see envs/objects/*.yaml)")
        else:
            out.append(item)
    if not out:
        raise PrimitiveSetError(f"--objects: {spec!r} selects no objects")
    return tuple(dict.fromkeys(out))


# ------------------------------------------------------------------------------ one demo
def _quat(R: np.ndarray) -> np.ndarray:
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(R, float).reshape(-1))
    return -q if q[0] < 0 else q  # canonical hemisphere (w >= 0)


def _pose_fields(prefix: str, pos, R) -> dict:
    R = np.asarray(R, float).reshape(3, 3)
    return {
        f"{prefix}_pos": np.asarray(pos, np.float32),
        f"{prefix}_rot6d": R[:, :2].T.reshape(6).astype(np.float32),
        f"{prefix}_quat": _quat(R).astype(np.float32),
        f"{prefix}_rotmat": R.reshape(9).astype(np.float32),
    }


def _pose_changed(a, b) -> bool:
    return bool(np.linalg.norm(a[0] - b[0]) > 1e-3 or np.linalg.norm(a[1] - b[1]) > 1e-2)


class _PrimitiveTap:
    """Sees every primitive the expert executes, without touching the strategies package: the
    expert's runner is wrapped (this instance only).  The runner's action stream is pure
    kinematics of the commanded joints, so it is expanded eagerly; this tells how many of its
    steps are the joint-space transit (a ``move`` primitive cannot be told from its transit by
    the stage name)."""

    def __init__(self, expert):
        self.expert = expert
        self.runner = expert.runner
        self._orig = expert.runner.actions
        expert.runner.actions = self._actions
        self.started: list[dict] = []  # one entry per primitive, in stage order
        self.finished = 0

    def _actions(self, prim, q_now, grip_now):
        current = {a: (p.copy(), R.copy()) for a, (p, R) in self.expert.fk(q_now).items()}
        acts = list(self._orig(prim, q_now, grip_now))
        n_prim = max(1, round(prim.duration / self.runner.dt))  # = PrimitiveRunner.actions
        n_transit = len(acts) - n_prim
        if (
            n_transit < 0
            or (prim.name != "move" and any(n == "move" for n, _ in acts[n_transit:]))
            or any(n != "move" for n, _ in acts[:n_transit])
        ):
            raise RuntimeError("PrimitiveRunner.actions changed: cannot locate the primitive's start")
        self.started.append(
            {"prim": prim, "current": current, "grip": dict(grip_now), "n_transit": n_transit, "n_steps": len(acts)}
        )
        yield from acts
        self.finished += 1


@dataclass
class DemoResult:
    object_id: str
    demo_index: int
    seed: int
    strategy: str
    success: bool
    failure_reason: str
    samples: list[dict]
    scene_clouds: np.ndarray  # (k, N, 3) float32
    object_clouds: np.ndarray  # (k, K, 3) float32
    steps: int
    sim_time_s: float
    wall_time_s: float
    placement: tuple[float, float, float]
    workspace: dict | None = None  # the env's crop box {"lo": [3], "hi": [3]}
    cpu_time_s: float = 0.0  # CPU time of this process (all its threads) for the demo

    def record(self) -> dict:
        return {
            "object_id": self.object_id,
            "demo_index": self.demo_index,
            "seed": self.seed,
            "strategy": self.strategy,
            "success": self.success,
            "failure_reason": self.failure_reason,
            "samples": len(self.samples),
            "steps": self.steps,
            "sim_time_s": round(self.sim_time_s, 3),
            "wall_time_s": round(self.wall_time_s, 3),
            "cpu_time_s": round(self.cpu_time_s, 3),
            "placement": {"x": self.placement[0], "y": self.placement[1], "yaw_rad": self.placement[2]},
        }


def make_env(cfg: PrimitiveSetConfig, object_id: str):
    from flatlab_lerobot.env import FlatLabEnv

    # Clouds are taken only at the captures (not every step), so the env observes no pixels/clouds.
    return FlatLabEnv(
        object_id=object_id,
        cameras=cfg.cameras,
        pointcloud_cameras=cfg.cameras,
        image_size=cfg.image_size,
        n_points=cfg.n_points,
        n_object_points=cfg.n_object_points,
        xy_range=cfg.xy_range,
        yaw_range_deg=cfg.yaw_range_deg,
        episode_length=cfg.max_steps,
        control_dt=cfg.control_dt,
        render_size=cfg.image_size,
        render_camera=cfg.cameras[0],
        obs_pixels=False,
        obs_pointcloud=False,
    )


def _clouds(env, cfg: PrimitiveSetConfig, rng: np.random.Generator):
    from flatlab_lerobot.sim.cameras import crop, sample

    sim, rig = env.sim, env.rig
    rig.invalidate()
    pts = crop(rig.scene_points(sim.data, cfg.cameras), *env.workspace)
    opts = crop(rig.object_points(sim.data, sim.obj_geoms, sim.flex_id, cfg.cameras), *env.workspace)
    return sample(pts, cfg.n_points, rng), sample(opts, cfg.n_object_points, rng), len(pts), len(opts)


def run_demo(cfg: PrimitiveSetConfig, object_id: str, demo_index: int, on_step=None) -> DemoResult:
    """Run demo ``demo_index`` of ``object_id`` and return its primitive samples.

    ``on_step(env, stage, primitive_index, action)`` is called before every control step (tests).
    Never raises for a failed demo: divergence, expert errors and timeouts end it with
    ``success=False`` and a reason; the samples taken so far are kept."""
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.rollout import ExpertPolicy, rollout
    from flatlab_lerobot.sim.core import FailureReason
    from flatlab_lerobot.strategies import STRATEGIES

    t0, c0 = time.perf_counter(), time.process_time()
    spec = get_object(object_id)
    strategy = spec.strategy if cfg.strategy == "auto" else cfg.strategy
    seed = demo_seed(cfg.seed, object_id, demo_index)
    rng = np.random.default_rng(seed)
    samples: list[dict] = []
    scene, objc = [], []
    n_stages = len(STRATEGIES[strategy])
    try:
        env = make_env(cfg, object_id)
    except Exception as exc:  # noqa: BLE001 -- keep the demo, label it
        reason = FailureReason.ERROR.text(f"{type(exc).__name__}: {exc}")
        n, m = cfg.n_points, cfg.n_object_points
        return DemoResult(object_id, demo_index, seed, strategy, False, reason, [], np.zeros((0, n, 3), np.float32),
                          np.zeros((0, m, 3), np.float32), 0, 0.0, time.perf_counter() - t0, (0.0, 0.0, 0.0), None,
                          time.process_time() - c0)  # fmt: skip
    policy = ExpertPolicy(strategy, env.cell, cfg.control_dt)
    tap = _PrimitiveTap(policy.expert)
    grace = round(DONE_GRACE_S / cfg.control_dt)
    state = {"prev": -1, "k": 0, "done_at": None}

    def capture(st) -> None:  # before the step: the scene as the primitive's start sees it
        index = st.primitive
        if index != state["prev"]:
            state["prev"], state["k"] = index, 0
        else:
            state["k"] += 1
        k = state["k"]
        entry = tap.started[index] if index < len(tap.started) else None
        if entry is not None and k == (0 if cfg.capture == "decision" else entry["n_transit"]) and k < entry["n_steps"]:
            sc, oc, n_seen, n_obj_seen = _clouds(st.env, cfg, rng)
            scene.append(sc)
            objc.append(oc)
            samples.append(_sample(st.env, spec, strategy, demo_index, seed, st.env.placement, index, entry, st.index,
                                   n_seen, n_obj_seen))  # fmt: skip
        if on_step is not None:
            on_step(st.env, st.stage, index, st.action)

    def expert_done(st) -> bool:  # the expert is done; it only holds from now on
        if tap.finished < n_stages:
            return False
        steps = st.index + 1
        state["done_at"] = steps if state["done_at"] is None else state["done_at"]
        return steps - state["done_at"] >= grace

    ep = rollout(env, policy, seed=seed, max_steps=cfg.max_steps, before_step=capture, stop=expert_done,
                 catch_errors=True)  # fmt: skip
    success, reason, steps = ep.success, ep.failure_reason, ep.steps
    placement = ep.placement
    workspace = {"lo": env.workspace[0].tolist(), "hi": env.workspace[1].tolist()}
    sim_time = ep.sim_time_s
    env.close()
    for s in samples:
        s["demo_success"] = success
        s["demo_failure_reason"] = reason
        s["demo_steps"] = steps
    n, m = cfg.n_points, cfg.n_object_points
    return DemoResult(
        object_id, demo_index, seed, strategy, success, reason, samples,
        np.stack(scene) if scene else np.zeros((0, n, 3), np.float32),
        np.stack(objc) if objc else np.zeros((0, m, 3), np.float32),
        steps, sim_time, time.perf_counter() - t0, placement, workspace, time.process_time() - c0,
    )  # fmt: skip


def _sample(env, spec, strategy, demo_index, seed, placement, index, entry, step, n_seen, n_obj_seen) -> dict:
    from flatlab_lerobot.tasks import touches

    prim, sim = entry["prim"], env.sim
    agent_pos = sim.joint_positions()
    row = {
        "object_id": spec.id,
        "category": spec.category,
        "split": spec.split,
        "strategy": strategy,
        "demo_index": demo_index,
        "demo_seed": seed,
        "placement_x": placement[0],
        "placement_y": placement[1],
        "placement_yaw": placement[2],
        "primitive_index": index,
        "primitive": prim.name,
        "step": step,
        "sim_time": float(sim.data.time),
        "duration_s": float(prim.duration),
        "transit_s": float(entry["n_transit"] * env.control_dt),
        "arms": ",".join(a for a in ARM_NAMES if a in prim.motions),
    }
    moving = []
    for i, arm in enumerate(ARM_NAMES):
        cur, g = entry["current"][arm], entry["grip"][arm]
        motion = prim.motions.get(arm)
        start, end, grip = (motion.start, motion.end, motion.gripper) if motion is not None else (cur, cur, (g, g))
        if motion is not None and (
            _pose_changed(cur, start)
            or _pose_changed(start, end)
            or abs(grip[0] - g) > 1e-3
            or abs(grip[1] - grip[0]) > 1e-3
        ):
            moving.append(arm)
        tcp = sim.tcp_pose(arm)
        row[f"{arm}_active"] = motion is not None
        row |= _pose_fields(f"{arm}_start", *start)
        row |= _pose_fields(f"{arm}_end", *end)
        row[f"{arm}_gripper_start"] = float(grip[0])
        row[f"{arm}_gripper_end"] = float(grip[1])
        row[f"{arm}_tcp_pos"] = tcp[0].astype(np.float32)
        row[f"{arm}_tcp_quat"] = _quat(tcp[1]).astype(np.float32)
        row[f"{arm}_gripper_measured"] = float(agent_pos[8 * i + 7])
        row[f"{arm}_contact"] = bool(touches(sim, arm))
    row["moving_arms"] = ",".join(moving)
    row["environment_state"] = sim.environment_state().astype(np.float32)
    row["scene_points_seen"] = int(n_seen)
    row["object_points_seen"] = int(n_obj_seen)
    return row


COLUMN_DOCS = {
    "sample_index": "row of scene_clouds.npy / object_clouds.npy",
    "object_id": "catalog id", "category": "catalog category", "split": "train | test_alpha | test_beta | reference",
    "strategy": "A | B | C (the expert's strategy)",
    "demo_index": "demonstration index per object", "demo_seed": "its seed (placement + cloud sampling)",
    "placement_x": "object placement offset (m)", "placement_y": "(m)", "placement_yaw": "(rad)",
    "primitive_index": "stage index in the strategy (strategies.STRATEGIES)", "primitive": "primitive name",
    "step": "control step of the capture", "sim_time": "sim time of the capture (s)",
    "duration_s": "commanded duration of the Cartesian motion (s)", "transit_s": "joint-space transit before it (s)",
    "arms": "arms the primitive commands", "moving_arms": "arms whose commanded pose or width changes",
    "{arm}_active": "the primitive commands this arm",
    "{arm}_start_pos / _end_pos": "commanded TCP position (3, m, world)",
    "{arm}_start_rot6d / _end_rot6d": "rotation: first two columns of R, (R[:,0], R[:,1]) (6)",
    "{arm}_start_quat / _end_quat": "rotation quaternion wxyz, w >= 0 (4)",
    "{arm}_start_rotmat / _end_rotmat": "rotation matrix, row-major (9)",
    "{arm}_gripper_start / _end": "commanded gripper width (m)",
    "{arm}_tcp_pos / _tcp_quat": "TCP pose measured in the sim at the capture",
    "{arm}_gripper_measured": "finger opening measured at the capture (m)",
    "{arm}_contact": "the arm's fingers touch the object at the capture",
    "environment_state": "privileged state (14), names in sim.core.ENV_STATE_NAMES",
    "scene_points_seen / object_points_seen": "points before sampling (0 object points: object cloud is zeros)",
    "demo_success": "the demo met the grasp success rule", "demo_failure_reason": "why not ('' on success)",
    "demo_steps": "control steps the demo ran",
}  # fmt: skip


# ------------------------------------------------------------------------------ shards
def _table(samples: list[dict]):
    """pyarrow table: scalars as scalar columns, vectors as fixed-size float32 lists."""
    import pyarrow as pa

    if not samples:
        return None
    cols = {}
    for key in samples[0]:
        vals = [s[key] for s in samples]
        if isinstance(vals[0], np.ndarray):
            flat = np.stack(vals).astype(np.float32)
            cols[key] = pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1)), flat.shape[1])
        else:
            cols[key] = pa.array(vals)
    return pa.table(cols)


def build_shard(cfg: PrimitiveSetConfig, object_id: str, shards_dir: Path, progress=None) -> dict:
    """All demos of one object into ``shards_dir/<object_id>/`` (written under a temporary name,
    renamed when complete).  ``progress(demo_record)`` after each demo.  Returns shard.json."""
    import pyarrow.parquet as pq

    final = shards_dir / object_id
    tmp = shards_dir / f".{object_id}.partial"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    results = []
    for k in range(cfg.demos):
        res = run_demo(cfg, object_id, k)
        results.append(res)
        if progress is not None:
            progress(res.record())
    samples = [s for r in results for s in r.samples]
    np.save(tmp / "scene_clouds.npy", np.concatenate([r.scene_clouds for r in results]))
    np.save(tmp / "object_clouds.npy", np.concatenate([r.object_clouds for r in results]))
    table = _table(samples)
    if table is not None:
        pq.write_table(table, tmp / "samples.parquet")
    meta = {
        "object_id": object_id,
        "fingerprint": cfg.fingerprint(),
        "settings": cfg.shard_settings(),
        "samples": len(samples),
        "workspace": next((r.workspace for r in results if r.workspace), None),
        "demos": [r.record() for r in results],
    }
    (tmp / "shard.json").write_text(json.dumps(meta, indent=1))
    shutil.rmtree(final, ignore_errors=True)
    os.replace(tmp, final)
    return meta


def _read_shard_meta(shards_dir: Path, object_id: str, cfg: PrimitiveSetConfig) -> dict | None:
    """shard.json of a finished shard made with the same settings; None if not there yet."""
    path = shards_dir / object_id / "shard.json"
    if not path.is_file():
        return None
    try:
        meta = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise PrimitiveSetError(f"{path}: unreadable ({exc}); delete that shard folder or use --overwrite") from exc
    if meta.get("fingerprint") != cfg.fingerprint():
        old, new = meta.get("settings", {}), cfg.shard_settings()
        diff = [f"{k}: {old.get(k)!r} there, {new[k]!r} now" for k in new if old.get(k) != new[k]]
        raise PrimitiveSetError(
            f"{path}: field 'settings' differs from this run ({'; '.join(diff) or 'unknown'}); "
            "use --overwrite or another --out"
        )
    return meta


# ------------------------------------------------------------------------------ workers
_QUEUE = None


def _worker_init(queue) -> None:
    global _QUEUE
    _QUEUE = queue  # (importing this module imported flatlab_lerobot, which selects EGL, first)


def _worker_shard(cfg: PrimitiveSetConfig, object_id: str, shards_dir: str) -> dict:
    return build_shard(cfg, object_id, Path(shards_dir), progress=_QUEUE.put)


def _run_shards(cfg, todo: list[str], shards_dir: Path, workers: int, bar, log) -> None:
    def done(rec):
        if bar is not None:
            bar.set_postfix_str(
                f"{rec['object_id']} #{rec['demo_index']} {'ok' if rec['success'] else 'failed'}", refresh=False
            )
            bar.update(1)

    if workers <= 1 or len(todo) <= 1:
        for obj in todo:
            build_shard(cfg, obj, shards_dir, progress=done)
        return
    import multiprocessing as mp
    import queue as queue_mod
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    ctx = mp.get_context("spawn")  # fresh interpreters: no inherited GL / MuJoCo state
    q = ctx.Queue()
    with ProcessPoolExecutor(min(workers, len(todo)), mp_context=ctx, initializer=_worker_init, initargs=(q,)) as ex:
        futures = {ex.submit(_worker_shard, cfg, obj, str(shards_dir)): obj for obj in todo}
        pending = set(futures)
        try:
            while pending:
                finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                while True:
                    try:
                        done(q.get_nowait())
                    except queue_mod.Empty:
                        break
                for f in finished:
                    f.result()  # re-raise a worker's error here, naming nothing half-written
        except BaseException:
            for f in pending:
                f.cancel()
            raise


# ------------------------------------------------------------------------------ merge
def _merge(cfg: PrimitiveSetConfig, out: Path, shards_dir: Path, metas: list[dict], extra: dict) -> dict:
    import pyarrow as pa
    import pyarrow.parquet as pq

    tables, n_total = [], 0
    for meta in metas:
        p = shards_dir / meta["object_id"] / "samples.parquet"
        if meta["samples"]:
            tables.append(pq.read_table(p))
        n_total += meta["samples"]
    (out / META).unlink(missing_ok=True)  # from here on the folder is incomplete until meta.json
    for name, width in (("scene_clouds.npy", cfg.n_points), ("object_clouds.npy", cfg.n_object_points)):
        with replacing(out / name) as tmp:
            arr = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=(n_total, width, 3))
            i = 0
            for meta in metas:
                if meta["samples"]:
                    part = np.load(shards_dir / meta["object_id"] / name, mmap_mode="r")
                    if part.shape != (meta["samples"], width, 3):
                        raise PrimitiveSetError(
                            f"{shards_dir / meta['object_id'] / name}: shape {part.shape} does not "
                            f"match shard.json ({meta['samples']} samples of {width} points)"
                        )
                    arr[i : i + len(part)] = part
                    i += len(part)
            arr.flush()
            del arr
    if tables:
        table = pa.concat_tables(tables)
        table = table.add_column(0, "sample_index", pa.array(np.arange(table.num_rows, dtype=np.int64)))
    else:
        table = pa.table({"sample_index": pa.array([], pa.int64())})
    with replacing(out / "samples.parquet") as tmp:
        pq.write_table(table, tmp)

    demos = [d for m in metas for d in m["demos"]]
    per_object = {
        m["object_id"]: {
            "demos": len(m["demos"]),
            "demos_success": sum(d["success"] for d in m["demos"]),
            "samples": m["samples"],
        }
        for m in metas
    }
    per_strategy: dict = {}
    for d in demos:
        s = per_strategy.setdefault(
            d["strategy"], {"demos": 0, "demos_success": 0, "samples": 0, "wall": 0.0, "cpu": 0.0}
        )
        s["demos"] += 1
        s["demos_success"] += int(d["success"])
        s["samples"] += d["samples"]
        s["wall"] += d["wall_time_s"]
        s["cpu"] += d.get("cpu_time_s", 0.0)
    for s in per_strategy.values():
        s["wall_s_per_demo"] = round(s.pop("wall") / max(1, s["demos"]), 3)
        s["cpu_s_per_demo"] = round(s.pop("cpu") / max(1, s["demos"]), 3)
    prim_names = table.column("primitive").to_pylist() if table.num_rows else []
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "settings": {**dataclasses.asdict(cfg), "objects": list(cfg.objects), "cameras": list(cfg.cameras)},
        "fingerprint": cfg.fingerprint(),
        "seed": cfg.seed,
        "counts": {
            "objects": len(metas),
            "demos": len(demos),
            "demos_success": sum(d["success"] for d in demos),
            "samples": n_total,
            "samples_from_successful_demos": int(sum(table.column("demo_success").to_pylist())) if n_total else 0,
            "per_primitive": dict(sorted(Counter(prim_names).items())),
            "per_strategy": per_strategy,
            "per_object": per_object,
        },
        "workspace": metas[0]["workspace"] if metas else None,
        "conventions": {
            "frame": "world (z up, table top at settings' table height); metres, radians",
            "rot6d": "first two columns of the rotation matrix: (R[0,0], R[1,0], R[2,0], R[0,1], R[1,1], R[2,1])",
            "quat": "w, x, y, z with w >= 0",
            "rotmat": "row-major 3x3",
            "poses": "commanded TCP poses of the primitive (PrimitiveRunner), not the measured ones (*_tcp_*)",
            "capture": {
                "decision": "when the expert poses the primitive (before the transit to its start pose)",
                "start": "when the arm reached the start pose (before the Cartesian motion)",
            }[cfg.capture],
            "object_clouds": "all zeros when the object is not seen (object_points_seen == 0)",
        },
        "files": {
            "scene_clouds.npy": f"({n_total}, {cfg.n_points}, 3) float32",
            "object_clouds.npy": f"({n_total}, {cfg.n_object_points}, 3) float32",
            "samples.parquet": f"{n_total} rows, one per primitive sample",
        },
        "columns": COLUMN_DOCS,
        "demos": demos,
        **extra,
    }
    write_json(out / META, meta)
    return meta


# ------------------------------------------------------------------------------ entry points
def build(
    cfg: PrimitiveSetConfig,
    out: Path,
    *,
    workers: int = 1,
    overwrite: bool = False,
    keep_shards: bool = True,
    progress: bool = True,
    log=print,
) -> dict:
    """Build (or resume) the primitive set in ``out``; returns the written meta.json content."""
    out = Path(out)
    shards_dir = out / SHARDS
    if overwrite:
        shutil.rmtree(shards_dir, ignore_errors=True)
        for name in (*FILES, META):
            (out / name).unlink(missing_ok=True)
    shards_dir.mkdir(parents=True, exist_ok=True)
    done = {o: m for o in cfg.objects if (m := _read_shard_meta(shards_dir, o, cfg)) is not None}
    todo = [o for o in cfg.objects if o not in done]
    if done:
        log(f"[primitive-set] {len(done)}/{len(cfg.objects)} object shards already done in {shards_dir}: skipped")
    if todo:
        from flatlab_lerobot.catalog import get_object

        def cost(o):
            return STRATEGY_COST.get(get_object(o).strategy if cfg.strategy == "auto" else cfg.strategy, 9)

        todo.sort(key=cost)  # slow (cloth) shards first: better load balance over the workers
    t0 = time.perf_counter()
    bar = None
    if progress and todo:
        from tqdm import tqdm

        bar = tqdm(total=len(todo) * cfg.demos, desc="primitive-set", unit="demo", dynamic_ncols=True)
    try:
        _run_shards(cfg, todo, shards_dir, workers, bar, log)
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t0
    metas = [_read_shard_meta(shards_dir, o, cfg) for o in cfg.objects]
    missing = [o for o, m in zip(cfg.objects, metas) if m is None]
    if missing:
        raise RuntimeError(f"shards missing after the run: {missing}")
    meta = _merge(
        cfg, out, shards_dir, metas, {"run": {"workers": workers, "wall_s": round(wall, 2), "shards_built": todo}}
    )
    if not keep_shards:
        shutil.rmtree(shards_dir, ignore_errors=True)
    c = meta["counts"]
    log(
        f"[primitive-set] {out}: {c['samples']} samples from {c['demos']} demos "
        f"({c['demos_success']} successful) of {c['objects']} objects; {wall:.1f} s"
    )
    return meta


def load(out: Path):
    """(samples DataFrame, scene_clouds, object_clouds) of a finished set (clouds memory-mapped)."""
    import pandas as pd

    out = Path(out)
    if not (out / META).is_file():
        raise PrimitiveSetError(f"{out / META}: missing; the set is incomplete (re-run flatlab primitive-set)")
    df = pd.read_parquet(out / "samples.parquet")
    return df, np.load(out / "scene_clouds.npy", mmap_mode="r"), np.load(out / "object_clouds.npy", mmap_mode="r")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="flatlab primitive-set",
        description="The action execution module's learning set: per expert demo, the scene cloud at each "
        "primitive with its start/end 6-D gripper poses (paper: 50 demos per Train object).",
    )
    ap.add_argument(
        "--objects", default="split:train", help="comma-separated ids and/or split:<name> (default: split:train)"
    )
    ap.add_argument(
        "--demos", type=int_at_least(1), default=5, help="demonstrations per object (paper: 50; default 5)"
    )
    ap.add_argument("--seed", type=int, default=0, help="base seed (placements and cloud sampling)")
    ap.add_argument("--points", type=int_at_least(1), default=4096, help="scene cloud size N (default 4096)")
    ap.add_argument("--object-points", type=int_at_least(1), default=1024, help="object cloud size (default 1024)")
    ap.add_argument("--cameras", default=",".join(CAMERA_NAMES), help="views fused into the clouds")
    ap.add_argument("--image-size", type=int_at_least(16), default=128, help="depth image side per camera (px)")
    ap.add_argument("--capture", choices=CAPTURE_MODES, default="decision",
                    help="decision: when the expert poses the primitive (default); start: at its start pose")  # fmt: skip
    ap.add_argument("--strategy", choices=("auto", "A", "B", "C"), default="auto", help="auto: the catalog label")
    ap.add_argument("--max-steps", type=int_at_least(1), default=600, help="control steps per demo at most")
    ap.add_argument("--xy-range", type=float, default=DEFAULT_PLANAR, help=f"placement offset ±m (default {DEFAULT_PLANAR})")
    ap.add_argument("--yaw-range", type=float, default=DEFAULT_YAW_DEG, help=f"placement yaw ±deg (default {DEFAULT_YAW_DEG:g})")
    ap.add_argument("--workers", type=int_at_least(1), default=1, help="processes (one object shard each at a time)")
    ap.add_argument("--out", type=Path, default=OUTPUTS_DIR / "learning" / "primitive_set")
    ap.add_argument("--overwrite", action="store_true", help="discard existing shards and outputs in --out")
    ap.add_argument("--clean-shards", action="store_true", help="delete shards/ after a successful merge")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    try:
        cfg = PrimitiveSetConfig(
            objects=resolve_objects(args.objects),
            demos=args.demos,
            seed=args.seed,
            n_points=args.points,
            n_object_points=args.object_points,
            cameras=tuple(c.strip() for c in args.cameras.split(",") if c.strip()),
            image_size=args.image_size,
            capture=args.capture,
            strategy=args.strategy,
            max_steps=args.max_steps,
            xy_range=args.xy_range,
            yaw_range_deg=args.yaw_range,
        )
        build(cfg, args.out, workers=args.workers, overwrite=args.overwrite, keep_shards=not args.clean_shards,
              progress=not args.no_progress)  # fmt: skip
    except PrimitiveSetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Collection throughput benchmark (a script that prints numbers, not a timed test).

``flatlab bench-collect --recipe datasets/bench_rigid.yaml --episodes 20 --workers 2``

1. **Collection**: the real ``flatlab collect`` of the recipe's first N episodes into a temporary
   folder, with W worker processes -> episodes/hour, seconds per phase, peak memory per process.
2. **Raw**: the RAW cost of the same episodes -- the expert actions stored in that dataset,
   replayed through bare ``mj_step`` (with the sim's per-substep control interpolation) plus one
   render pass per camera and step for RGB/depth (and one segmentation pass for point clouds),
   exactly the passes the recipe's observations need; no env, expert, frames or dataset.  Also W
   worker processes, so the ratio collection / raw is per core.  Building each episode's model is
   timed separately (``raw.build_s``) and is not part of the raw cost.
3. ``--profile``: one episode in this process, timed piece by piece: env build, physics,
   rendering, clouds, expert/IK, frame building, video encoding + stats, lerobot's save_episode,
   commit.

The JSON (``--json``, default ``outputs/bench/collect_speed_<recipe>.json``) also records the
load average before and after: the numbers are only comparable on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

TARGETS = {"rigid_episodes_per_hour": 1000, "cloth_episodes_per_hour": 300, "overhead_ratio": 1.3,
           "worker_peak_rss_mb": 2048}  # fmt: skip


# ---------------------------------------------------------------------------------- raw replay
def raw_episode(object_id: str, placement, actions, cameras, image_size: int, rgbd: bool, seg_cameras, control_dt):
    """Replay ``actions`` (T, 16) with bare mj_step + rendering; returns (build s, replay s, peak
    RSS MB, replay CPU s)."""
    import mujoco
    import numpy as np

    from flatlab_lerobot.bench.speed import _raw_render_pass
    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.sim.core import FlatLabSim
    from flatlab_lerobot.sim.robot import ARMS

    t0 = time.perf_counter()
    sim = FlatLabSim(get_object(object_id), control_dt=control_dt)
    sim.reset(*placement)
    m, d = sim.model, sim.data
    ids = np.concatenate([sim.arms[a].ctrl for a in ARMS])
    lo, hi = m.actuator_ctrlrange[ids, 0], m.actuator_ctrlrange[ids, 1]
    r = mujoco.Renderer(m, image_size, image_size)
    rgb = np.empty((image_size, image_size, 3), np.uint8)
    zbuf = np.empty((image_size, image_size), np.float32)
    n = sim.n_substeps
    t1, c1 = time.perf_counter(), time.process_time()
    start = np.array(d.ctrl[ids])
    for a in np.asarray(actions, float):
        a = np.clip(a, lo, hi)
        for k in range(1, n + 1):
            d.ctrl[ids] = start + (a - start) * (k / n)
            mujoco.mj_step(m, d)
        start = a
        if rgbd:
            for c in cameras:
                _raw_render_pass(r, d, c, False, rgb, zbuf)
        for c in seg_cameras:
            _raw_render_pass(r, d, c, True, rgb, zbuf)
    t2, c2 = time.perf_counter(), time.process_time()
    r.close()
    from flatlab_lerobot.collect.collector import peak_rss_mb

    return t1 - t0, t2 - t1, peak_rss_mb(), c2 - c1


def _raw_init() -> None:
    import flatlab_lerobot.sim.core  # noqa: F401 -- warm the imports before the clock starts


def raw_cost(recipe, root: Path, workers: int) -> dict:
    """Replay the episodes stored under ``root`` (actions from the parquet files, placement and
    object from meta/flatlab_episodes.jsonl) with ``workers`` processes."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    import numpy as np
    import pyarrow.parquet as pq

    from flatlab_lerobot.collect.store import EPISODES_JSONL

    cols = {"episode_index": [], "frame_index": [], "action": []}
    for f in sorted((root / "data").rglob("*.parquet")):
        t = pq.read_table(f, columns=list(cols))
        for k in cols:
            cols[k] += t.column(k).to_pylist()
    recs = [json.loads(x) for x in (root / EPISODES_JSONL).read_text().splitlines() if x.strip()]
    jobs = []
    for r in recs:
        ep = r["dataset_episode_index"]
        if ep is None:
            continue
        rows = sorted((fi, a) for e, fi, a in zip(cols["episode_index"], cols["frame_index"], cols["action"],
                                                   strict=True) if e == ep)  # fmt: skip
        actions = np.array([a for _, a in rows], np.float64)
        p = r["placement"]
        jobs.append((r["object_id"], (p["x"], p["y"], p["yaw_rad"]), actions))
    rgbd = recipe.has("rgb") or recipe.has("depth")
    pc = recipe.has("pointcloud") or recipe.has("object_pointcloud")
    seg_cams = tuple(recipe.pointcloud_cameras or recipe.cameras) if pc else ()
    args = [
        (o, pl, a, tuple(recipe.cameras), recipe.image_size, rgbd, seg_cams, recipe.control_dt) for o, pl, a in jobs
    ]
    if workers <= 1:
        t0 = time.perf_counter()
        out = [raw_episode(*a) for a in args]
        wall = time.perf_counter() - t0
    else:
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_raw_init) as ex:
            list(ex.map(time.sleep, [0.2] * workers))  # start (and warm) every worker first
            t0 = time.perf_counter()
            out = list(ex.map(raw_episode, *zip(*args, strict=True)))
            wall = time.perf_counter() - t0
    steps = sum(len(a) for _, _, a in jobs)
    replay = sum(x[1] for x in out)
    return {
        "episodes": len(jobs),
        "steps": steps,
        "wall_s": round(wall, 2),
        "episodes_per_hour": round(3600 * len(jobs) / wall, 1) if wall > 0 else None,
        "build_s": round(sum(x[0] for x in out), 2),
        "replay_s": round(replay, 2),
        "ms_per_step": round(1000 * replay / max(1, steps), 2),
        "cpu_s_per_episode": round(sum(x[3] for x in out) / max(1, len(jobs)), 3),
        # share of `workers` cores the replay got (< 1: other processes competed for them)
        "cpu_share": round(sum(x[3] for x in out) / (wall * min(workers, os.cpu_count() or 1)), 2)
        if wall > 0
        else None,
        "peak_rss_mb": round(max(x[2] for x in out), 1) if out else None,
    }


# ---------------------------------------------------------------------------------- profile
# (label, module, attribute path): inclusive wall seconds of these calls during one episode.  Timed
# by temporary wrappers, not cProfile: CPython 3.12.1's cProfile drops the callers of some C calls.
PROFILE_PIECES = (
    ("env build (make_env)", "flatlab_lerobot.collect.runner", "make_env"),
    ("env reset (incl. settling, first render)", "flatlab_lerobot.env", "FlatLabEnv.reset"),
    ("env step (physics + observation)", "flatlab_lerobot.env", "FlatLabEnv.step"),
    ("  physics (FlatLabSim.step)", "flatlab_lerobot.sim.core", "FlatLabSim.step"),
    ("  observation (FlatLabEnv._observe)", "flatlab_lerobot.env", "FlatLabEnv._observe"),
    ("    render passes (CameraRig._render)", "flatlab_lerobot.sim.cameras", "CameraRig._render"),
    ("    clouds (CameraRig.depth_to_points)", "flatlab_lerobot.sim.cameras", "CameraRig.depth_to_points"),
    ("IK (DualArmIK.solve)", "flatlab_lerobot.sim.robot", "DualArmIK.solve"),
    ("frame building (runner._frame)", "flatlab_lerobot.collect.runner", "_frame"),
    ("video encoding (video.encode_stream)", "flatlab_lerobot.collect.video", "encode_stream"),
    ("video stats (video.image_stats)", "flatlab_lerobot.collect.video", "image_stats"),
    ("dataset open (DatasetStore.begin)", "flatlab_lerobot.collect.store", "DatasetStore.begin"),
    ("add_frame + save_episode (DatasetStore.add)", "flatlab_lerobot.collect.store", "DatasetStore.add"),
    ("  lerobot save_episode", "lerobot.datasets.lerobot_dataset", "LeRobotDataset.save_episode"),
    ("commit (finalize, meta, fsync, swap)", "flatlab_lerobot.collect.store", "DatasetStore.commit"),
)


def profile_episode(recipe, episode_index: int = 0) -> dict:
    """Time split of one episode simulated, encoded and written (its own commit) in this process."""
    import functools
    import importlib

    from flatlab_lerobot.collect.collector import _quiet_ffmpeg
    from flatlab_lerobot.collect.runner import run_episode
    from flatlab_lerobot.collect.features import camera_meta
    from flatlab_lerobot.collect.store import DatasetStore
    from flatlab_lerobot.collect.video import encode_videos

    _quiet_ffmpeg()
    acc = {label: [0.0, 0.0] for label, _, _ in PROFILE_PIECES}  # wall, CPU
    patched = []

    def timed(label, fn):
        @functools.wraps(fn)
        def wrapper(*a, **k):
            t, c = time.perf_counter(), time.process_time()
            try:
                return fn(*a, **k)
            finally:
                acc[label][0] += time.perf_counter() - t
                acc[label][1] += time.process_time() - c

        return wrapper

    tmp = Path(tempfile.mkdtemp(prefix="flatlab_profile_"))
    try:
        store = DatasetStore(recipe, tmp)
        store.recover()
        store.begin()  # the first open imports lerobot/torch, once per run: not timed
        store.abort()
        store.camera_meta = camera_meta(recipe)  # computed once per run, too
        run_episode(recipe, episode_index)  # warm imports and caches
        for label, mod, attr in PROFILE_PIECES:
            owner = importlib.import_module(mod)
            *path, name = attr.split(".")
            for part in path:
                owner = getattr(owner, part)
            orig = owner.__dict__[name]
            patched.append((owner, name, orig))
            setattr(owner, name, timed(label, orig))
        clk = [(time.perf_counter(), time.process_time())]
        res = run_episode(recipe, episode_index)
        clk.append((time.perf_counter(), time.process_time()))
        encode_videos(res, recipe, store.work)
        clk.append((time.perf_counter(), time.process_time()))
        store.begin()
        store.add(res)
        store.commit()
        clk.append((time.perf_counter(), time.process_time()))
    finally:
        for owner, name, orig in reversed(patched):
            setattr(owner, name, orig)
        shutil.rmtree(tmp, ignore_errors=True)
    split = {"episode (run_episode)": [clk[1][0] - clk[0][0], clk[1][1] - clk[0][1]], **acc}
    split["encode videos + stats (worker)"] = [clk[2][0] - clk[1][0], clk[2][1] - clk[1][1]]
    split["write (writer process)"] = [clk[3][0] - clk[2][0], clk[3][1] - clk[2][1]]
    return {"episode_index": episode_index, "frames": len(res.frames), "total_s": round(clk[3][0] - clk[0][0], 3),
            "total_cpu_s": round(clk[3][1] - clk[0][1], 3),
            "seconds": {k: round(v[0], 3) for k, v in split.items()},
            "cpu_seconds": {k: round(v[1], 3) for k, v in split.items()},
            "note": "inclusive seconds; indented pieces are parts of the line above"}  # fmt: skip


# ---------------------------------------------------------------------------------- main
class LoadSampler:
    """Mean of the 1-minute load average, sampled every 2 s while the ``with`` block runs."""

    def __init__(self, period: float = 2.0):
        import threading

        self.period, self.samples, self._stop = period, [os.getloadavg()[0]], threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.wait(self.period):
            self.samples.append(os.getloadavg()[0])

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.samples.append(os.getloadavg()[0])

    @property
    def mean(self) -> float:
        return round(sum(self.samples) / len(self.samples), 2)


def _dir_mb(root: Path) -> float:
    return sum(f.stat().st_size for f in root.rglob("*") if f.is_file()) / 1e6


def run(recipe, episodes: int, workers: int, raw: bool = True, profile: bool = False, keep: Path | None = None,
        log=print) -> dict:  # fmt: skip
    import dataclasses

    from flatlab_lerobot.catalog import get_object
    from flatlab_lerobot.collect.collector import collect

    recipe = dataclasses.replace(recipe, episodes=episodes, workers=workers)
    out = {
        "recipe": recipe.source,
        "name": recipe.name,
        "episodes": episodes,
        "workers": workers,
        "cpu_count": os.cpu_count(),
        "cameras": list(recipe.cameras),
        "image_size": recipe.image_size,
        "modalities": list(recipe.modalities),
        "fps": recipe.fps,
        "max_steps": recipe.max_steps,
        "video": dataclasses.asdict(recipe.video),
        "deformable": any(get_object(o).deformable for o in recipe.objects),
        "loadavg_before": [round(x, 2) for x in os.getloadavg()],
    }
    parent = Path(tempfile.mkdtemp(prefix="flatlab_bench_collect_")) if keep is None else Path(keep)
    cores = min(workers, os.cpu_count() or 1)
    try:
        t0 = time.perf_counter()
        import lerobot.datasets.lerobot_dataset  # noqa: F401 -- once per process (torch): not per episode

        out["startup_import_s"] = round(time.perf_counter() - t0, 2)
        log(f"[bench-collect] collecting {episodes} episodes of {recipe.name} with {workers} worker(s) ...")
        with LoadSampler() as load:
            s = collect(recipe, parent, overwrite=True, progress=False, log=lambda *_: None)
        root = Path(s["root"])
        rss = s["worker_peak_rss_mb"]
        w = s["writer_s"]
        cpu_ep = (s["worker_s"].get("cpu", 0.0) + w["begin_cpu_s"] + w["save_cpu_s"] + w["commit_cpu_s"]) / episodes
        out["collection"] = {
            "wall_s": s["wall_s"],
            "episodes_per_hour": s["episodes_per_hour"],
            # load-independent view: CPU seconds per episode (workers + writer), and what that
            # gives with `workers` cores fully available
            "cpu_s_per_episode": round(cpu_ep, 3),
            "episodes_per_hour_cpu_bound": round(cores * 3600 / cpu_ep, 1) if cpu_ep > 0 else None,
            "frames": s["frames_new"],
            "successes": s["successes_total"],
            "first_episode_s": s["first_episode_s"],
            "worker_s": s["worker_s"],
            "writer_s": s["writer_s"],
            "dataset_mb": round(_dir_mb(root), 2),
            # share of `workers` cores the collection got (< 1: other processes competed for them)
            "cpu_share": round(cpu_ep * episodes / (s["wall_s"] * cores), 2) if s["wall_s"] > 0 else None,
            "loadavg_during": load.mean,  # 1-min load average, sampled (our own processes included)
        }
        out["peak_rss_mb"] = {
            "workers": rss,
            "worker_max": max(rss.values()) if rss else s["writer_peak_rss_mb"],
            "writer": s["writer_peak_rss_mb"],
        }
        if raw:
            log(f"[bench-collect] raw replay of the same {episodes} episodes with {workers} worker(s) ...")
            with LoadSampler() as load:
                out["raw"] = raw_cost(recipe, root, workers)
            out["raw"]["loadavg_during"] = load.mean
            out["overhead_ratio"] = round(s["wall_s"] / out["raw"]["wall_s"], 2)
            out["overhead_ratio_incl_build"] = round(
                s["wall_s"] / (out["raw"]["wall_s"] + out["raw"]["build_s"] / max(1, workers)), 2
            )
            raw_cpu = out["raw"]["cpu_s_per_episode"]
            out["overhead_ratio_cpu"] = round(cpu_ep / raw_cpu, 2) if raw_cpu > 0 else None
        if profile:
            log("[bench-collect] profiling one episode ...")
            out["profile"] = profile_episode(recipe, 0)
    finally:
        if keep is None:
            shutil.rmtree(parent, ignore_errors=True)
    out["loadavg_after"] = [round(x, 2) for x in os.getloadavg()]
    out["targets"] = TARGETS
    return out


def report(res: dict) -> str:
    c = res["collection"]
    kind = "cloth" if res["deformable"] else "rigid"
    target = TARGETS[f"{kind}_episodes_per_hour"]
    lines = [
        (f"{res['name']}: {res['episodes']} episodes x <= {res['max_steps']} steps, {len(res['cameras'])} cameras at "
         f"{res['image_size']}² ({', '.join(res['modalities'])}), {res['workers']} worker(s) on {res['cpu_count']} "
         f"cores; load average before/after {res['loadavg_before'][0]}/{res['loadavg_after'][0]}"),
        (f"  collection: {c['episodes_per_hour']} episodes/hour ({c['wall_s']} s, {c['frames']} frames, "
         f"{c['dataset_mb']} MB; target >= {target} {kind})"),
        (f"  collection CPU: {c['cpu_s_per_episode']} s per episode (workers + writer) = "
         f"{c['episodes_per_hour_cpu_bound']} episodes/hour with {min(res['workers'], res['cpu_count'])} free core(s); "
         f"it got {c['cpu_share']:.0%} of them (load average during: {c['loadavg_during']})"),
        (f"  peak RSS: worker {res['peak_rss_mb']['worker_max']} MB, writer {res['peak_rss_mb']['writer']} MB "
         f"(target <= {TARGETS['worker_peak_rss_mb']} MB per worker)"),
        f"  worker seconds (sum): {c['worker_s']}; writer seconds: {c['writer_s']}",
    ]  # fmt: skip
    if "raw" in res:
        r = res["raw"]
        lines.append(
            f"  raw mj_step + render of the same episodes: {r['episodes_per_hour']} episodes/hour ({r['wall_s']} s, "
            f"{r['ms_per_step']} ms/step; model builds {r['build_s']} s not counted; got {r['cpu_share']:.0%} of "
            f"{min(res['workers'], res['cpu_count'])} core(s), load average during: {r['loadavg_during']})"
        )
        lines.append(
            f"  overhead collection / raw: {res['overhead_ratio']}x wall (target <= {TARGETS['overhead_ratio']}x); "
            f"{res['overhead_ratio_incl_build']}x counting model builds as raw; {res['overhead_ratio_cpu']}x in CPU "
            f"seconds per episode ({c['cpu_s_per_episode']} vs {r['cpu_s_per_episode']})"
        )
    if "profile" in res:
        p = res["profile"]
        lines.append(
            f"  time split of episode {p['episode_index']} ({p['frames']} frames, in-process): "
            f"wall {p['total_s']} s, CPU {p['total_cpu_s']} s"
        )
        lines += [f"    {k:50s} {v:7.3f} s  CPU {p['cpu_seconds'][k]:7.3f} s" for k, v in p["seconds"].items()]
    return "\n".join(lines)


def main(argv=None) -> int:
    from flatlab_lerobot.collect.recipe import RecipeError, load_recipe

    ap = argparse.ArgumentParser(prog="flatlab bench-collect", description=__doc__.splitlines()[0])
    ap.add_argument("--recipe", required=True, type=Path, help="e.g. datasets/bench_rigid.yaml")
    ap.add_argument("--episodes", type=int, default=None, help="episodes to collect (default: the recipe's)")
    ap.add_argument("--workers", type=int, default=None, help="worker processes (default: the recipe's)")
    ap.add_argument(
        "--json", type=Path, default=None, help="result file (default: outputs/bench/collect_speed_<name>.json)"
    )
    ap.add_argument("--no-raw", action="store_true", help="skip the raw mj_step + render replay")
    ap.add_argument("--profile", action="store_true", help="also time the pieces of one episode in-process")
    ap.add_argument("--keep", type=Path, default=None, help="collect into this folder and keep the dataset")
    args = ap.parse_args(argv)
    try:
        recipe = load_recipe(args.recipe)
    except RecipeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    episodes = args.episodes if args.episodes is not None else recipe.episodes
    workers = args.workers if args.workers is not None else recipe.workers
    if episodes < 1 or not 1 <= workers <= 64:
        print(f"error: --episodes must be >= 1 and --workers in [1, 64], got {episodes}, {workers}", file=sys.stderr)
        return 2
    res = run(recipe, episodes, workers, raw=not args.no_raw, profile=args.profile, keep=args.keep)
    print(report(res))
    if args.json is None:
        from flatlab_lerobot.paths import OUTPUTS_DIR

        args.json = OUTPUTS_DIR / "bench" / f"collect_speed_{recipe.name}.json"
    from flatlab_lerobot.atomic import write_json

    write_json(args.json, res, indent=2)
    print(f"-> {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

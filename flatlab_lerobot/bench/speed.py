"""Speed benchmark (a script that prints numbers, not a timed test).

1. Env step with rendering (default env settings) against the raw cost of the same work done
   directly with MuJoCo: ``n_substeps`` x ``mj_step`` + for every camera one colour+depth render
   pass and one segmentation pass (what the observation needs), as a ratio.
2. Real-time factor of the rigid cell and of the 15x15 cloth cell without rendering, under the
   scripted expert (so contacts are realistic).

Run: ``flatlab bench`` (or ``python -m flatlab_lerobot.bench.speed``).
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from flatlab_lerobot.catalog import REFERENCE_OBJECTS, get_object
from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.sim.core import FlatLabSim
from flatlab_lerobot.strategies import Expert


def _raw_render_pass(r: mujoco.Renderer, data, cam: str, segment: bool, rgb, zbuf) -> None:
    r.update_scene(data, cam)
    scn = r.scene
    if segment:
        scn.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        scn.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
    mujoco.mjr_render(r._rect, scn, r._mjr_context)
    mujoco.mjr_readPixels(rgb, zbuf, r._rect, r._mjr_context)
    scn.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
    scn.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False


def env_vs_raw(object_id: str, steps: int) -> dict:
    env = FlatLabEnv(object_id=object_id)
    obs, _ = env.reset(seed=0)
    hold = obs["agent_pos"].astype(float)
    for _ in range(3):  # warm up
        env.step(hold)
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(hold)
    env_s = (time.perf_counter() - t0) / steps
    sim = env.sim
    m, d = sim.model, sim.data
    size = env.rig.height, env.rig.width
    r = mujoco.Renderer(m, *size)
    rgb = np.empty((*size, 3), np.uint8)
    zbuf = np.empty(size, np.float32)
    cams = sorted(set(env.cameras) | set(env.pointcloud_cameras))
    t0 = time.perf_counter()
    for _ in range(steps):
        for _ in range(sim.n_substeps):
            mujoco.mj_step(m, d)
        for c in cams:
            _raw_render_pass(r, d, c, False, rgb, zbuf)
            if c in env.pointcloud_cameras:
                _raw_render_pass(r, d, c, True, rgb, zbuf)
    raw_s = (time.perf_counter() - t0) / steps
    r.close()
    env.close()
    return {"object": object_id, "cameras": cams, "image": size, "env_step_ms": env_s * 1e3, "raw_ms": raw_s * 1e3,
            "env_steps_per_s": 1 / env_s, "ratio": env_s / raw_s}  # fmt: skip


def real_time_factor(object_id: str, strategy: str, sim_seconds: float) -> dict:
    sim = FlatLabSim(get_object(object_id))
    sim.reset(0.0, 0.0, 0.0)
    gen = Expert(sim.cell, sim.control_dt).episode(strategy, lambda: (sim.joint_positions(), sim.environment_state()))
    t_phys = 0.0
    start = sim.data.time
    while sim.data.time - start < sim_seconds:
        action = next(gen)[2]  # expert time is not counted: physics only
        t0 = time.perf_counter()
        sim.step(action)
        t_phys += time.perf_counter() - t0
    return {"object": object_id, "timestep": sim.model.opt.timestep, "sim_s": sim.data.time - start,
            "wall_s": t_phys, "rtf": (sim.data.time - start) / t_phys}  # fmt: skip


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=30, help="env steps timed per measurement")
    ap.add_argument("--sim-seconds", type=float, default=8.0, help="simulated seconds per RTF measurement")
    args = ap.parse_args(argv)
    for oid in (REFERENCE_OBJECTS["B"], REFERENCE_OBJECTS["C"]):
        res = env_vs_raw(oid, args.steps)
        print(f"env step with rendering [{oid}, cameras {res['cameras']} at {res['image'][1]}x{res['image'][0]}, "
              f"scene+object clouds]: {res['env_step_ms']:.1f} ms ({res['env_steps_per_s']:.1f} steps/s); "
              f"raw mj_step+render of the same: {res['raw_ms']:.1f} ms; ratio {res['ratio']:.2f}x (target <= 1.25x)")  # fmt: skip
    for strategy in ("B", "C"):
        oid = REFERENCE_OBJECTS[strategy]
        res = real_time_factor(oid, strategy, args.sim_seconds)
        target = 10 if strategy != "C" else 1
        print(f"real-time factor without rendering [{oid}, timestep {res['timestep']} s, scripted expert]: "
              f"{res['rtf']:.1f}x ({res['sim_s']:.1f} s simulated in {res['wall_s']:.2f} s; target >= {target}x)")


if __name__ == "__main__":
    main()

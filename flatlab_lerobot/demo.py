"""``flatlab demo``: the scripted expert on one reference object per strategy.

For each strategy it writes, under the output folder, a key-frame PNG strip (one frame at the
start of every primitive, plus the last frame), a short MP4 and a line of the success summary
(``summary.json`` and ``summary.md``).  Files are written to a temporary name and renamed, so
an interrupted demo never leaves a half-written file.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from flatlab_lerobot.catalog import REFERENCE_OBJECTS, get_object
from flatlab_lerobot.sim.core import FlatLabSim, SimulationDiverged
from flatlab_lerobot.strategies import Expert


def sample_placement(seed: int, planar: float = 0.05, yaw_deg: float = 30.0) -> tuple[float, float, float]:
    """The benchmark's default reset distribution: planar offset ±``planar`` m, yaw ±``yaw_deg``."""
    from flatlab_lerobot.tasks import ResetDistribution

    return ResetDistribution(planar, yaw_deg).sample(seed)


def run_expert_episode(
    object_id: str,
    strategy: str,
    seed: int,
    max_time: float = 30.0,
    on_step=None,
) -> dict:
    """Run the scripted expert once; ``on_step(sim, stage, primitive_index)`` is called after every
    control step.  Returns the episode record (success, time, failure reason, ...)."""
    sim = FlatLabSim(get_object(object_id))
    x, y, yaw = sample_placement(seed)
    sim.reset(x, y, yaw)
    expert = Expert(sim.cell, sim.control_dt)
    gen = expert.episode(strategy, lambda: (sim.joint_positions(), sim.environment_state()))
    reason, stage, n_prims = "", "", 0
    t0 = time.perf_counter()
    try:
        while sim.data.time < max_time:
            stage, prim_index, action = next(gen)
            sim.step(action)
            n_prims = prim_index + 1
            if on_step is not None:
                on_step(sim, stage, prim_index)
            if sim.is_success():
                break
    except SimulationDiverged as exc:
        reason = f"diverged: {exc}"
    st = sim.grasp_status()
    success = sim.is_success()
    if not success and not reason:
        reason = "timeout: " + st.shortfall
    return {
        "object_id": object_id,
        "strategy": strategy,
        "seed": seed,
        "placement": {"x": x, "y": y, "yaw_deg": float(np.degrees(yaw))},
        "success": bool(success),
        "sim_time_s": round(float(sim.data.time), 3),
        "wall_time_s": round(time.perf_counter() - t0, 3),
        "primitives": n_prims,
        "final_clearance_m": round(st.clearance, 4),
        "failure_reason": reason,
        "_sim": sim,
    }


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    write(tmp)
    os.replace(tmp, path)


def run_demo(out_dir: Path, strategies=("A", "B", "C"), seed: int = 0, size=(360, 480), fps: int = 10) -> list[dict]:
    import imageio.v3 as iio
    import mujoco

    out_dir.mkdir(parents=True, exist_ok=True)
    records = []
    for strategy in strategies:
        object_id = REFERENCE_OBJECTS[strategy]
        keyframes, video, state = [], [], {"renderer": None, "last": None, "last_stage": ""}

        def on_step(sim, stage, prim_index, keyframes=keyframes, video=video, state=state):
            if state["renderer"] is None:
                state["renderer"] = mujoco.Renderer(sim.model, *size)
            r = state["renderer"]
            r.update_scene(sim.data, camera="front")
            frame = r.render()
            video.append(frame)
            key = (prim_index, stage != "move")
            # A's push passes that are not needed run as short holds: one "hold" frame stands for the run
            repeat_hold = stage == "hold" and state["last_stage"] == "hold"
            if key != state["last"] and not repeat_hold:
                keyframes.append(_label(frame, f"{prim_index}: {stage}"))
            state["last"], state["last_stage"] = key, stage

        rec = run_expert_episode(object_id, strategy, seed, on_step=on_step)
        sim = rec.pop("_sim")
        r = state["renderer"]
        r.update_scene(sim.data, camera="front")
        keyframes.append(_label(r.render(), "success" if rec["success"] else "failed"))
        r.close()
        strip = _grid(keyframes, cols=4)
        stem = f"strategy_{strategy}_{object_id}"
        _atomic_write(out_dir / f"{stem}_keyframes.png", lambda p, s=strip: iio.imwrite(p, s))
        _atomic_write(
            out_dir / f"{stem}.mp4",
            lambda p, v=video: iio.imwrite(p, np.stack(v), plugin="pyav", codec="libx264", fps=fps),
        )
        rec["keyframes_png"] = f"{stem}_keyframes.png"
        rec["video_mp4"] = f"{stem}.mp4"
        records.append(rec)
        print(
            f"strategy {strategy} on {object_id}: {'SUCCESS' if rec['success'] else 'FAILED'} "
            f"({rec['sim_time_s']:.1f} s simulated, {rec['wall_time_s']:.1f} s wall) {rec['failure_reason']}",
            flush=True,
        )
    md = ["| strategy | object | success | sim time (s) | wall (s) | key frames |", "|---|---|---|---|---|---|"]
    md += [
        f"| {r['strategy']} | {r['object_id']} | {r['success']} | {r['sim_time_s']} | {r['wall_time_s']} | {r['keyframes_png']} |"
        for r in records
    ]
    _atomic_write(out_dir / "summary.json", lambda p: p.write_text(json.dumps(records, indent=2)))
    _atomic_write(out_dir / "summary.md", lambda p: p.write_text("\n".join(md) + "\n"))
    print(f"{sum(r['success'] for r in records)}/{len(records)} strategies succeeded; outputs in {out_dir}")
    return records


def _label(frame: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    img = Image.fromarray(frame)
    draw = ImageDraw.Draw(img)
    draw.rectangle([0, 0, 8 + 7 * len(text), 18], fill=(0, 0, 0))
    draw.text((4, 3), text, fill=(255, 255, 255))
    return np.asarray(img)


def _grid(frames: list[np.ndarray], cols: int) -> np.ndarray:
    h, w, _ = frames[0].shape
    rows = -(-len(frames) // cols)
    out = np.full((rows * h, cols * w, 3), 255, np.uint8)
    for i, f in enumerate(frames):
        out[(i // cols) * h : (i // cols + 1) * h, (i % cols) * w : (i % cols + 1) * w] = f
    return out

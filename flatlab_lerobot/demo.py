"""``flatlab demo``: the scripted expert on one reference object per strategy.

For each strategy it writes, under the output folder, a key-frame PNG strip (one frame at the
start of every primitive, plus the last frame), a short MP4 and a line of the success summary
(``summary.json`` and ``summary.md``).  Files are written to a temporary name and renamed, so
an interrupted demo never leaves a half-written file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from flatlab_lerobot.atomic import replacing, write_text
from flatlab_lerobot.catalog import REFERENCE_OBJECTS
from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.rollout import ExpertPolicy, rollout


def run_expert_episode(
    object_id: str,
    strategy: str,
    seed: int,
    max_time: float = 30.0,
    on_step=None,
) -> dict:
    """Run the scripted expert once in the default cell (placement: the env's reset distribution
    for ``seed``), for at most ``max_time`` simulated seconds of control; ``on_step(sim, stage,
    primitive_index)`` is called after every control step.  Returns the episode record (success,
    time, failure reason, ...)."""
    env = FlatLabEnv(object_id=object_id, episode_length=round(max_time / 0.1), control_dt=0.1,
                     obs_pixels=False, obs_pointcloud=False)  # fmt: skip
    after = None if on_step is None else (lambda st: on_step(st.env.sim, st.stage, st.primitive))
    try:
        ep = rollout(env, ExpertPolicy(strategy, env.cell, env.control_dt), seed=seed, after_step=after)
    finally:
        env.close()
    x, y, yaw = ep.placement
    return {
        "object_id": object_id,
        "strategy": strategy,
        "seed": seed,
        "placement": {"x": x, "y": y, "yaw_deg": float(np.degrees(yaw))},
        "success": ep.success,
        "sim_time_s": round(ep.sim_time_s, 3),
        "wall_time_s": round(ep.wall_s, 3),
        "primitives": max(ep.primitives, default=-1) + 1,
        "final_clearance_m": round(env.sim.grasp_status().clearance, 4),
        "failure_reason": ep.failure_reason,
        "_sim": env.sim,
    }


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
        with replacing(out_dir / f"{stem}_keyframes.png") as p:
            iio.imwrite(p, strip)
        with replacing(out_dir / f"{stem}.mp4") as p:
            iio.imwrite(p, np.stack(video), plugin="pyav", codec="libx264", fps=fps)
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
    write_text(out_dir / "summary.json", json.dumps(records, indent=2))
    write_text(out_dir / "summary.md", "\n".join(md) + "\n")
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

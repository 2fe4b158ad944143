"""Front-camera frames of the scripted expert's strategy B, the default expert above and the one with
``ExpertOptions.b_right_half_turn`` below, each labelled with the right wrist's commanded angle (docs/baselines.md).

    python scripts/expert_b_frames.py --object box_shoe --yaw 25 --steps 20,35,50,74 --out docs/img/expert_b_right_half_turn.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--object", default="box_shoe", help="catalog object id")
    ap.add_argument("--yaw", type=float, default=25.0, help="the object's yaw at the table centre, degrees")
    ap.add_argument("--steps", default="20,35,50,74", help="comma-separated control steps to show")
    ap.add_argument("--size", type=int, default=320, help="render size (px)")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    from flatlab_lerobot.atomic import replacing
    from flatlab_lerobot.catalog import load_objects
    from flatlab_lerobot.env import FlatLabEnv
    from flatlab_lerobot.rollout import ExpertPolicy, rollout
    from flatlab_lerobot.strategies.expert import ExpertOptions

    if a.object not in load_objects():
        raise SystemExit(f"--object: unknown object id {a.object!r}")
    try:
        steps = [int(s) for s in a.steps.split(",")]
    except ValueError:
        raise SystemExit(f"--steps {a.steps!r}: want comma-separated integers") from None
    rows = []
    for on in (False, True):
        env = FlatLabEnv(object_id=a.object, obs_pixels=False, obs_pointcloud=False, render_size=a.size)
        tiles = {}

        def after(st, tiles=tiles, env=env, on=on):
            if st.index in steps:
                im = Image.fromarray(env.render())
                label = f"{'half turn' if on else 'default'}, step {st.index} {st.stage}: right wrist {st.action[14]:+.2f} rad"
                ImageDraw.Draw(im).text((6, 6), label, fill=(255, 255, 0))
                tiles[st.index] = im

        try:
            policy = ExpertPolicy("B", env.cell, env.control_dt, options=ExpertOptions(b_right_half_turn=on))
            ep = rollout(env, policy, seed=0, options={"placement": (0.0, 0.0, np.deg2rad(a.yaw))}, after_step=after)
        finally:
            env.close()
        print(f"b_right_half_turn={on}: success {ep.success} in {ep.steps} steps; frames at {sorted(tiles)}")
        rows.append([tiles[s] for s in steps if s in tiles])
    if not rows[0] or not rows[1]:
        raise SystemExit(f"--steps {a.steps}: no step inside the episodes")
    w, h = a.size, a.size
    sheet = Image.new("RGB", (w * max(len(r) for r in rows), h * 2))
    for r, tiles in enumerate(rows):
        for c, t in enumerate(tiles):
            sheet.paste(t, (c * w, r * h))
    with replacing(a.out) as tmp:
        sheet.save(tmp, format="PNG")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

"""Key frames of policy episodes as one PNG strip per episode, from the real lerobot-eval's video.

    python scripts/key_frames.py --policy outputs/unified/cpu --object box_shoe --seed 1000 \
        --out docs/img/unified_B.png -- --env.pointcloud_cameras=[front,top,left,right] ...

Runs ``lerobot-eval --policy.path=<policy> --env.type=flatlab --env.object_id=<object> --seed=<seed>
--eval.n_episodes=1`` (the same episode as ``flatlab eval``'s trial with that seed), then picks
``--frames`` frames evenly over the episode's video (which ends when the env terminates) and writes
them side by side.  Extra arguments after ``--`` go to lerobot-eval.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import av
import numpy as np
from PIL import Image, ImageDraw


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True, help="pretrained_model folder")
    ap.add_argument("--object", required=True, help="catalog object id")
    ap.add_argument("--seed", type=int, default=1000, help="episode seed (flatlab eval's trial t: 1000 + t)")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--steps", default=None, help="FIRST:LAST: spread the frames over these steps only (default: all)")
    ap.add_argument("--size", type=int, default=384, help="render size (px)")
    ap.add_argument("--out", type=Path, required=True)
    args, extra = ap.parse_known_args(argv)
    window = None
    if args.steps:  # checked before the episode runs
        try:
            window = tuple(int(v) for v in args.steps.split(":"))
        except ValueError:
            window = ()
        if len(window) != 2:
            ap.error(f"--steps {args.steps!r}: want FIRST:LAST, two step numbers")
    extra = [a for a in extra if a != "--"]
    exe = Path(sys.executable).parent / "lerobot-eval"
    tmp = Path(tempfile.mkdtemp(prefix="keyframes_"))
    try:
        cmd = [str(exe), f"--policy.path={args.policy}", "--env.type=flatlab", f"--env.object_id={args.object}",
               f"--env.render_size={args.size}", f"--seed={args.seed}", "--eval.n_episodes=1", "--eval.batch_size=1",
               f"--output_dir={tmp / 'eval'}", *extra]  # fmt: skip
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            print(r.stderr[-3000:], file=sys.stderr)
            return r.returncode
        info = json.loads((tmp / "eval" / "eval_info.json").read_text())
        success = bool(info["per_task"][0]["metrics"]["successes"][0])
        video = next((tmp / "eval").rglob("*.mp4"))
        with av.open(str(video)) as c:
            frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
        first, last = window or (0, len(frames) - 1)
        first, last = max(0, first), min(len(frames) - 1, last)
        idx = np.linspace(first, last, args.frames).round().astype(int)
        h, w = frames[0].shape[:2]
        strip = Image.new("RGB", (w * len(idx), h + 22), "white")
        draw = ImageDraw.Draw(strip)
        for i, k in enumerate(idx):
            strip.paste(Image.fromarray(frames[k]), (i * w, 22))
            draw.text((i * w + 6, 5), f"step {k}", fill="black")
        draw.text((w * len(idx) - 190, 5), f"{args.object} seed {args.seed}: {'success' if success else 'failure'}",
                  fill="black")  # fmt: skip
        args.out.parent.mkdir(parents=True, exist_ok=True)
        strip.save(args.out, optimize=True)
        print(f"{args.out}: {len(frames)} frames, success={success}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

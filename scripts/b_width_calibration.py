"""How narrow an object can B's two-hand squeeze still lift?  The scripted expert's B on calibration slabs that are
not benchmark objects: square slabs of side w, and oblong ones (w x 20-30 cm, either way round), 2 and 4 cm thick.
The result sets the unified policy's ``--policy.b_min_width`` (docs/unified.md, stop 76).

    python scripts/b_width_calibration.py --out docs/results/b_width_calibration.json

The slabs are written to a copy of ``envs/`` in a temporary folder (``split: reference``, so no split, set or
evaluation ever sees them) and run through ``rollout.run_task_episode("grasp", slab, "B", seed)``: the task's reset
distribution (table centre +-5 cm, yaw +-30 deg) at seeds 0..n-1.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MASS_DENSITY = 375.0  # kg/m^3: a 20 x 20 x 4 cm slab weighs 0.6 kg, as the catalog's boxes do


def slabs() -> dict[str, tuple[float, float, float]]:
    """id -> size (x, y, thickness) in m."""
    out = {}
    for w in (0.06, 0.08, 0.085, 0.09, 0.095, 0.10, 0.12, 0.14, 0.16, 0.20):
        for t in (0.02, 0.04):
            out[f"cal_sq{round(w * 1000):03d}_t{round(t * 1000):02d}"] = (w, w, t)
    for w, length in ((0.07, 0.20), (0.08, 0.30)):
        out[f"cal_x{round(w * 1000):03d}_y{round(length * 1000):03d}"] = (w, length, 0.02)
        out[f"cal_x{round(length * 1000):03d}_y{round(w * 1000):03d}"] = (length, w, 0.02)
    return out


def write_envs(folder: Path) -> None:
    shutil.copytree(REPO / "envs", folder)
    lines = ["# calibration slabs of scripts/b_width_calibration.py: not benchmark objects", "objects:"]
    for oid, (x, y, t) in slabs().items():
        lines += [f"  - id: {oid}", "    category: Box", "    split: reference", "    material: rigid", "    shape: slab",
                  f"    size: [{x}, {y}, {t}]", f"    mass: {round(MASS_DENSITY * x * y * t, 4)}", "    friction: 0.4",
                  "    rgba: [0.7, 0.5, 0.3, 1]", "    strategy: B"]  # fmt: skip
    (folder / "objects" / "calibration.yaml").write_text("\n".join(lines) + "\n")


def one(job: tuple[str, int]) -> dict:
    from flatlab_lerobot.rollout import run_task_episode

    oid, seed = job
    t0 = time.perf_counter()
    ep = run_task_episode("grasp", oid, "B", seed)
    return {"object": oid, "seed": seed, "success": bool(ep.success), "steps": int(ep.steps),
            "failure_reason": ep.failure_reason or "", "wall_s": round(time.perf_counter() - t0, 1)}  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="episodes per slab (seeds 0..n-1)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    if a.seeds < 1 or a.workers < 1:
        ap.error("--seeds and --workers: at least 1")
    with tempfile.TemporaryDirectory() as tmp:
        envs = Path(tmp) / "envs"
        write_envs(envs)
        os.environ["FLATLAB_ENVS_DIR"] = str(envs)  # the workers inherit it
        t0 = time.perf_counter()
        with ProcessPoolExecutor(a.workers) as ex:
            runs = list(ex.map(one, [(oid, s) for oid in slabs() for s in range(a.seeds)]))
        wall = time.perf_counter() - t0
    table = {}
    for oid, size in slabs().items():
        r = [x for x in runs if x["object"] == oid]
        table[oid] = {"size_m": list(size), "width_m": min(size[:2]), "lifted": sum(x["success"] for x in r), "trials": len(r)}
        print(f"{oid:18s} {size[0]:.3f} x {size[1]:.3f} x {size[2]:.3f} m: B lifted {table[oid]['lifted']}/{len(r)}")
    if a.out:
        from flatlab_lerobot.paper.pipeline import git_commit, machine

        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({
            "what": "the scripted expert's B (two-hand squeeze) on calibration slabs that are not benchmark objects: how "
                    "narrow an object it can still lift (--policy.b_min_width of flatlab_unified)",
            "command": shlex.join(["python", "scripts/b_width_calibration.py", *(sys.argv[1:] if argv is None else argv)]),
            "seeds": list(range(a.seeds)), "reset": "the grasp task's: table centre +-5 cm, yaw +-30 deg",
            "mass_density_kg_m3": MASS_DENSITY, "wall_s": round(wall, 1), "machine": machine(),
            "git": git_commit(), "slabs": table, "runs": runs,
        }, indent=1) + "\n")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

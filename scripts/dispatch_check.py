"""Does a build made on this CPU match one made on another?  Prints the digests to compare, in a few minutes.

    python scripts/dispatch_check.py [--out outputs/dispatch_check] [--steps 200]

Needs the `cpu` preset's learning sets (``outputs/paper/cpu/strategy_export_orig`` and
``primitive_export_train``: ``flatlab paper --preset cpu --only primitive_export_train strategy_export_orig``).
For each math-library setting in ``SETTINGS`` it trains the A-2 generator and the top-view executor for
``--steps`` steps (their `cpu` recipes, seed 1000, ``OMP_NUM_THREADS=1``) and prints each model's sha256, with the
learning sets' content digests.  ``--compare`` reads a record written by another machine (its ``"check"`` entry,
e.g. ``docs/results/cpu_dispatch_xeon.json``) and says which digests are equal.  Equal learning sets and unequal
``default`` models: the CPUs differ only in the math libraries' dispatch; equal ``avx2`` (or ``generic``) models:
a build with the libraries held at that setting is portable between the two CPUs (``docs/results.md``,
Reproducibility).  ``--settings generic`` runs one setting only; a digest the other record lacks is said so.
Records: ``docs/results/cpu_dispatch_xeon.json`` (Intel Xeon, stop 75), ``cpu_dispatch_amd.json`` (AMD EPYC, stop 78).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from flatlab_lerobot.paper.pipeline import content_hashes, machine

REPO = Path(__file__).resolve().parents[1]

SETTINGS = {
    "default": {},
    "avx2": {"MKL_CBWR": "AVX2", "ONEDNN_MAX_CPU_ISA": "AVX2"},
    # every library on its generic code path: oneMKL's conditional-numerical-reproducibility branch meant to give
    # the same results on any x86 CPU, oneDNN held at SSE4.1, ATen's kernels unvectorized (stop 78: avx2 was not
    # portable between the AMD EPYC and the Intel Xeon)
    "generic": {"MKL_CBWR": "COMPATIBLE", "ONEDNN_MAX_CPU_ISA": "SSE41", "ATEN_CPU_CAPABILITY": "default"},
}
TRAININGS = {  # name: (recipe, learning set under outputs/paper/cpu)
    "generator_A2": ("policies/flatlab_strategy/ablation_A2.json", "strategy_export_orig"),
    "executor_top": ("policies/flatlab_executor/object_top_cosine_rot15.json", "primitive_export_train"),
}


def digest(path: Path) -> dict:
    files = [p for p in path.rglob("*") if p.is_file()]
    return content_hashes(path, files)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", type=Path, default=REPO / "outputs/paper/cpu", help="folder holding the learning sets")
    ap.add_argument("--out", type=Path, default=REPO / "outputs/dispatch_check")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--compare", type=Path, help="a record with another machine's \"check\" entry")
    ap.add_argument("--json", type=Path, help="write this machine's check here")
    ap.add_argument("--settings", default=",".join(SETTINGS), help=f"comma-separated, of {', '.join(SETTINGS)}")
    args = ap.parse_args(argv)
    if args.steps < 1:
        ap.error("--steps must be >= 1")
    settings = [x.strip() for x in args.settings.split(",") if x.strip()]
    if not settings or (bad := [x for x in settings if x not in SETTINGS]):
        ap.error(f"--settings: unknown {bad if settings else 'empty list'}; choose from {', '.join(SETTINGS)}")
    other = None
    if args.compare:  # checked before minutes of training
        try:
            other = json.loads(args.compare.read_text()).get("check")
        except (OSError, json.JSONDecodeError) as e:
            sys.exit(f"--compare: cannot read {args.compare} ({e})")
        if not other:
            sys.exit(f"--compare: {args.compare} has no \"check\" entry")
        if other.get("steps") != args.steps:
            sys.exit(f"--compare: {args.compare} was made with --steps {other.get('steps')}, not {args.steps}")
    res: dict = {"cpu_model": machine()["cpu_model"], "steps": args.steps, "sets": {}, "models": {}, "wall_s": {}}
    for name, (_, ds) in TRAININGS.items():
        root = args.sets / ds
        if not (root / "meta" / "info.json").is_file():
            sys.exit(f"--sets: {root} is not a learning set (no meta/info.json); build it with "
                     f"`flatlab paper --preset cpu --only {ds}`")  # fmt: skip
        res["sets"][ds] = digest(root)["content_sha256"]
    for setting in settings:
        extra = SETTINGS[setting]
        env = {**os.environ, "OMP_NUM_THREADS": "1", **extra}
        for k in ("MKL_CBWR", "ONEDNN_MAX_CPU_ISA", "MKL_ENABLE_INSTRUCTIONS", "ATEN_CPU_CAPABILITY"):
            if k not in extra:
                env.pop(k, None)
        for name, (recipe, ds) in TRAININGS.items():
            out = args.out / f"{name}_{setting}"
            cmd = [str(Path(sys.executable).with_name("lerobot-train")), f"--config_path={recipe}",
                   f"--dataset.root={args.sets / ds}", f"--output_dir={out}", f"--steps={args.steps}",
                   f"--save_freq={args.steps}", "--wandb.enable=false"]  # fmt: skip
            if out.exists():
                shutil.rmtree(out)
            t0 = time.time()
            r = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
            if r.returncode:
                sys.exit(f"{name} ({setting}) failed:\n{r.stderr[-3000:]}")
            res["wall_s"][f"{name}_{setting}"] = round(time.time() - t0, 1)
            res["models"][f"{name}_{setting}"] = digest(out)["model_sha256"]
            print(f"{name:14s} {setting:8s} {res['models'][f'{name}_{setting}'][:16]}  {res['wall_s'][f'{name}_{setting}']} s",
                  flush=True)  # fmt: skip
    for ds, h in res["sets"].items():
        print(f"{ds:24s} content {h[:16]}")
    if args.json:
        args.json.write_text(json.dumps({"check": res}, indent=1) + "\n")
    if other:
        print(f"against {other['cpu_model']} ({args.compare}):")
        for kind in ("sets", "models"):
            for k, h in res[kind].items():
                verdict = "not in that record" if k not in other[kind] else "equal" if other[kind][k] == h else "DIFFERENT"
                print(f"  {k:24s} {verdict}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

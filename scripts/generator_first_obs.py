"""The unified policy's strategy choice on the env's first observation, per object and seed, without running the
episodes: column S of ``flatlab eval`` in about a minute per split instead of an evaluation.  ``--policy`` may also be a
``flatlab_strategy`` checkpoint (a generator alone, read as the unified policy reads it: ``--generator-cloud-points``).

    python scripts/generator_first_obs.py --policy outputs/paper/cpu/unified_cpu_two --splits train --seeds 1000-1004 \
        --image-size 128 --n-object-points 4096 --out outputs/s35/first_obs_train.json

For each object of the splits and each seed it resets the env as ``flatlab eval``'s trial with that seed does (same
placement draw and point sampling: give the evaluation's cameras, image size and point counts) and calls the policy's own
``rank_strategies`` on ``observation.object_pointcloud`` (``--policy-arg`` overrides its config, e.g. ``b_min_width=0.09``).
Prints S per split; writes every choice, the whole ranking and the seen object's width (the shorter side of the smallest
rectangle around its cloud seen from above) to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from flatlab_lerobot.catalog import benchmark_objects
from flatlab_lerobot.env import FlatLabEnv
from flatlab_lerobot.paper.desk import parse_seeds
from flatlab_lerobot.policies import seen_points
from flatlab_lerobot.policies.unified.observed_contact import seen_width


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True, type=Path, help="flatlab_unified or flatlab_strategy pretrained_model folder")
    ap.add_argument("--generator-cloud-points", type=int, default=2048,
                    help="for a flatlab_strategy --policy: the unified policy's generator_cloud_points")
    ap.add_argument("--splits", default="train,test_alpha,test_beta")
    ap.add_argument("--objects", default="", help="comma-separated object ids instead of --splits")
    ap.add_argument("--seeds", default="1000-1004", help="episode seeds: '1000-1004', '1000,1003'")
    ap.add_argument("--cameras", default="front,top,left,right", help="the env's pointcloud_cameras")
    ap.add_argument("--image-size", type=int, default=128)
    ap.add_argument("--n-points", type=int, default=4096, help="the env's n_points (its draws come first)")
    ap.add_argument("--n-object-points", type=int, default=4096)
    ap.add_argument("--generator-tta", type=int, default=0, help="the policy's generator_tta (0: its own)")
    ap.add_argument("--policy-arg", action="append", default=[], metavar="FIELD=VALUE",
                    help="a flatlab_unified config override, e.g. b_min_width=0.09 (repeatable)")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    try:
        seeds = parse_seeds(a.seeds)
    except ValueError:
        ap.error(f"--seeds {a.seeds!r}: want e.g. 1000-1004 or 1000,1003")
    from lerobot.configs.policies import PreTrainedConfig

    import flatlab_lerobot.lerobot_plugin  # noqa: F401  registers the policy types
    from flatlab_lerobot.catalog import CatalogError, get_object
    from flatlab_lerobot.policies.strategy.modeling_flatlab_strategy import FlatLabStrategyPolicy
    from flatlab_lerobot.policies.unified.modeling_flatlab_unified import FlatLabUnifiedPolicy

    if not (a.policy / "config.json").is_file():
        raise SystemExit(f"--policy {a.policy}: no config.json (want a flatlab_unified or flatlab_strategy pretrained_model folder)")
    kind = PreTrainedConfig.from_pretrained(a.policy).type
    if kind == "flatlab_unified":
        overrides = [f"--generator_tta={a.generator_tta}", *(f"--{x.removeprefix('--')}" for x in a.policy_arg)]
        try:
            cfg = PreTrainedConfig.from_pretrained(a.policy, cli_overrides=overrides)
        except Exception as e:  # draccus' parse errors and the config's own ValueErrors name the field
            raise SystemExit(f"--policy-arg {' '.join(a.policy_arg)}: {e}") from None
        policy = FlatLabUnifiedPolicy.from_pretrained(a.policy, config=cfg).eval()
        rank = policy.rank_strategies
    elif kind == "flatlab_strategy":
        gen = FlatLabStrategyPolicy.from_pretrained(a.policy).eval()
        if a.policy_arg:
            raise SystemExit("--policy-arg: only for a flatlab_unified --policy")

        def rank(cloud):  # noqa: E306
            return gen.rank_cloud(cloud, a.generator_cloud_points, a.generator_tta or None)
    else:
        raise SystemExit(f"--policy {a.policy}: config.json type is {kind!r}, want 'flatlab_unified' or 'flatlab_strategy'")
    rows, t0 = [], time.perf_counter()
    if a.objects:
        try:
            groups = {"objects": [get_object(o.strip()) for o in a.objects.split(",") if o.strip()]}
        except (CatalogError, KeyError) as e:
            raise SystemExit(f"--objects: {e}") from None
    else:
        try:
            groups = {s.strip(): benchmark_objects(s.strip()) for s in a.splits.split(",") if s.strip()}
        except ValueError as e:
            raise SystemExit(f"--splits: {e}") from None
    for split, specs in groups.items():
        for spec in specs:
            env = FlatLabEnv(object_id=spec.id, cameras=("front",), pointcloud_cameras=tuple(a.cameras.split(",")),
                             image_size=a.image_size, n_points=a.n_points, n_object_points=a.n_object_points, obs_pixels=False)  # fmt: skip
            for seed in seeds:
                obs, _ = env.reset(seed=seed)
                ranked = list(rank(obs["object_pointcloud"]))
                width = seen_width(seen_points(np.asarray(obs["object_pointcloud"], float)))
                rows.append({"object_id": spec.id, "split": spec.split, "group": split, "category": spec.category, "label": spec.strategy,
                             "seed": seed, "strategy": ranked[0], "S": ranked[0] == spec.strategy, "ranked": "".join(ranked),
                             "seen_width_m": None if width is None else round(width, 4)})  # fmt: skip
            env.close()
        r = [x for x in rows if x["group"] == split]
        print(f"{split}: S {100 * sum(x['S'] for x in r) / len(r):.1f} % ({sum(x['S'] for x in r)}/{len(r)})", flush=True)
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({"policy": str(a.policy), "args": vars(a) | {"policy": str(a.policy), "out": str(a.out)},
                                     "wall_s": round(time.perf_counter() - t0, 1), "choices": rows}, indent=1) + "\n")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""``flatlab executor-metrics``: pose errors of a trained ``flatlab_executor`` on an exported
primitive dataset (``flatlab primitive-export``; Test-alpha / Test-beta exports need ``--eval-only``
there and are read here for *reporting only*: nothing selects a checkpoint from them).

Per split, per strategy's grasp primitive (a_grasp / b_squeeze / c_pinch start pose) and per
(strategy, stage, primitive):

* ``p_mse``: mean over commanded arms of ||p_hat - p||^2 (m^2), start and end poses;
* ``r_err``: mean geodesic angle 2 arccos |<q_hat, q>| (rad);
* ``grip_mae``: mean |gripper width error| (m);
* ``z_bias``: mean signed height error z_hat - z (m), start and end poses: a model that leaves the
  hand above the object on average shows it here, where the squared error hides the sign;
* ``active_arm_accuracy`` (split rows ``all``): the predicted "primitive commands this arm" flag.

The "grasp" rows are the paper's Grasping P-MSE (start pose of the grasp primitive).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np


def evaluate(policy, dataset_root: Path, batch_size: int = 32, tta: int | None = None) -> dict:
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from flatlab_lerobot.learning.primitive_export import TASK_RE
    from flatlab_lerobot.policies.executor.configuration_flatlab_executor import (
        ARMS, GRASP_STAGE, OBS_PRIMITIVE, PRIMITIVE_NAMES, STRATEGY_NAMES, arm_slices, decode_primitive,
    )  # fmt: skip
    from flatlab_lerobot.policies.executor.modeling_flatlab_executor import geodesic_angle

    ds = LeRobotDataset("local/flatlab_primitives_eval", root=dataset_root)
    loader = torch.utils.data.DataLoader(ds, batch_size=batch_size, shuffle=False, num_workers=0)
    acc: dict = defaultdict(lambda: defaultdict(list))
    act_acc: dict = defaultdict(list)  # per split: predicted "arm commanded" flag == the expert's
    policy.eval()
    for batch in loader:
        pred = policy.predict_world(batch, tta)
        prim = batch[OBS_PRIMITIVE]
        strat, stage, name = (x.tolist() for x in decode_primitive(prim))
        splits = [TASK_RE.match(t)["split"] for t in batch["task"]]
        tgt = batch["action"].float()
        for i, p in enumerate(pred):
            sl = arm_slices(i)
            active = tgt[:, sl["active"]][:, 0] > 0.5
            res = {}
            for e in ("start", "end"):
                res[f"{e}_se"] = ((p[f"{e}_pos"] - tgt[:, sl[f"{e}_pos"]]) ** 2).sum(-1)
                res[f"{e}_th"] = geodesic_angle(p[f"{e}_quat"], tgt[:, sl[f"{e}_quat"]])
                res[f"{e}_dz"] = p[f"{e}_pos"][:, 2] - tgt[:, sl[f"{e}_pos"]][:, 2]
            ge = ((p["gripper_start"] - tgt[:, sl["gripper_start"]]).abs() + (p["gripper_end"] - tgt[:, sl["gripper_end"]]).abs())[:, 0] / 2
            hit = ((p["active"][:, 0] > 0.5) == active).tolist()
            for b in range(len(active)):
                act_acc[splits[b]].append(hit[b])
                if not active[b]:
                    continue
                s = STRATEGY_NAMES[strat[b]]
                keys = [(splits[b], "all"), (splits[b], f"{s}/{stage[b]:02d}/{PRIMITIVE_NAMES[name[b]]}")]
                if stage[b] == GRASP_STAGE[s]:
                    keys += [(splits[b], "grasp"), (splits[b], f"grasp/{s}")]
                for k in keys:
                    a = acc[k]
                    a["start_se"].append(float(res["start_se"][b]))
                    a["end_se"].append(float(res["end_se"][b]))
                    a["start_th"].append(float(res["start_th"][b]))
                    a["end_th"].append(float(res["end_th"][b]))
                    a["start_dz"].append(float(res["start_dz"][b]))
                    a["end_dz"].append(float(res["end_dz"][b]))
                    a["grip"].append(float(ge[b]))
                    a["arm"].append(ARMS[i])
    out: dict = {}
    for (split, key), a in sorted(acc.items()):
        row = {"n_arm_samples": len(a["start_se"]),
               "p_mse_start_m2": float(np.mean(a["start_se"])), "p_mse_end_m2": float(np.mean(a["end_se"])),
               "r_err_start_rad": float(np.mean(a["start_th"])), "r_err_end_rad": float(np.mean(a["end_th"])),
               "grip_mae_m": float(np.mean(a["grip"])),
               "z_bias_start_m": float(np.mean(a["start_dz"])), "z_bias_end_m": float(np.mean(a["end_dz"]))}  # fmt: skip
        out.setdefault(split, {})[key] = row
    for split, hits in act_acc.items():
        out.setdefault(split, {})["all"]["active_arm_accuracy"] = float(np.mean(hits))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="flatlab executor-metrics", description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy.path", dest="policy_path", type=Path, required=True, help="a pretrained_model folder")
    ap.add_argument("--dataset", type=Path, action="append", required=True, help="exported dataset root (repeatable)")
    ap.add_argument("--out", type=Path, help="write the JSON here (default: print)")
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--tta", type=int, default=None,
                    help="test-time augmentation passes (flatlab_executor `tta`; default: the checkpoint's config)")
    args = ap.parse_args(argv)
    if args.tta is not None and not 1 <= args.tta <= 64:
        print(f"error: --tta {args.tta}: must be in [1, 64]", file=sys.stderr)
        return 2
    if not (args.policy_path / "config.json").is_file():
        print(f"error: --policy.path {args.policy_path}: no config.json (give a .../pretrained_model folder)", file=sys.stderr)
        return 2
    for d in args.dataset:
        if not (d / "meta" / "info.json").is_file():
            print(f"error: --dataset {d}: no meta/info.json (run flatlab primitive-export)", file=sys.stderr)
            return 2
    import torch

    from flatlab_lerobot.policies.executor.modeling_flatlab_executor import FlatLabExecutorPolicy

    torch.set_num_threads(max(1, torch.get_num_threads()))
    t0 = time.perf_counter()
    pol = FlatLabExecutorPolicy.from_pretrained(args.policy_path)
    pol.to("cpu")
    tta = pol.config.tta if args.tta is None else args.tta
    result = {"policy": str(args.policy_path), "ablation": pol.config.ablation, "tta": tta, "splits": {}}
    for d in args.dataset:
        for split, rows in evaluate(pol, d, args.batch_size, tta).items():
            result["splits"].setdefault(split, {}).update(rows)
    result["wall_s"] = round(time.perf_counter() - t0, 2)
    text = json.dumps(result, indent=1)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

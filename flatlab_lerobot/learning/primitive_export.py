"""``flatlab primitive-export``: a primitive set (``flatlab primitive-set``) as a LeRobotDataset that
the real ``lerobot-train --policy.type=flatlab_executor`` trains on.

One episode per demo, one frame per primitive sample (in stage order), features as documented in
:mod:`flatlab_lerobot.policies.executor.configuration_flatlab_executor`.  Each frame's ``task`` is
``flatlab primitive | object=<id> | split=<split> | strategy=<S>``: the policy reads the splits from
the dataset's task list when ``lerobot-train`` builds it and refuses a dataset holding any object that
is not in the Train split (:func:`check_training_tasks`).

Split rule: by default every object of the set must be in the Train split (error otherwise);
``--eval-only`` exports Test-alpha / Test-beta objects for the pose-error metrics (P-MSE / R-Err) --
such a dataset cannot train the executor.

By default only successful demos are exported, and samples where no arm moves (the ``hold`` of a
skipped push pass, the final hold) are dropped (``--keep-still`` keeps them).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from flatlab_lerobot.paths import OUTPUTS_DIR
from flatlab_lerobot.policies.executor.configuration_flatlab_executor import (  # noqa: F401  re-exported
    TASK_RE, TRAIN_SPLIT, PrimitiveExportError, check_training_tasks, task_string,
)  # fmt: skip

FPS = 10  # nominal: frames are primitives, not time steps
ROBOT_TYPE = "flatlab_dual_panda_primitives"


def features(n_points: int, n_object_points: int = 256) -> dict:
    from flatlab_lerobot.policies.executor.configuration_flatlab_executor import (
        ACTION_DIM, ACTION_NAMES, ARMS, MAX_STAGES, OBS_OBJECT_CLOUD, OBS_POINTCLOUD, OBS_PRIMITIVE, OBS_TCP_STATE, PRIMITIVE_DIM,
        PRIMITIVE_NAMES, STRATEGY_NAMES, TCP_STATE_DIM,
    )  # fmt: skip

    prim_names = [f"strategy_{s}" for s in STRATEGY_NAMES] + [f"stage_{i}" for i in range(MAX_STAGES)]
    prim_names += [f"primitive_{p}" for p in PRIMITIVE_NAMES]
    tcp_names = [f"{a}_{f}" for a in ARMS for f in ("x", "y", "z", "qw", "qx", "qy", "qz", "gripper")]
    return {
        OBS_POINTCLOUD: {"dtype": "float32", "shape": (n_points, 3), "names": ["points", "xyz"]},
        OBS_OBJECT_CLOUD: {"dtype": "float32", "shape": (n_object_points, 3), "names": ["points", "xyz"]},
        OBS_PRIMITIVE: {"dtype": "float32", "shape": (PRIMITIVE_DIM,), "names": prim_names},
        OBS_TCP_STATE: {"dtype": "float32", "shape": (TCP_STATE_DIM,), "names": tcp_names},
        "action": {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)},
    }


def frame_of(row, cloud: np.ndarray, object_cloud: np.ndarray) -> dict:
    """One sample row (+ its scene and object clouds) -> a dataset frame (no ``task``)."""
    from flatlab_lerobot.policies.executor.configuration_flatlab_executor import (
        ARM_FIELDS, ARMS, OBS_OBJECT_CLOUD, OBS_POINTCLOUD, OBS_PRIMITIVE, OBS_TCP_STATE, encode_primitive,
    )  # fmt: skip

    tcp, act = [], []
    for arm in ARMS:
        tcp += [np.asarray(row[f"{arm}_tcp_pos"], np.float32), np.asarray(row[f"{arm}_tcp_quat"], np.float32),
                np.float32([row[f"{arm}_gripper_measured"]])]  # fmt: skip
        for name, _ in ARM_FIELDS:
            v = row[f"{arm}_{name}"]
            act.append(np.atleast_1d(np.asarray(v, np.float32)))
    return {
        OBS_POINTCLOUD: np.asarray(cloud, np.float32),
        OBS_OBJECT_CLOUD: np.asarray(object_cloud, np.float32),
        OBS_PRIMITIVE: np.float32(encode_primitive(row["strategy"], int(row["primitive_index"]), row["primitive"])),
        OBS_TCP_STATE: np.concatenate(tcp).astype(np.float32),
        "action": np.concatenate(act).astype(np.float32),
    }


def export(
    set_dir: Path,
    out: Path,
    *,
    eval_only: bool = False,
    include_failed: bool = False,
    keep_still: bool = False,
    repo_id: str = "local/flatlab_primitives",
    object_points: int = 256,
    overwrite: bool = False,
    log=print,
) -> dict:
    """Write the LeRobotDataset; returns a summary (also written to ``<out>/flatlab_export.json``)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from flatlab_lerobot.learning import primitive_set as ps

    t0 = time.perf_counter()
    try:
        df, scene, objects = ps.load(Path(set_dir))
    except ps.PrimitiveSetError as exc:
        raise PrimitiveExportError(f"--set: {exc}") from exc
    splits = sorted(set(df["split"]))
    if not eval_only and splits != [TRAIN_SPLIT]:
        others = sorted(set(df.loc[df["split"] != TRAIN_SPLIT, "object_id"]))
        raise PrimitiveExportError(
            f"--set {set_dir}: samples.parquet column 'split': objects outside the Train split {others}; "
            "a training set holds Train objects only (use --eval-only for a metrics-only export)"
        )
    keep = np.ones(len(df), bool)
    if not include_failed:
        keep &= df["demo_success"].to_numpy(bool)
    if not keep_still:
        keep &= df["moving_arms"].astype(str).str.len().to_numpy() > 0
    sel = df[keep]
    if sel.empty:
        raise PrimitiveExportError(f"--set {set_dir}: no samples left after filtering (successful demos, moving arms)")
    out = Path(out)
    if out.exists():
        if not overwrite:
            raise PrimitiveExportError(f"--out {out}: exists (use --overwrite)")
        shutil.rmtree(out)
    k = min(int(object_points), objects.shape[1])  # the stored object cloud is in random order: its first k
    ds = LeRobotDataset.create(repo_id, FPS, features(scene.shape[1], k), root=out, robot_type=ROBOT_TYPE, use_videos=False)
    n_eps = 0
    for (_, _), ep in sel.groupby(["object_id", "demo_index"], sort=False):
        ep = ep.sort_values("primitive_index")
        for _, row in ep.iterrows():
            i = int(row["sample_index"])
            frame = frame_of(row, scene[i], objects[i, :k])
            frame["task"] = task_string(row["object_id"], row["split"], row["strategy"])
            ds.add_frame(frame)
        ds.save_episode()
        n_eps += 1
    ds.finalize()
    summary = {
        "format": "flatlab_primitive_export",
        "source": str(Path(set_dir).resolve()),
        "eval_only": eval_only,
        "splits": splits if eval_only else [TRAIN_SPLIT],
        "objects": sorted(set(sel["object_id"])),
        "episodes": n_eps,
        "frames": int(len(sel)),
        "dropped": {"failed_demos": int((~df["demo_success"].to_numpy(bool)).sum()) if not include_failed else 0,
                    "total": int((~keep).sum())},  # fmt: skip
        "n_points": int(scene.shape[1]),
        "n_object_points": k,
        "wall_s": round(time.perf_counter() - t0, 2),
    }
    (out / "flatlab_export.json").write_text(json.dumps(summary, indent=1))
    log(f"[primitive-export] {out}: {n_eps} episodes, {len(sel)} frames of {len(summary['objects'])} objects "
        f"(splits {summary['splits']}); {summary['wall_s']} s")  # fmt: skip
    return summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="flatlab primitive-export",
        description="A primitive set as a LeRobotDataset for `lerobot-train --policy.type=flatlab_executor`.",
    )
    ap.add_argument("--set", type=Path, default=OUTPUTS_DIR / "learning" / "primitive_set", help="primitive set folder")
    ap.add_argument("--out", type=Path, default=OUTPUTS_DIR / "learning" / "primitive_dataset", help="dataset root")
    ap.add_argument("--repo-id", default="local/flatlab_primitives")
    ap.add_argument("--eval-only", action="store_true", help="allow Test-alpha/beta objects (metrics only; cannot train)")
    ap.add_argument("--include-failed", action="store_true", help="also export samples of failed demos")
    ap.add_argument("--keep-still", action="store_true", help="keep samples where no arm moves")
    ap.add_argument("--object-points", type=int, default=256,
                    help="object cloud points per frame (default 256, the env's n_object_points)")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    try:
        export(args.set, args.out, eval_only=args.eval_only, include_failed=args.include_failed,
               keep_still=args.keep_still, repo_id=args.repo_id, object_points=args.object_points, overwrite=args.overwrite)  # fmt: skip
    except PrimitiveExportError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

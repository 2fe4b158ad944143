"""``flatlab strategy-export``: a strategy set (``flatlab strategy-set``) as a LeRobotDataset v3 that
``lerobot-train --policy.type=flatlab_strategy --dataset.root=<out>`` trains on.

Layout (one frame = one cloud):

* one **episode** per (train object, placement view): the object's variants (original, scales,
  rigid counterparts) in that placement, ordered round-robin over their strategies (seeded), so
  ``group_size`` consecutive frames of an episode -- what the policy loads per sample through
  lerobot's delta indices -- hold one object's transformations with different strategies: the
  contrastive term's negatives.
* the episode's ``task`` is the base object id, and episodes are written view by view, so
  ``--dataset.eval_split=f`` (lerobot's own hold-out: the last ceil(n*f) episodes per task) holds
  out the last placement views of every TRAIN object: the validation set (``flatlab
  strategy-eval --select`` scores the checkpoints on exactly these episodes).
* features: the chosen inputs (``--inputs``): ``observation.object_pointcloud`` (N, 3) float32,
  centred and in metres (the set's unit-sphere cloud times its radius: the policy normalizes it
  and reads its size),
  ``observation.scene_pointcloud`` (N, 3) float32 (ablation A-8, needs ``--extras scene`` in the
  set), ``observation.images.object`` (64, 64, 3) image (A-7, needs ``--extras rgb``); ``action``
  (3,) float32: the strategy one-hot (A, B, C); ``object_index`` (1,) int64: the base object.
* ``meta/flatlab_strategy_frames.parquet``: per frame, the set's index row (object id, split,
  category, transform, view, ...) and ``episode_index`` / ``frame_index``.

Only train-split objects are accepted: a set that holds a Test-alpha / Test-beta object is refused.
``--originals-only`` keeps the untransformed objects (ablations A-2 / A-3: no data transformation).
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

DEFAULT_SET = OUTPUTS_DIR / "learning" / "strategy_set"
DEFAULT_OUT = OUTPUTS_DIR / "learning" / "strategy_lerobot"
INPUTS = {
    "object": ("observation.object_pointcloud", "clouds.npy"),
    "scene": ("observation.scene_pointcloud", "scene_clouds.npy"),
    "rgb": ("observation.images.object", "rgb.npy"),
}
FRAMES_FILE = "meta/flatlab_strategy_frames.parquet"
FPS = 10


def load_inputs(set_dir: Path, inputs) -> dict[str, np.ndarray]:
    """{feature key: array over the set's rows} for ``inputs`` (names of :data:`INPUTS`)."""
    out = {}
    for name in inputs:
        if name not in INPUTS:
            raise ValueError(f"--inputs: unknown input {name!r}; known: {list(INPUTS)}")
        key, fname = INPUTS[name]
        path = Path(set_dir) / fname
        if not path.is_file():
            extra = "" if name == "object" else f" (build the set with `flatlab strategy-set --extras {name}`)"
            raise FileNotFoundError(f"--set: {path} missing: the set has no '{name}' input{extra}")
        out[key] = np.load(path)
    return out


def metric_clouds(arrays: dict, index) -> None:
    """The object clouds back in metres (centred: the set's unit-sphere cloud times its
    ``radius``), in place: the policy normalizes them itself and also reads their size."""
    key = INPUTS["object"][0]
    if key in arrays:
        arrays[key] = (arrays[key] * index["radius"].to_numpy(np.float32)[:, None, None]).astype(np.float32)


def check_train_only(index, set_dir) -> None:
    """Refuse a set holding any object outside the catalog's train split: by the set's own
    ``split`` column and by the catalog's split of every base object (Test-alpha / Test-beta
    objects never reach a training set)."""
    from flatlab_lerobot.catalog import load_objects

    catalog = load_objects()
    bases = sorted(set(index.base_object_id))
    unknown = [b for b in bases if b not in catalog]
    if unknown:
        raise ValueError(f"--set: {set_dir}: base object(s) {unknown[:5]} are not in the catalog")
    bad = sorted({b for b in bases if catalog[b].split != "train"} | set(index.base_object_id[index.split != "train"]))
    if bad:
        raise ValueError(f"--set: {set_dir} holds non-train object(s) {bad[:5]} (field 'split'); "
                         "only train objects may be trained on")  # fmt: skip


def episode_plan(index, seed: int = 0) -> list[tuple[str, int, list[int]]]:
    """[(base object id, view, set rows in frame order)], view-major then catalog order: each
    episode's rows interleaved round-robin over strategies (seeded shuffle within a strategy)."""
    rng = np.random.default_rng(seed)
    bases = list(dict.fromkeys(index.base_object_id))
    plan = []
    for view in sorted(set(index.view)):
        for base in bases:
            rows = index.index[(index.base_object_id == base) & (index.view == view)].to_numpy()
            if not len(rows):
                continue
            strat = index.loc[rows, "strategy"].to_numpy()
            by = [rng.permutation(rows[strat == s]) for s in sorted(set(strat))]
            order = [int(r[i]) for i in range(max(map(len, by))) for r in by if i < len(r)]
            plan.append((base, int(view), order))
    return plan


def export(set_dir: Path, out: Path, inputs=("object",), originals_only: bool = False, seed: int = 0,
           repo_id: str = "local/flatlab_strategy", points: int | None = None,
           counterparts: bool = True) -> dict:  # fmt: skip
    """Write the LeRobotDataset; returns a summary dict."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from flatlab_lerobot.learning.strategy_set import load

    t0 = time.perf_counter()
    clouds, index, meta = load(set_dir)
    check_train_only(index, set_dir)
    arrays = load_inputs(set_dir, inputs)
    metric_clouds(arrays, index)
    if points is not None:  # a seeded random subset of every cloud (smaller files, faster loading)
        rng = np.random.default_rng(seed)
        for key, arr in arrays.items():
            if arr.ndim == 3 and arr.shape[-1] == 3 and not key.startswith("observation.images."):
                if points > arr.shape[1]:
                    raise ValueError(f"--points: {points} > the set's {arr.shape[1]} points per cloud")
                idx = np.stack([rng.permutation(arr.shape[1])[:points] for _ in range(len(arr))])
                arrays[key] = np.take_along_axis(arr, idx[..., None], axis=1)
    if originals_only:
        index = index[index["transform"] == "original"]
    if not counterparts:  # no rigid counterparts of the cloths (the material transformation)
        index = index[~index["rigid_counterpart"].astype(bool)]
    out = Path(out)
    if out.exists():
        raise FileExistsError(f"--out: {out} exists; remove it first")
    features = {ACTION: {"dtype": "float32", "shape": (3,), "names": ["A", "B", "C"]},
                "object_index": {"dtype": "int64", "shape": (1,), "names": None}}  # fmt: skip
    for key, arr in arrays.items():
        if key.startswith("observation.images."):
            features[key] = {"dtype": "image", "shape": tuple(arr.shape[1:]), "names": ["height", "width", "channels"]}
        else:
            features[key] = {"dtype": "float32", "shape": tuple(arr.shape[1:]), "names": None}
    tmp = out.parent / f".{out.name}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    ds = LeRobotDataset.create(repo_id, fps=FPS, features=features, root=tmp, robot_type="flatlab", use_videos=False)
    base_ids = {b: i for i, b in enumerate(dict.fromkeys(index.base_object_id))}
    plan = episode_plan(index, seed)
    frames = []
    for ep, (base, view, rows) in enumerate(plan):
        for fi, r in enumerate(rows):
            row = index.loc[r]
            frame = {ACTION: np.eye(3, dtype=np.float32)[int(row.label)],
                     "object_index": np.array([base_ids[base]], np.int64), "task": base}  # fmt: skip
            for key, arr in arrays.items():
                frame[key] = arr[r]
            ds.add_frame(frame)
            frames.append({"episode_index": ep, "frame_index": fi, "set_row": int(r), **row.to_dict()})
        ds.save_episode()
    ds.finalize()
    import pandas as pd

    pd.DataFrame(frames).to_parquet(tmp / FRAMES_FILE, index=False)
    summary = {
        "set": str(set_dir), "inputs": list(inputs), "originals_only": originals_only, "seed": seed,
        "points": points, "counterparts": counterparts, "n_frames": len(frames), "n_episodes": len(plan), "n_objects": len(base_ids),
        "views": sorted({v for _, v, _ in plan}), "set_meta_seed": meta.get("seed"),
        "export_seconds": round(time.perf_counter() - t0, 1),
    }  # fmt: skip
    (tmp / "meta" / "flatlab_strategy_export.json").write_text(json.dumps(summary, indent=1) + "\n")
    tmp.rename(out)
    return summary


ACTION = "action"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="flatlab strategy-export", description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", type=Path, default=DEFAULT_SET, help="strategy set folder (default: outputs/learning/strategy_set)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="LeRobotDataset root to write (must not exist)")
    ap.add_argument("--inputs", default="object", help=f"comma-separated inputs among {list(INPUTS)} (default: object)")
    ap.add_argument("--originals-only", action="store_true", help="no transformed variants (ablations A-2 / A-3)")
    ap.add_argument("--no-counterparts", action="store_true", help="drop the cloths' rigid counterparts")
    ap.add_argument("--seed", type=int, default=0, help="seed of the frame order within an episode")
    ap.add_argument("--points", type=int, default=None, help="keep a seeded random subset of N points per cloud")
    args = ap.parse_args(argv)
    inputs = tuple(s.strip() for s in args.inputs.split(",") if s.strip())
    if not inputs or any(i not in INPUTS for i in inputs):
        ap.error(f"--inputs: unknown input(s) in {args.inputs!r}; known: {list(INPUTS)}")
    try:
        if args.points is not None and args.points < 1:
            raise ValueError(f"--points: must be >= 1, got {args.points}")
        summary = export(args.set, args.out, inputs, args.originals_only, args.seed, points=args.points,
                         counterparts=not args.no_counterparts)
    except (ValueError, FileNotFoundError, FileExistsError) as exc:
        ap.error(str(exc))
    print(f"strategy export: {summary['n_frames']} frames in {summary['n_episodes']} episodes "
          f"({summary['n_objects']} objects) in {summary['export_seconds']} s -> {args.out}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

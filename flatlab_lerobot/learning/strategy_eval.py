"""``flatlab strategy-eval``: the learned strategy generator (``flatlab_strategy``) judged on the
benchmark objects.

* ``--policy`` is a ``pretrained_model`` folder, or a ``lerobot-train`` output folder: then every
  saved checkpoint is scored on the **validation** episodes of its training dataset (lerobot's
  ``--dataset.eval_split`` hold-out: the last placement views of the TRAIN objects, see
  ``flatlab strategy-export``) and the best (validation accuracy, then validation cross-entropy,
  then the later step) is used.  Test-alpha / Test-beta clouds play no part in the choice.
* ``--set`` is a strategy set of the benchmark objects in fresh placements, built with a seed
  disjoint from the training set's (``flatlab strategy-set --splits all --scales 0
  --no-counterparts --views 3 --seed 1000``).  Reported: accuracy per split and per category
  against the grounded catalog label (``catalog_strategy``) and against the paper's label, and
  the 3x3 confusion matrix (rows: catalog label, columns: prediction) per split.
* ``--ambiguity SET``: how far a cloth's cloud is from its rigid counterpart's, against how far two
  placements of one object are (yaw-aligned chamfer distance on the normalized clouds).
* ``--sheet-neighbours TRAIN_SET`` (with ``--set``): every flex sheet of ``--set`` against the flex sheets of a
  training set, in metres: the nearest training cloud's label (1-NN), and for a TRAIN object its own views'
  distance against the nearest other label's -- whether the cloud can tell a mouse pad (A) from a fabric (C).

Writes a JSON (``--out``) with the metrics, the command, seeds, wall time, machine and git commit.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from flatlab_lerobot.learning import int_at_least

LETTERS = ("A", "B", "C")
SPLITS = ("train", "test_alpha", "test_beta")
MACHINE = "2 CPU cores, no GPU"


# ------------------------------------------------------------------------------ policy
def load_policy(path: Path):
    """A ``flatlab_strategy`` policy from a ``pretrained_model`` folder, in eval mode on the CPU."""
    from flatlab_lerobot.policies.strategy.modeling_flatlab_strategy import FlatLabStrategyPolicy

    path = Path(path)
    if not (path / "config.json").is_file() or not (path / "model.safetensors").is_file():
        raise FileNotFoundError(f"--policy: {path} is not a pretrained_model folder (config.json + model.safetensors)")
    cfg = json.loads((path / "config.json").read_text())
    if cfg.get("type") != "flatlab_strategy":
        raise ValueError(f"--policy: {path}/config.json is a {cfg.get('type')!r} policy, not flatlab_strategy")
    policy = FlatLabStrategyPolicy.from_pretrained(str(path))
    policy.config.device = "cpu"
    return policy.to("cpu").eval()


def set_inputs(policy, set_dir: Path) -> np.ndarray:
    """The policy's input for every row of a strategy set (clouds, or RGB crops as (3, H, W) floats)."""
    from flatlab_lerobot.learning.strategy_export import INPUTS, load_inputs

    from flatlab_lerobot.learning.strategy_export import metric_clouds
    from flatlab_lerobot.learning.strategy_set import load

    name = next((n for n, (k, _) in INPUTS.items() if k == policy.config.input_key), None)
    arrays = load_inputs(set_dir, [name])
    metric_clouds(arrays, load(set_dir)[1])
    arr = arrays[policy.config.input_key]
    if policy.config.is_image:
        arr = arr.transpose(0, 3, 1, 2).astype(np.float32) / 255.0
    return arr


def predict(policy, x: np.ndarray, batch: int = 64) -> np.ndarray:
    """(N, 3) logits."""
    import torch

    key, out = policy.config.input_key, []
    with torch.no_grad():
        for i in range(0, len(x), batch):
            out.append(policy.predict_logits({key: torch.as_tensor(x[i : i + batch])}).numpy())
    return np.concatenate(out) if out else np.zeros((0, 3), np.float32)


# ------------------------------------------------------------------------------ metrics
def confusion(true, pred) -> list[list[int]]:
    m = np.zeros((3, 3), int)
    for t, p in zip(true, pred, strict=True):
        m[LETTERS.index(t), LETTERS.index(p)] += 1
    return m.tolist()


def _acc(true, pred) -> float | None:
    true, pred = np.asarray(true), np.asarray(pred)
    return None if len(true) == 0 else round(float((true == pred).mean()) * 100, 2)


def metrics(index, pred: list[str]) -> dict:
    """Accuracy per split / category (catalog and paper labels) and confusion matrices."""
    from flatlab_lerobot.catalog import load_objects

    catalog = load_objects()
    idx = index.reset_index(drop=True).copy()
    idx["pred"] = list(pred)
    idx["paper_strategy"] = [catalog[b].paper_strategy for b in idx.base_object_id]
    out = {"n": len(idx), "per_split": {}, "per_category": {}, "per_object": {}}
    for split in [s for s in SPLITS if s in set(idx.split)]:
        d = idx[idx.split == split]
        out["per_split"][split] = {
            "n": len(d), "n_objects": int(d.base_object_id.nunique()),
            "acc_catalog": _acc(d.catalog_strategy, d.pred), "acc_paper": _acc(d.paper_strategy, d.pred),
            "confusion_catalog": confusion(d.catalog_strategy, d.pred),
        }  # fmt: skip
        for cat, c in d.groupby("category"):
            out["per_category"][f"{split}/{cat}"] = {
                "n": len(c), "catalog_labels": "".join(sorted(set(c.catalog_strategy))),
                "acc_catalog": _acc(c.catalog_strategy, c.pred), "acc_paper": _acc(c.paper_strategy, c.pred),
                "pred": dict(sorted(c.pred.value_counts().items())),
            }  # fmt: skip
    for obj, o in idx.groupby("base_object_id"):
        out["per_object"][obj] = {"catalog": o.catalog_strategy.iloc[0], "paper": o.paper_strategy.iloc[0],
                                  "pred": "".join(o.pred)}  # fmt: skip
    out["confusion_catalog"] = confusion(idx.catalog_strategy, idx.pred)
    return out


# ------------------------------------------------------------------------------ selection
def validation_episodes(dataset_root: Path, eval_split: float) -> list[int]:
    """lerobot's hold-out (``make_train_eval_datasets``): per task, its last ceil(n * f) episodes."""
    import pandas as pd

    frames = pd.read_parquet(Path(dataset_root) / "meta" / "flatlab_strategy_frames.parquet")
    eps = frames.groupby("episode_index").base_object_id.first()
    out = []
    for _task, e in eps.groupby(eps):
        ids = sorted(e.index)
        n = math.ceil(len(ids) * eval_split)
        out += ids[len(ids) - n :] if n else []
    return sorted(out)


def validation_data(dataset_root: Path, eval_split: float, input_key: str):
    """(inputs, labels 0..2) of the validation frames, read from the LeRobotDataset itself."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    eps = validation_episodes(dataset_root, eval_split)
    if not eps:
        raise ValueError(f"{dataset_root}: no validation episodes (train with --dataset.eval_split > 0)")
    ds = LeRobotDataset("local/flatlab_strategy", root=dataset_root, episodes=eps, video_backend="pyav")
    xs, ys = [], []
    for i in range(len(ds)):
        item = ds[i]
        xs.append(item[input_key].numpy())
        ys.append(int(item["action"].argmax()))
    return np.stack(xs).astype(np.float32), np.array(ys)


def _val_score(policy, x: np.ndarray, y: np.ndarray) -> dict:
    logits = predict(policy, x)
    m = logits.max(1, keepdims=True)
    logp = logits - m - np.log(np.exp(logits - m).sum(1, keepdims=True))
    return {"val_acc": round(float((logits.argmax(1) == y).mean()) * 100, 2),
            "val_ce": round(float(-logp[np.arange(len(y)), y].mean()), 4)}  # fmt: skip


def select_checkpoint(train_dir: Path, average_last: int = 0) -> tuple[Path, dict]:
    """(best pretrained_model folder, the scores of every checkpoint) by validation accuracy.  With
    ``average_last`` K > 0 no checkpoint is chosen: the mean of the last K checkpoints' weights
    (:mod:`.checkpoint_average`) is written beside them and returned, with its validation score too."""
    ckpts = sorted(p for p in (Path(train_dir) / "checkpoints").glob("[0-9]*") if (p / "pretrained_model").is_dir())
    if not ckpts:
        raise FileNotFoundError(f"--policy: {train_dir}/checkpoints has no saved step (lerobot-train output?)")
    tc = json.loads((ckpts[-1] / "pretrained_model" / "train_config.json").read_text())
    root, split = tc["dataset"]["root"], float(tc["dataset"].get("eval_split") or 0.0)
    first = load_policy(ckpts[-1] / "pretrained_model")
    x, y = validation_data(Path(root), split, first.config.input_key)
    scores = {c.name: _val_score(load_policy(c / "pretrained_model"), x, y) for c in ckpts}
    best = max(scores, key=lambda k: (scores[k]["val_acc"], -scores[k]["val_ce"], int(k)))
    sel = {"dataset_root": root, "eval_split": split, "n_val": len(y), "scores": scores, "selected": best}
    if average_last:
        from flatlab_lerobot.learning.checkpoint_average import average_checkpoints

        path, steps = average_checkpoints(Path(train_dir), average_last)
        sel.update(selected=path.parent.name, averaged_steps=steps, average_score=_val_score(load_policy(path), x, y),
                   best_single=best)  # fmt: skip
        return path, sel
    return ckpts[[c.name for c in ckpts].index(best)] / "pretrained_model", sel


# ------------------------------------------------------------------------------ ambiguity
def chamfer_yaw(a: np.ndarray, b: np.ndarray, n_yaw: int = 36) -> float:
    """Symmetric chamfer distance between two normalized clouds, minimized over rotations of
    ``b`` about the vertical axis and its mirror image (placements differ in yaw)."""
    best = math.inf
    for mirror in (1.0, -1.0):
        bb = b * np.array([1.0, mirror, 1.0])
        for t in np.linspace(0, 2 * np.pi, n_yaw, endpoint=False):
            c, s = math.cos(t), math.sin(t)
            r = bb @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])
            d = ((a[:, None, :] - r[None, :, :]) ** 2).sum(-1)
            best = min(best, float(np.sqrt(d.min(1)).mean() + np.sqrt(d.min(0)).mean()) / 2)
    return best


def ambiguity(set_dir: Path, n_points: int = 256) -> dict:
    """For every cloth variant in the (training) set: the distance of its cloud to its rigid
    counterpart's (same outline, same scale) against the distance between two placements of the
    cloth itself and to a different object of the same strategy."""
    from flatlab_lerobot.learning.strategy_set import load

    clouds, index, _ = load(set_dir)
    sub = clouds[:, :: max(1, clouds.shape[1] // n_points)][:, :n_points].astype(np.float64)
    cloth = index[(index.material != "rigid") & ~index.rigid_counterpart]
    rows = []
    for (oid, base), g in cloth.groupby(["object_id", "base_object_id"]):
        rig = index[index.object_id == oid + "@rigid"]
        views = list(g.index)
        if not len(rig) or len(views) < 2:
            continue
        other = index[(index.strategy == "C") & (index.base_object_id != base)]
        for k, i in enumerate(views[:2]):
            j = views[(k + 1) % len(views)]
            rows.append({
                "object_id": oid, "category": g.category.iloc[0],
                "cloth_vs_rigid": chamfer_yaw(sub[i], sub[rig.index[k % len(rig)]]),
                "cloth_vs_own_other_view": chamfer_yaw(sub[i], sub[j]),
                "cloth_vs_other_cloth": chamfer_yaw(sub[i], sub[other.index[k % len(other)]]) if len(other) else None,
            })  # fmt: skip
    if not rows:
        raise ValueError(f"--ambiguity: {set_dir} has no cloth with a rigid counterpart and >= 2 views")
    import pandas as pd

    df = pd.DataFrame(rows)
    def med(col):
        v = col.dropna()
        return round(float(v.median()), 4) if len(v) else None

    summ = {c: med(df[c]) for c in ("cloth_vs_rigid", "cloth_vs_own_other_view", "cloth_vs_other_cloth")}
    per_cat = {cat: {c: med(d[c]) for c in summ} for cat, d in df.groupby("category")}
    return {"n_pairs": len(df), "n_points": n_points, "metric": "symmetric chamfer (unit-sphere clouds), min over yaw "
            "and mirror", "median": summ, "per_category_median": per_cat,
            "frac_rigid_closer_than_own_view": round(float((df.cloth_vs_rigid < df.cloth_vs_own_other_view).mean()), 3)}


FLIPS = np.array([(1, 1, 1), (-1, 1, 1), (1, -1, 1), (-1, -1, 1)], np.float32)
"""The 4 sign flips of a footprint's principal axes (x, y; z kept)."""


def _sheet_clouds(clouds: np.ndarray, index, n_points: int):
    """The flex sheets' untransformed clouds of a set, back in metres (unit-sphere cloud x radius: what the policy's
    shape and size embedding see together), centred, the footprint's principal axes along x / y:
    (rows of ``index``, array (n, n_points, 3))."""
    rows = index[(index.material == "deformable") & (index["transform"] == "original")]
    out = []
    for i in rows.index:
        p = np.asarray(clouds[i][:n_points], np.float64) * float(index.loc[i, "radius"])
        p = p - p.mean(0)
        _, vec = np.linalg.eigh(np.cov(p[:, :2].T))
        out.append(np.concatenate([p[:, :2] @ vec[:, ::-1], p[:, 2:]], 1))
    return rows, np.asarray(out, np.float32)


def sheet_neighbours(train_dir: Path, query_dir: Path, n_points: int = 512) -> dict:
    """Can a cloud tell the flex sheets' labels apart?  Every flex sheet of the query set (``--set``) against every
    flex sheet of the training set: the symmetric chamfer distance of the metric clouds (min over the 4 flips of the
    footprint's principal axes), the label of the nearest training cloud (1-NN), and for a TRAIN object in fresh
    placements the distance to its own training views against the nearest object of another label (the margin a
    classifier must resolve to call it right)."""
    import pandas as pd
    import torch

    from flatlab_lerobot.learning.strategy_set import load

    tr_clouds, tr_index, _ = load(train_dir)
    q_clouds, q_index, _ = load(query_dir)
    refs, R = _sheet_clouds(tr_clouds, tr_index, n_points)
    queries, Q = _sheet_clouds(q_clouds, q_index, n_points)
    if not len(refs) or not len(queries):
        raise ValueError(f"--sheet-neighbours: {train_dir if not len(refs) else query_dir} has no flex sheet")
    bad = sorted(set(refs.split) - {"train"})
    if bad:
        raise ValueError(f"--sheet-neighbours {train_dir}: holds {bad} objects; the training set must be TRAIN only")
    ref_t = torch.as_tensor(R)
    label_of = refs.groupby("object_id").strategy.first()  # one label per training object
    rows = []
    for (_, row), q in zip(queries.iterrows(), Q):
        best = None
        for flip in FLIPS:
            D = torch.cdist(torch.as_tensor(q * flip).expand(len(ref_t), -1, -1), ref_t)
            d = (D.min(2).values.mean(1) + D.min(1).values.mean(1)) / 2
            best = d if best is None else torch.minimum(best, d)
        d = pd.Series(best.numpy() * 1000.0, index=refs.index)
        per_obj = d.groupby(refs.object_id).min()
        nn = refs.loc[d.idxmin()]
        own = per_obj.get(row.object_id)
        other = per_obj[label_of[per_obj.index] != row.strategy]
        rows.append({"object_id": row.object_id, "split": row.split, "category": row.category, "label": row.strategy,
                     "view": int(row["view"]), "nn_object": nn.object_id, "nn_label": nn.strategy,
                     "nn_mm": round(float(d.min()), 2), "own_mm": None if own is None else round(float(own), 2),
                     "other_label_mm": round(float(other.min()), 2) if len(other) else None,
                     "other_label_object": other.idxmin() if len(other) else None})  # fmt: skip
    df = pd.DataFrame(rows)
    per_split = {}
    for s, g in df.groupby("split"):
        per_split[s] = {"n": len(g), "nn_label_right": int((g.label == g.nn_label).sum()),
                        "nn_mm_range": [float(g.nn_mm.min()), float(g.nn_mm.max())]}  # fmt: skip
        if s == "train":
            per_split[s]["own_nearer_than_other_label"] = int((g.own_mm < g.other_label_mm).sum())
    per_object = {}
    for o, g in df.groupby("object_id", sort=False):
        per_object[o] = {"split": g.split.iloc[0], "label": g.label.iloc[0], "nn": "".join(g.nn_label),
                         "nn_objects": sorted(set(g.nn_object)), "nn_mm_median": round(float(g.nn_mm.median()), 2),
                         "other_label_object": g.other_label_object.mode().iloc[0],
                         "other_label_mm_median": round(float(g.other_label_mm.median()), 2)}  # fmt: skip
        if g.own_mm.notna().all():
            per_object[o]["own_mm_median"] = round(float(g.own_mm.median()), 2)
    return {"train_set": str(train_dir), "query_set": str(query_dir), "n_points": n_points,
            "n_train_clouds": len(refs), "n_query_clouds": len(queries),
            "metric": "symmetric chamfer (mm) of metric clouds (unit-sphere cloud x radius), centred, footprint axes "
            "aligned, min over their 4 sign flips; flex sheets only, untransformed",
            "per_split": per_split, "per_object": per_object}  # fmt: skip


# ------------------------------------------------------------------------------ summary
PAPER = {"cpu": (99.2, 91.3, 78.6), "paper": (99.2, 91.3, 78.6), "ablation_A1": (97.1, 88.0, 77.3),
         "ablation_A2": (99.2, 91.3, 71.4), "ablation_A3": (99.2, 90.7, 70.5), "ablation_A7": (94.8, 82.3, 56.4),
         "ablation_A8": (85.7, 79.3, 70.5)}  # fmt: skip
"""Table 2 of the paper (Train / Test-alpha / Test-beta strategy accuracy, %): Full and A-1..A-8."""


def summarize(paths) -> str:
    """A markdown table of ``strategy_<recipe>.json`` results beside the paper's numbers."""
    lines = ["| recipe | train wall (s) | selected step | val acc | Train (catalog / paper label) | Test-α | Test-β | "
             "paper Train / α / β |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for p in paths:
        d = json.loads(Path(p).read_text())
        name = Path(p).stem.removeprefix("strategy_")
        ps = d.get("per_split", {})

        def cell(split, ps=ps):
            m = ps.get(split)
            return "-" if m is None else f"{m['acc_catalog']} / {m['acc_paper']}"

        sel = d.get("selection") or {}
        val = (sel.get("scores") or {}).get(sel.get("selected"), {}).get("val_acc")
        wall = (d.get("training") or {}).get("train_wall_s")
        lines.append(f"| {name} | {wall} | {sel.get('selected')} | {val} | {cell('train')} | {cell('test_alpha')} | "
                     f"{cell('test_beta')} | {' / '.join(map(str, PAPER.get(name, ())))} |")  # fmt: skip
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ CLI
def _git_commit() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).resolve().parent).stdout.strip()  # fmt: skip
    except Exception:  # noqa: BLE001
        return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="flatlab strategy-eval", description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", type=Path, help="pretrained_model folder, or a lerobot-train output folder (select)")
    ap.add_argument("--set", type=Path, help="strategy set of the benchmark objects in fresh placements")
    ap.add_argument("--ambiguity", type=Path, help="strategy set with cloths and rigid counterparts: measure them")
    ap.add_argument("--sheet-neighbours", type=Path, metavar="TRAIN_SET",
                    help="strategy set of TRAIN objects: the flex sheets of --set against its flex sheets (1-NN)")
    ap.add_argument("--out", type=Path, help="JSON file to write")
    ap.add_argument("--label", default="", help="free text stored in the JSON (e.g. the recipe)")
    ap.add_argument("--train-wall", type=Path, help="JSON written next to the training run (wall time, command): "
                    "copied into the result as 'training'")
    ap.add_argument("--summarize", nargs="+", type=Path, help="result JSONs: print a markdown table and exit")
    ap.add_argument("--average-last", type=int_at_least(1), default=0, metavar="K",
                    help="with a lerobot-train output folder: evaluate the mean of its last K checkpoints' weights "
                    "(written to checkpoints/average_lastK/pretrained_model) instead of the checkpoint chosen on "
                    "validation")
    ap.add_argument("--tta", type=int, default=None,
                    help="inference passes averaged (flatlab_strategy `tta`; default: the checkpoint's config)")
    args = ap.parse_args(argv)
    if args.tta is not None and not 1 <= args.tta <= 64:
        ap.error(f"--tta {args.tta}: must be in [1, 64]")
    if args.summarize:
        text = summarize(args.summarize)
        if args.out:
            args.out.write_text(text)
        print(text, end="")
        return 0
    if not (args.policy or args.ambiguity or args.sheet_neighbours):
        ap.error("give --policy (with --set), --sheet-neighbours (with --set) and/or --ambiguity")
    for flag, given in (("--policy", args.policy), ("--sheet-neighbours", args.sheet_neighbours)):
        if given and not args.set:
            ap.error(f"{flag} needs --set (the evaluation strategy set)")
    t0 = time.perf_counter()
    res: dict = {"command": "flatlab strategy-eval " + " ".join(sys.argv[1:] if argv is None else argv),
                 "label": args.label}  # fmt: skip
    try:
        if args.policy:
            from flatlab_lerobot.learning.strategy_set import load

            path, sel = args.policy, None
            if (args.policy / "checkpoints").is_dir():
                path, sel = select_checkpoint(args.policy, args.average_last)
            elif args.average_last:
                raise ValueError(f"--average-last needs a lerobot-train output folder; {args.policy} has no checkpoints/")
            policy = load_policy(path)
            if args.tta is not None:
                policy.config.check_tta(args.tta, f"--tta ({path})")
                policy.config.tta = args.tta
            _, index, meta = load(args.set)
            logits = predict(policy, set_inputs(policy, args.set))
            res.update({"policy": str(path), "selection": sel, "tta": int(policy.config.tta), "eval_set": str(args.set),
                        "eval_set_seed": meta.get("seed"), "eval_set_views": meta["settings"].get("views"),
                        **metrics(index, [LETTERS[i] for i in logits.argmax(1)])})  # fmt: skip
            tc = path / "train_config.json"
            if tc.is_file():
                t = json.loads(tc.read_text())
                res["train"] = {"seed": t.get("seed"), "steps": t.get("steps"), "batch_size": t.get("batch_size"),
                                "dataset_root": t["dataset"].get("root")}  # fmt: skip
        if args.train_wall:
            res["training"] = json.loads(args.train_wall.read_text())
        if args.ambiguity:
            res["ambiguity"] = ambiguity(args.ambiguity)
        if args.sheet_neighbours:
            res["sheet_neighbours"] = sheet_neighbours(args.sheet_neighbours, args.set)
    except (FileNotFoundError, ValueError, KeyError, json.JSONDecodeError) as exc:
        ap.error(str(exc))
    res.update({"wall_s": round(time.perf_counter() - t0, 1), "machine": MACHINE, "git_commit": _git_commit(),
                "python": platform.python_version(), "cpu_count": os.cpu_count()})  # fmt: skip
    text = json.dumps(res, indent=1) + "\n"
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    for split, m in res.get("per_split", {}).items():
        print(f"{split:11s} n={m['n']:4d}  acc(catalog) {m['acc_catalog']}%  acc(paper) {m['acc_paper']}%  "
              f"confusion {m['confusion_catalog']}")  # fmt: skip
    if "ambiguity" in res:
        print("ambiguity (median chamfer):", res["ambiguity"]["median"])
    for split, m in res.get("sheet_neighbours", {}).get("per_split", {}).items():
        own = m.get("own_nearer_than_other_label")
        print(f"sheets {split:11s} n={m['n']:3d}  1-NN label right {m['nn_label_right']}  nearest {m['nn_mm_range']} mm"
              + ("" if own is None else f"  own views nearer than another label's: {own}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The dataset card (``README.md``): rendered from ``datasets/card_template.md`` (found through
:mod:`flatlab_lerobot.paths`, shipped in the wheel) and the dataset's own records."""

from __future__ import annotations

import json


from flatlab_lerobot.collect.recipe import Recipe, RecipeError
from flatlab_lerobot.paths import CARD_TEMPLATE, portable_name
from flatlab_lerobot.collect.features import build_features

CARD_TAGS = ("LeRobot", "FlatLab", "mujoco", "bimanual", "grasping")
CARD_MAX_EPISODE_ROWS = 200  # the card's episode table; every record is in meta/flatlab_episodes.jsonl


def _md_table(header: list[str], rows: list[list]) -> str:
    def cell(v) -> str:
        return str(v).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def _rate(ok: int, n: int) -> str:
    return f"{100 * ok / n:.1f}%" if n else "n/a"


def _size_category(n: int) -> str:
    """The hub's ``size_categories`` value for ``n`` rows (frames)."""
    bounds = ["", "1K", "10K", "100K", "1M", "10M", "100M", "1B", "10B", "100B", "1T"]
    for i in range(1, len(bounds)):
        if n < 10 ** (i + 2):
            return f"n<{bounds[i]}" if i == 1 else f"{bounds[i - 1]}<n<{bounds[i]}"
    return "n>1T"


_CATALOG: list[dict] = []  # the catalog, loaded once per process (~0.3 s; the card is rendered at every commit)


def _catalog_rows(object_ids: list[str]) -> dict[str, dict]:
    """name / category / split / material / label of each object from the current catalog ('?' when gone)."""
    from flatlab_lerobot.catalog import load_objects

    if not _CATALOG:
        try:
            _CATALOG.append(load_objects())
        except Exception:  # noqa: BLE001 -- the card must still render from the dataset's own files
            _CATALOG.append({})
    cat = _CATALOG[0]
    out = {}
    for oid in object_ids:
        o = cat.get(oid)
        out[oid] = (
            {"name": o.name or oid, "category": o.category, "split": o.split, "material": o.material,
             "label": o.strategy}
            if o is not None
            else dict.fromkeys(("name", "category", "split", "material", "label"), "?")
        )  # fmt: skip
    return out


def _group_table(key_rows: list[tuple[str, dict]], records: list[dict], what: str) -> str:
    """``what`` | objects | episodes | successful | rate, one row per distinct key."""
    groups: dict[str, dict] = {}
    for oid, key in key_rows:
        groups.setdefault(key, {"objects": set(), "n": 0, "ok": 0})["objects"].add(oid)
    obj_key = dict(key_rows)
    for r in records:
        g = groups[obj_key[r["object_id"]]] if r["object_id"] in obj_key else None
        if g is not None:
            g["n"] += 1
            g["ok"] += bool(r["success"])
    return _md_table(
        [what, "objects", "episodes", "successful", "success rate"],
        [[k, len(g["objects"]), g["n"], g["ok"], _rate(g["ok"], g["n"])] for k, g in sorted(groups.items())],
    )


def _train_command(recipe: Recipe, repo_id: str, feats: dict) -> str:
    """``lerobot-train`` for act on state + RGB (depth and clouds are not inputs act/diffusion accept)."""
    inputs = {"observation.state": {"type": "STATE", "shape": list(feats["observation.state"]["shape"])}}
    for k, v in feats.items():
        if k.startswith("observation.images.") and v["dtype"] in ("video", "image"):
            h, w, c = v["shape"]
            inputs[k] = {"type": "VISUAL", "shape": [c, h, w]}
    if len(inputs) == 1 and "observation.environment_state" in feats:  # act needs an image or the env state
        inputs["observation.environment_state"] = {
            "type": "ENV", "shape": list(feats["observation.environment_state"]["shape"]),
        }  # fmt: skip
    return " \\\n  ".join(
        [
            "lerobot-train --policy.type=act",
            f"--dataset.repo_id={repo_id} --dataset.video_backend=pyav",
            f"--policy.input_features='{json.dumps(inputs, separators=(',', ':'))}'",
            f"--policy.push_to_hub=false --output_dir=outputs/train/{recipe.name}_act --steps=100000 --batch_size=8",
        ]
    )


def render_card(
    recipe: Recipe,
    meta: dict,
    records: list[dict],
    *,
    repo_id: str | None = None,
    tags: list[str] | tuple[str, ...] = (),
    license: str = "apache-2.0",
    info: dict | None = None,
) -> str:
    """The dataset card (``README.md``): hub YAML header, objects with category / split / strategy,
    splits, strategies, failure-reason histogram, features, cameras, how to load and train, episode
    table, recipe.  ``info`` is ``meta/info.json`` (its features and frame count win when given);
    ``repo_id`` / ``tags`` / ``license`` are the hub target's (``flatlab push``)."""
    from huggingface_hub import DatasetCardData

    p = CARD_TEMPLATE
    template = p.read_text()
    repo_id = repo_id or recipe.repo_id
    saved = [r for r in records if r.get("dataset_episode_index") is not None]
    n_att, n_saved = len(records), len(saved)
    n_ok = sum(1 for r in records if r["success"])
    n_ok_saved = sum(1 for r in saved if r["success"])
    total_frames = int(info["total_frames"]) if info else sum(int(r["num_frames"]) for r in saved)
    feats = info["features"] if info else build_features(recipe)

    # objects: catalog facts + what this dataset holds for each
    object_ids = list(dict.fromkeys([*recipe.objects, *(r["object_id"] for r in records)]))
    cat = _catalog_rows(object_ids)
    obj_rows = []
    for oid in object_ids:
        rs = [r for r in records if r["object_id"] == oid]
        used = ", ".join(sorted({r["strategy"] for r in rs})) or "-"
        ok = sum(1 for r in rs if r["success"])
        c = cat[oid]
        obj_rows.append([f"`{oid}`", c["name"], c["category"], c["split"], c["material"], c["label"], used,
                         len(rs), ok, _rate(ok, len(rs))])  # fmt: skip
    object_table = _md_table(
        ["object", "name", "category", "split", "material", "label", "strategy used", "episodes", "successful",
         "success rate"], obj_rows,
    )  # fmt: skip
    split_table = _group_table([(o, cat[o]["split"]) for o in object_ids], records, "split")
    strat_groups: dict[str, list[int]] = {}
    for r in records:
        g = strat_groups.setdefault(r["strategy"], [0, 0])
        g[0] += 1
        g[1] += bool(r["success"])
    strategy_table = _md_table(
        ["strategy", "episodes", "successful", "success rate"],
        [[s, n, ok, _rate(ok, n)] for s, (n, ok) in sorted(strat_groups.items())],
    )
    reasons: dict[str, int] = {}
    for r in records:
        if not r["success"]:
            key = r.get("failure_reason") or "(no reason recorded)"
            reasons[key] = reasons.get(key, 0) + 1
    failure_table = (
        _md_table(["failure reason", "episodes", "share of attempted"],
                  [[k, n, _rate(n, n_att)] for k, n in sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0]))])
        if reasons else "No failed episode."
    )  # fmt: skip

    ep_rows = [
        ["-" if r["dataset_episode_index"] is None else r["dataset_episode_index"], r["seed"], r["object_id"],
         r["strategy"], r["num_frames"], r["success"], r.get("failure_reason") or ""]
        for r in records[:CARD_MAX_EPISODE_ROWS]
    ]  # fmt: skip
    episode_table = _md_table(["#", "seed", "object", "strategy", "frames", "success", "failure reason"], ep_rows)
    if n_att > CARD_MAX_EPISODE_ROWS:
        episode_table += f"\n\n({n_att - CARD_MAX_EPISODE_ROWS} more in `meta/flatlab_episodes.jsonl`.)"
    feature_table = _md_table(
        ["key", "dtype", "shape"], [[f"`{k}`", v["dtype"], tuple(v["shape"])] for k, v in feats.items()]
    )
    cams = meta.get("cameras") or {}
    camera_table = (
        _md_table(["camera", "width x height", "fx", "fy", "cx", "cy"],
                  [[f"`{c}`", f"{m['width']} x {m['height']}", f"{m['fx']:.2f}", f"{m['fy']:.2f}", f"{m['cx']:.2f}",
                    f"{m['cy']:.2f}"] for c, m in cams.items()])
        if cams else "No camera."
    )  # fmt: skip
    splits = sorted({cat[o]["split"] for o in object_ids})
    has_depth = any(k.startswith("observation.depth.") for k in feats)
    train_note = (
        "The command feeds act the joint state and the RGB cameras only: depth maps are 1-channel images "
        "and point clouds are (N, 3) arrays, which act's and diffusion's image encoders do not take. "
        "Add `--policy.pretrained_backbone_weights=null` on a machine that cannot reach download.pytorch.org."
    )
    if has_depth:
        train_note += " Depth decodes in mm by default (`--dataset.depth_output_unit=m` for metres)."
    dataset_structure = (
        "[meta/info.json](meta/info.json):\n\n<details><summary>meta/info.json</summary>\n\n```json\n"
        + json.dumps(info, indent=2) + "\n```\n\n</details>"
        if info else "See `meta/info.json` (LeRobotDataset v3: `data/`, `videos/`, `meta/`)."
    )  # fmt: skip
    card_data = DatasetCardData(
        license=license,
        task_categories=["robotics"],
        size_categories=[_size_category(total_frames)],
        pretty_name=recipe.name,
        tags=list(dict.fromkeys([*CARD_TAGS, *tags])),
        configs=[{"config_name": "default", "data_files": "data/*/*.parquet"}],
    ).to_yaml()
    duration = total_frames / recipe.fps
    values = {
        "card_data": card_data,
        "name": recipe.name,
        "repo_id": repo_id,
        "codebase_version": (info or {}).get("codebase_version", "v3.0"),
        "description": recipe.description or "Scripted-expert demonstrations of grasping flat objects.",
        "recipe_source": portable_name(meta.get("recipe_source", recipe.source)),
        "package_version": _package_version(),
        "camera_note": _camera_note(feats, bool(cams)),
        "fingerprint": meta.get("recipe_fingerprint", recipe.fingerprint()),
        "fps": recipe.fps,
        "robot_type": recipe.robot_type,
        "cameras": ", ".join(recipe.cameras) or "none",
        "image_size": recipe.image_size,
        "modalities": ", ".join(recipe.modalities) or "state and action only",
        "objects": ", ".join(object_ids),
        "num_objects": len(object_ids),
        "splits": ", ".join(splits),
        "strategy": "per object (catalog label)" if recipe.strategy == "auto" else recipe.strategy,
        "seed": recipe.seed,
        "randomization": _randomization_text(recipe),
        "episodes_attempted": n_att,
        "episodes_saved": n_saved,
        "episodes_successful": n_ok,
        "success_rate": f"{_rate(n_ok, n_att)} ({n_ok} / {n_att})",
        "total_frames": total_frames,
        "duration": f"{duration / 60:.1f} min" if duration >= 60 else f"{duration:.1f} s",
        "object_table": object_table,
        "split_table": split_table,
        "strategy_table": strategy_table,
        "failure_table": failure_table,
        "successful_note": f"{n_ok_saved} of the {n_saved} saved episodes are successful; add "
        "`--dataset.episodes='[...]'` with the `ok` list above to train on those only",
        "train_command": _train_command(recipe, repo_id, feats),
        "train_note": train_note,
        "feature_table": feature_table,
        "camera_table": camera_table,
        "episode_table": episode_table,
        "recipe_yaml": _yaml(recipe.to_dict()),
        "dataset_structure": dataset_structure,
    }
    try:
        return template.format(**values)
    except (KeyError, IndexError, ValueError) as exc:
        raise RecipeError(f"{p}: bad placeholder in the card template: {exc}") from exc


def _camera_note(feats: dict, has_cameras: bool) -> str:
    """What the camera metadata lets one rebuild, naming only the modalities this dataset has."""
    if not has_cameras:
        return "This dataset has no camera."
    note = ("Intrinsics (`fx, fy, cx, cy`, `K`) and extrinsics (`cam_to_world`, 4x4) of every camera are in "
            "`meta/flatlab.json`")  # fmt: skip
    depth = sorted(k for k in feats if k.startswith("observation.depth."))
    if depth:
        note += (f", so point clouds can be rebuilt from {', '.join(f'`{k}`' for k in depth)} "
                 "(see `flatlab_lerobot.collect.features.depth_to_points`)")  # fmt: skip
    note += "."
    clouds = [k for k in ("observation.pointcloud", "observation.object_pointcloud") if k in feats]
    if clouds:
        note += f" Point clouds are stored per frame in {' and '.join(f'`{k}`' for k in clouds)} (world frame)."
    return note


def _package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("lerobot_env_flatlab")
    except PackageNotFoundError:
        return "unknown"


def _randomization_text(recipe: Recipe) -> str:
    """The recipe's randomization ranges in words (the card's table row)."""
    r = recipe.randomization
    parts = [f"object ±{r.xy_range * 100:g} cm, yaw ±{r.yaw_range_deg:g}°"]
    if r.joint_noise:
        parts.append(f"arm joints ±{r.joint_noise:g} rad")
    if r.camera_pos_jitter or r.camera_rot_jitter_deg:
        parts.append(f"cameras ±{r.camera_pos_jitter * 100:g} cm, ±{r.camera_rot_jitter_deg:g}°")
    for name, (lo, hi) in (("mass", r.mass_scale), ("friction", r.friction_scale)):
        if (lo, hi) != (1.0, 1.0):
            parts.append(f"{name} x [{lo:g}, {hi:g}]")
    return "; ".join(parts) + " (per episode: `domain` in `meta/flatlab_episodes.jsonl`)"


def _yaml(d: dict) -> str:
    import yaml

    return yaml.safe_dump(d, sort_keys=False)

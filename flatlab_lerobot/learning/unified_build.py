"""``flatlab unified-build``: one ``flatlab_unified`` artifact from a trained strategy generator and a
trained action execution module.

    flatlab unified-build --generator outputs/train/strategy_cpu/checkpoints/last/pretrained_model \\
        --executor outputs/train/executor_cpu/checkpoints/last/pretrained_model \\
        --out outputs/unified/cpu [--strategy learned|A|B|C] \
        [--alt-executor outputs/train/executor_other/... --alt-strategies A,C]

It writes a standard ``pretrained_model`` folder -- ``config.json`` (the unified config with both
sub-configs nested), ``model.safetensors`` (``generator.*`` and ``executor.*`` weights, copied
unchanged), ``policy_preprocessor.json`` / ``policy_postprocessor.json`` -- that ``lerobot-eval
--policy.path=<out>`` and ``flatlab eval --policy <out>`` load, and ``flatlab_unified_build.json``
(sources, the Train-only check, the env flags that give the clouds the executor was trained on).

**Test objects never train it.**  Where the guarantee comes from:

* ``flatlab strategy-export`` refuses a strategy set holding a non-Train object, and
  ``flatlab primitive-export`` one holding a non-Train object (unless ``--eval-only``, which marks
  every task ``split=test_*``); ``flatlab_executor`` refuses, when ``lerobot-train`` builds it, a
  dataset whose task list names a non-Train object (``check_training_tasks``).
``--alt-executor`` adds a second trained executor that poses every stage of the strategies named by
``--alt-strategies`` (``--executor`` poses the others); it must read the clouds ``--executor`` reads, and
it is checked for Train-only data like the first.  Several folders after ``--executor`` (or
``--alt-executor``) -- the same recipe trained with other seeds -- make an ensemble: every stage that
executor poses is the mean of their predictions (``modeling_flatlab_executor.mean_predictions``).

* This builder checks again, from each sub-model's ``train_config.json`` (``lerobot-train`` writes
  it beside the weights): the dataset it names must be on this machine and hold Train objects only --
  the executor's by its task list (``check_training_tasks``) and ``flatlab_export.json``
  (``eval_only`` false), the generator's by ``meta/flatlab_strategy_frames.parquet`` (every frame's
  split and the catalog split of its base object, ``strategy_export.check_train_only``).  A sub-model
  whose dataset names a non-Train object is refused.  One whose dataset cannot be checked (no
  ``train_config.json``, e.g. a model built in a test, or a dataset not on this machine) is refused
  too, unless ``--allow-unverified``; the artifact's build record then says "unverified".
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

from flatlab_lerobot.paths import OUTPUTS_DIR

BUILD_RECORD = "flatlab_unified_build.json"
PRIMITIVE_SET_DEFAULTS = {"cameras": ["front", "top", "left", "right"], "image_size": 128}
"""``flatlab primitive-set``'s defaults: the clouds an executor is trained on when its set is not found."""


class UnifiedBuildError(ValueError):
    """Bad input; the message names the flag / file and field."""


def resolve_pretrained(path: Path, flag: str) -> Path:
    """A ``pretrained_model`` folder: the folder itself, ``<it>/pretrained_model`` or a training
    output's ``checkpoints/last/pretrained_model``."""
    p = Path(path).expanduser()
    for cand in (p, p / "pretrained_model", p / "checkpoints" / "last" / "pretrained_model"):
        if (cand / "config.json").is_file():
            if not (cand / "model.safetensors").is_file():
                raise UnifiedBuildError(f"{flag} {path}: {cand / 'model.safetensors'} missing")
            return cand
    raise UnifiedBuildError(f"{flag} {path}: no config.json there (want a LeRobot pretrained_model folder)")


def _load_config(path: Path, want: str, flag: str):
    from lerobot.configs.policies import PreTrainedConfig

    import flatlab_lerobot.policies.unified.configuration_flatlab_unified  # noqa: F401  registers the three types

    cfg = PreTrainedConfig.from_pretrained(path)
    if cfg.type != want:
        raise UnifiedBuildError(f"{flag} {path}: config.json field 'type' is {cfg.type!r}, expected {want!r}")
    return cfg


def _train_dataset(path: Path) -> tuple[Path | None, str]:
    """(local root of the dataset named in ``train_config.json``, why not found)."""
    tc = path / "train_config.json"
    if not tc.is_file():
        return None, f"{tc} missing"
    try:
        ds = json.loads(tc.read_text()).get("dataset") or {}
    except json.JSONDecodeError as e:
        return None, f"{tc}: not JSON ({e})"
    root = ds.get("root")
    if root:
        root = Path(root)
    else:  # lerobot's default location of a repo id
        from lerobot.utils.constants import HF_LEROBOT_HOME

        root = Path(HF_LEROBOT_HOME) / str(ds.get("repo_id"))
    if not (root / "meta" / "info.json").is_file():
        return None, f"{tc}: field 'dataset' names {root}, which is not on this machine"
    return root, ""


def check_executor_data(path: Path, flag: str = "--executor") -> dict:
    """The executor's training dataset holds Train objects only (raises), or why that is unknown."""
    from lerobot.datasets.io_utils import load_tasks

    from flatlab_lerobot.policies.executor.configuration_flatlab_executor import (
        TASK_RE, PrimitiveExportError, check_training_tasks,
    )  # fmt: skip

    root, why = _train_dataset(path)
    if root is None:
        return {"verified": False, "reason": why}
    export = root / "flatlab_export.json"
    summary = json.loads(export.read_text()) if export.is_file() else {}
    if summary.get("eval_only"):
        raise UnifiedBuildError(f"{flag} {path}: trained on {root}, an --eval-only export ({export}: "
                                "field 'eval_only' is true): Test objects never train the unified policy")  # fmt: skip

    meta = SimpleNamespace(root=root, tasks=load_tasks(root))  # what check_training_tasks reads of the metadata
    try:
        check_training_tasks(meta)
    except PrimitiveExportError as e:
        raise UnifiedBuildError(f"{flag} {path}: {e}") from e
    objects = sorted({TASK_RE.match(str(t))["object"] for t in meta.tasks.index})
    return {"verified": True, "dataset": str(root.resolve()), "objects": objects, "export": summary}


def check_generator_data(path: Path) -> dict:
    """The generator's training dataset holds Train objects only (raises), or why that is unknown."""
    import pandas as pd

    from flatlab_lerobot.learning.strategy_export import FRAMES_FILE, check_train_only

    root, why = _train_dataset(path)
    if root is None:
        return {"verified": False, "reason": why}
    frames = root / FRAMES_FILE
    if not frames.is_file():
        return {"verified": False, "reason": f"{frames} missing: not a `flatlab strategy-export` dataset"}
    index = pd.read_parquet(frames)
    try:
        check_train_only(index, root)
    except ValueError as e:
        raise UnifiedBuildError(f"--generator {path}: {e}") from e
    return {"verified": True, "dataset": str(root.resolve()), "objects": sorted(set(index.base_object_id))}


def cloud_settings(executor_check: dict, n_points: int, n_object_points: int) -> dict:
    """The env settings that give the clouds the executor was trained on: from its primitive set's
    ``meta.json`` when found, else the primitive set's defaults (marked ``assumed``)."""
    out = {"n_points": n_points, "n_object_points": n_object_points, **PRIMITIVE_SET_DEFAULTS, "assumed": True}
    src = (executor_check.get("export") or {}).get("source")
    meta = Path(src) / "meta.json" if src else None
    if meta is not None and meta.is_file():
        s = json.loads(meta.read_text()).get("settings", {})
        out.update(cameras=list(s.get("cameras", out["cameras"])), image_size=int(s.get("image_size", out["image_size"])),
                   control_dt=float(s.get("control_dt", 0.1)), assumed=False)  # fmt: skip
    return out


def env_flags(settings: dict) -> list[str]:
    cams = ",".join(settings["cameras"])
    return [f"--env.pointcloud_cameras=[{cams}]", f"--env.image_size={settings['image_size']}",
            f"--env.n_points={settings['n_points']}", f"--env.n_object_points={settings['n_object_points']}",
            "--env.obs_pixels=false"]  # fmt: skip


def _flag(key: str) -> str:
    """The command-line flag behind a sub-model key: "executor_members.0" -> "--executor (member 1)"."""
    name, _, i = key.partition("_members.")
    return f"--{name.replace('_', '-')}" + (f" (member {int(i) + 1})" if i else "")


def _paths(x) -> list[Path]:
    """One path or a sequence of them (an ensemble: the first leads, the rest are its members)."""
    if x is None:
        return []
    return [Path(x)] if isinstance(x, (str, Path)) else [Path(p) for p in x]


def build(generator: Path, executor: Path | list[Path], out: Path, strategy: str = "learned",
          allow_unverified: bool = False, device: str = "cpu", object_points: int | None = None,
          alt_executor: Path | list[Path] | None = None, alt_strategies: tuple[str, ...] | list[str] = (),
          log=print) -> dict:  # fmt: skip
    """Write the artifact; returns the build record (also ``<out>/flatlab_unified_build.json``).

    ``executor`` / ``alt_executor``: one ``pretrained_model`` folder, or several of the same recipe
    (other seeds): the first is the executor, the others its ensemble members (predictions averaged)."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.utils.constants import ACTION, OBS_STATE
    from safetensors.torch import load_file

    from flatlab_lerobot.lerobot_env import OBS_CELL, OBS_OBJECT_POINTCLOUD, OBS_POINTCLOUD
    from flatlab_lerobot.policies.executor.configuration_flatlab_executor import OBS_OBJECT_CLOUD
    from flatlab_lerobot.policies.unified.configuration_flatlab_unified import (
        CELL_DIM, STATE_DIM, STRATEGY_CHOICES, FlatLabUnifiedConfig, check_alt_strategies, executor_input_mismatch,
    )  # fmt: skip
    from flatlab_lerobot.policies.unified.modeling_flatlab_unified import FlatLabUnifiedPolicy
    from flatlab_lerobot.policies.unified.processor_flatlab_unified import make_flatlab_unified_pre_post_processors

    t0 = time.perf_counter()
    if strategy not in STRATEGY_CHOICES:
        raise UnifiedBuildError(f"--strategy {strategy!r}: must be one of {list(STRATEGY_CHOICES)}")
    gen_dir = resolve_pretrained(generator, "--generator")
    gen_cfg = _load_config(gen_dir, "flatlab_strategy", "--generator")
    checks = {"generator": check_generator_data(gen_dir)}
    ex_paths, alt_paths = _paths(executor), _paths(alt_executor)
    if not ex_paths:
        raise UnifiedBuildError("--executor: give at least one pretrained_model folder")
    alt_strategies = [str(x).strip() for x in alt_strategies if str(x).strip()]
    try:
        check_alt_strategies(alt_strategies, bool(alt_paths), "--alt-strategies (with --alt-executor)")
    except ValueError as e:
        raise UnifiedBuildError(str(e)) from e
    dirs, cfgs = {}, {}  # "executor", "executor_members.0", ..., "alt_executor", "alt_executor_members.0", ...
    for name, paths in (("executor", ex_paths), ("alt_executor", alt_paths)):
        flag = f"--{name.replace('_', '-')}"
        for i, path in enumerate(paths):
            key = name if i == 0 else f"{name}_members.{i - 1}"
            dirs[key] = resolve_pretrained(path, flag)
            cfgs[key] = _load_config(dirs[key], "flatlab_executor", flag)
            checks[key] = check_executor_data(dirs[key], flag)
            why = executor_input_mismatch(cfgs[name], cfgs[key]) if i else ""
            if why:
                raise UnifiedBuildError(f"{flag} {dirs[key]}: {why}: an ensemble's members must read the same inputs")
    ex_dir, ex_cfg = dirs["executor"], cfgs["executor"]
    alt_dir, alt_cfg = dirs.get("alt_executor"), cfgs.get("alt_executor")
    unverified = {k: v["reason"] for k, v in checks.items() if not v["verified"]}
    if unverified and not allow_unverified:
        raise UnifiedBuildError(
            "cannot check that these sub-models were trained on Train objects only: "
            + "; ".join(f"{_flag(k)}: {why}" for k, why in unverified.items())
            + " (--allow-unverified builds anyway and records it)"
        )
    for sub in (gen_cfg, *cfgs.values()):
        sub.device, sub.pretrained_path = device, None
    ex_feats = ex_cfg.input_features
    if OBS_POINTCLOUD not in ex_feats:
        raise UnifiedBuildError(f"--executor {ex_dir}: config.json has no input feature {OBS_POINTCLOUD!r}")
    for name, other in cfgs.items():
        flag = "--alt-executor" if name.startswith("alt") else "--executor"
        for key in (OBS_POINTCLOUD, OBS_OBJECT_CLOUD):
            a, b = ex_feats.get(key), other.input_features.get(key)
            if (a is None) != (b is None) or (a is not None and tuple(a.shape) != tuple(b.shape)):
                raise UnifiedBuildError(
                    f"{flag} {dirs[name]}: config.json input feature {key!r} is "
                    f"{None if b is None else tuple(b.shape)}, --executor's {None if a is None else tuple(a.shape)}: "
                    "every executor must read the same clouds"
                )
    n = tuple(ex_feats[OBS_POINTCLOUD].shape)
    obj_ft = ex_feats.get(OBS_OBJECT_CLOUD) or gen_cfg.input_features.get(gen_cfg.input_key)
    k = tuple(obj_ft.shape) if obj_ft is not None else (256, 3)
    if object_points is not None:  # a denser observed object cloud: the generator FPS-resamples it
        if object_points < 16:
            raise UnifiedBuildError(f"--object-points {object_points}: must be >= 16")
        k = (int(object_points), 3)
    cfg = FlatLabUnifiedConfig(
        generator=gen_cfg, executor=ex_cfg, strategy=strategy, device=device, push_to_hub=False,
        alt_executor=alt_cfg, alt_executor_strategies=list(alt_strategies),
        executor_members=[c for k, c in cfgs.items() if k.startswith("executor_members.")],  # in flag order
        alt_executor_members=[c for k, c in cfgs.items() if k.startswith("alt_executor_members.")],
        input_features={
            OBS_STATE: PolicyFeature(FeatureType.STATE, (STATE_DIM,)),
            OBS_CELL: PolicyFeature(FeatureType.STATE, (CELL_DIM,)),
            OBS_POINTCLOUD: PolicyFeature(FeatureType.STATE, n),
            OBS_OBJECT_POINTCLOUD: PolicyFeature(FeatureType.STATE, k),
        },
        output_features={ACTION: PolicyFeature(FeatureType.ACTION, (16,))},
    )  # fmt: skip
    settings = cloud_settings(checks["executor"], n[0], k[0])
    if "control_dt" in settings:
        cfg.control_dt = settings["control_dt"]
    policy = FlatLabUnifiedPolicy(cfg)
    policy.generator.load_state_dict(load_file(str(gen_dir / "model.safetensors")), strict=True)
    for name, d in dirs.items():
        policy.get_submodule(name).load_state_dict(load_file(str(d / "model.safetensors")), strict=True)
    policy.eval()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    policy.save_pretrained(out)
    pre, post = make_flatlab_unified_pre_post_processors(cfg)
    pre.save_pretrained(out)
    post.save_pretrained(out)
    flags = env_flags(settings)
    record = {
        "format": "flatlab_unified_build",
        "strategy": strategy,
        "generator": str(gen_dir.resolve()),
        "executor": str(ex_dir.resolve()),
        **({"alt_executor": str(alt_dir.resolve()), "alt_strategies": list(alt_strategies)} if alt_dir else {}),
        **{k: str(d.resolve()) for k, d in dirs.items() if "_members." in k},
        "train_only_check": checks,
        "allow_unverified": bool(unverified),
        "clouds": settings,
        "env_flags": flags,
        "wall_s": round(time.perf_counter() - t0, 2),
    }
    (out / BUILD_RECORD).write_text(json.dumps(record, indent=1, default=str))
    for k_, why in unverified.items():
        log(f"[unified-build] WARNING: {_flag(k_)}: Train-only training data UNVERIFIED ({why})")
    alt = f", strategies {','.join(alt_strategies)} posed by --alt-executor" if alt_dir else ""
    if len(ex_paths) > 1 or len(alt_paths) > 1:
        alt += f", ensembles of {len(ex_paths)} / {len(alt_paths)} executors"
    log(f"[unified-build] {out}: flatlab_unified (strategy={strategy}{alt}); evaluate with\n"
        f"  flatlab eval --policy {out} --splits train,test_alpha,test_beta {' '.join(flags)}\n"
        f"  lerobot-eval --policy.path={out} --env.type=flatlab --env.object_id=<id> {' '.join(flags)}")  # fmt: skip
    return record


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="flatlab unified-build",
        description="One flatlab_unified artifact (a LeRobot pretrained_model folder) from a trained "
        "flatlab_strategy generator and a trained flatlab_executor.",
    )
    ap.add_argument("--generator", type=Path, required=True, help="the strategy generator's pretrained_model folder")
    ap.add_argument("--executor", type=Path, nargs="+", required=True,
                    help="the executor's pretrained_model folder; several (the same recipe, other seeds): an ensemble "
                    "whose poses are the mean of their predictions")
    ap.add_argument("--out", type=Path, default=OUTPUTS_DIR / "unified" / "pretrained_model", help="artifact folder")
    ap.add_argument("--strategy", default="learned", choices=("learned", "A", "B", "C"),
                    help="learned (the generator chooses) or fixed: A = learned Slide, B = learned Lift baseline")  # fmt: skip
    ap.add_argument("--allow-unverified", action="store_true",
                    help="build even when a sub-model's training data cannot be checked for Train-only objects")  # fmt: skip
    ap.add_argument("--device", default="cpu", help="the artifact's policy.device (default cpu)")
    ap.add_argument("--object-points", type=int, default=None,
                    help="the env's n_object_points the artifact expects (default: the executor's); more points than "
                    "the generator's generator_cloud_points (2048) are farthest-point resampled to it, as the strategy set is")
    ap.add_argument("--alt-executor", type=Path, nargs="+", default=None,
                    help="a second trained flatlab_executor that poses the stages of --alt-strategies (same clouds); "
                    "several: an ensemble, as --executor")
    ap.add_argument("--alt-strategies", default="",
                    help="comma-separated strategies (A, B, C) posed by --alt-executor, e.g. A,C")
    args = ap.parse_args(argv)
    try:
        build(args.generator, args.executor, args.out, args.strategy, args.allow_unverified, args.device,
              object_points=args.object_points, alt_executor=args.alt_executor,
              alt_strategies=args.alt_strategies.split(","))
    except UnifiedBuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

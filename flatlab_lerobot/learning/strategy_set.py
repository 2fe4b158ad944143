"""``flatlab strategy-set``: the strategy generator's learning set (paper §3.2, §4.1, App. B).

The paper trains its strategy generator on object clouds "uniformly sampled to 2048 points,
centered at zero, and normalized to lie on a unit sphere", built with "randomized object
placements and simulated data transformation" (1390 clouds).  This module builds that set from
the same simulation pipeline as the demonstrations:

1. objects: the catalog objects of ``--splits`` (default: train) or ``--objects``; for each, its
   variants (:func:`flatlab_lerobot.transforms.variants`): the original, ``--scales`` (7) uniform
   rescalings over its sensible range, and for a cloth the rigid counterpart of each of these
   (``--no-counterparts`` drops them).  The original keeps its catalog label; a transformed
   instance keeps it too unless the transform changes the label ``transforms.LABEL_RULE`` gives
   (then it carries the rule's new label; ``label_source`` says which).
2. per variant, ``--views`` placements (``tasks.ResetDistribution``: +-5 cm, +-30 deg yaw): the
   object is put in the cell (:class:`~flatlab_lerobot.sim.core.FlatLabSim`, arms resting at
   home), settles for ``--settle`` s, and the object-only cloud is rendered from ``--cameras``
   (``CameraRig`` segmentation + depth, ``--image-size`` pixels square; a small object that
   covers fewer pixels than ``--points`` is rendered again at 2x, then 4x that size).
3. the cloud is resampled to exactly ``--points`` (2048) points by farthest-point sampling
   (``fpsample``, seeded start point); an object seen in fewer points keeps all of them once and
   repeats seeded random ones (``n_points_raw`` tells).  It is centred on its mean and divided
   by its largest norm: every point lies in the unit ball, one on the sphere.

Files under ``--out`` (default ``outputs/learning/strategy_set``), written to a temporary
folder and renamed when complete:

* ``clouds.npy`` (N, 2048, 3) float32: the normalized clouds.
* ``index.parquet``: one row per cloud, in cloud order: ``label`` (0/1/2) and ``strategy``
  (A/B/C), ``label_source`` (catalog | catalog_kept | rule), ``catalog_strategy`` (the base object's label),
  ``object_id`` (with its transformation: ``fabric_cotton@s0.5@rigid``), ``base_object_id``,
  ``category``, ``split``, ``material``, ``shape``, ``transform`` (original | scale | rigid |
  scale+rigid), ``scale`` (1.0 for the original size), ``rigid_counterpart``, ``view``, ``seed``
  and ``placement_x/y/yaw``, ``centre_x/y/z`` (world, m) and ``radius`` (m) of the
  normalization (world point = cloud * radius + centre), ``n_points_raw`` (object pixels over
  all cameras) at ``image_size`` (the render size used), ``size_x/y/z`` and ``mass`` of the
  variant.
* ``meta.json``: counts per label / split / category / transform / material, the settings and
  seed, every base object's scale range and scales, the label rule and the catalog objects it
  disagrees with, the paper's count, and the build time.

Determinism: view ``k`` of variant ``v`` uses ``SeedSequence([seed, crc32(v), k])`` for its
placement and sampling, in a fresh simulation, so a cloud depends only on (settings, variant,
k), not on ``--workers`` or the order of work: the same command writes the same clouds and index.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
import zlib
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from flatlab_lerobot.learning import int_at_least
from flatlab_lerobot.paths import OUTPUTS_DIR

CAMERA_NAMES = ("front", "top", "left", "right")
DEFAULT_OUT = OUTPUTS_DIR / "learning" / "strategy_set"
PAPER_CLOUDS = 1390
FILES = ("clouds.npy", "index.parquet", "meta.json")
MAX_UPSCALE = 4  # an object seen in fewer than n_points pixels is rendered again at 2x, then 4x the size


@dataclass(frozen=True)
class SetConfig:
    """What to build.

    splits: catalog splits whose objects are used (ignored when ``objects`` is given).
    objects: explicit catalog ids.  n_scales: rescaled instances per object (0: originals only).
    counterparts: add the rigid counterpart of every cloth variant.  views: placements per
    variant.  seed: base seed.  cameras / image_size: the views the object cloud is rendered
    from.  settle: seconds of physics before the capture.  n_points: points per cloud.
    limit: build only the first ``limit`` variants (in plan order).
    """

    splits: tuple[str, ...] = ("train",)
    objects: tuple[str, ...] = ()
    n_scales: int = 7
    counterparts: bool = True
    views: int = 1
    seed: int = 0
    cameras: tuple[str, ...] = CAMERA_NAMES
    image_size: int = 512
    settle: float = 0.5
    n_points: int = 2048
    limit: int | None = None
    extras: tuple[str, ...] = ()  # "scene": scene_clouds.npy; "rgb": rgb.npy (ablations)


EXTRAS = ("scene", "rgb")
RGB_SIZE = 64  # px: the object's RGB crop (ablation A-7)
RGB_CAMERA = "top"


# ------------------------------------------------------------------------------ plan
def select_objects(cfg: SetConfig):
    """The base ObjectSpecs of the set, in catalog-split then id order."""
    from flatlab_lerobot.catalog import BENCHMARK_SPLITS, load_objects

    catalog = load_objects()
    if cfg.objects:
        unknown = [o for o in cfg.objects if o not in catalog]
        if unknown:
            raise ValueError(f"--objects: unknown object id(s) {unknown}; known: {sorted(catalog)}")
        return [catalog[o] for o in dict.fromkeys(cfg.objects)]
    bad = [s for s in cfg.splits if s not in BENCHMARK_SPLITS]
    if bad:
        raise ValueError(f"--splits: unknown split(s) {bad}; known: {list(BENCHMARK_SPLITS)} or 'all'")
    order = {s: i for i, s in enumerate(BENCHMARK_SPLITS)}
    objs = [o for o in catalog.values() if o.split in cfg.splits]
    return sorted(objs, key=lambda o: (order[o.split], o.id))


def plan(cfg: SetConfig):
    """(base objects, variants in build order) of ``cfg`` (``limit`` applied)."""
    from flatlab_lerobot.transforms import variants

    bases = select_objects(cfg)
    todo = [v for b in bases for v in variants(b, cfg.n_scales, cfg.counterparts)]
    if cfg.limit is not None:
        todo = todo[: cfg.limit]
        kept = {v.base.id for v in todo}
        bases = [b for b in bases if b.id in kept]
    return bases, todo


def view_seed(seed: int, variant_id: str, view: int) -> int:
    """The seed of view ``view`` of ``variant_id``: independent of the order of work."""
    return int(np.random.SeedSequence([seed, zlib.crc32(variant_id.encode()), view]).generate_state(1)[0])


# ------------------------------------------------------------------------------ clouds
def resample(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Exactly ``n`` points (float64): farthest-point sampling from a seeded start point when
    there are enough, else every point once plus seeded random repeats."""
    import fpsample

    k = len(points)
    if k == 0:
        raise ValueError("no points to sample from")
    if k < n:
        idx = np.concatenate([np.arange(k), rng.choice(k, n - k, replace=True)])
    else:
        h = int(np.clip(np.log2(k) - 8, 3, 9))  # KD-tree height: buckets of 2**h points
        idx = fpsample.bucket_fps_kdline_sampling(
            np.ascontiguousarray(points, np.float64), n, h=h, start_idx=int(rng.integers(k))
        )
    return np.asarray(points, np.float64)[np.asarray(idx, np.int64)]


def normalize(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(cloud centred on its mean and scaled into the unit ball (float32), centre, radius)."""
    centre = points.mean(axis=0)
    q = points - centre
    radius = float(np.linalg.norm(q, axis=1).max())
    if radius <= 0:
        raise ValueError("degenerate cloud: all points coincide")
    return (q / radius).astype(np.float32), centre, radius


def _object_cloud(sim, rigs: dict, cfg: SetConfig) -> tuple[np.ndarray, int]:
    """(raw world-frame object points, image size used): rendered at ``cfg.image_size``, and at
    2x / 4x that size while the object covers fewer pixels than ``cfg.n_points`` (small scales)."""
    from flatlab_lerobot.sim.cameras import CameraRig

    size = cfg.image_size
    while True:
        rig = rigs.get(size)
        if rig is None:
            vis = sim.model.vis.global_  # the offscreen buffer must hold the image
            vis.offwidth, vis.offheight = max(vis.offwidth, size), max(vis.offheight, size)
            rig = rigs[size] = CameraRig(sim.model, size, size, cfg.cameras)
        rig.invalidate()
        raw = rig.object_points(sim.data, sim.obj_geoms, sim.flex_id)
        if len(raw) >= cfg.n_points or size >= MAX_UPSCALE * cfg.image_size:
            return raw, size
        size *= 2


def _extras(sim, rigs: dict, cfg: SetConfig, rng: np.random.Generator) -> dict:
    """The opt-in extra views of one placement: ``scene`` (the whole scene cloud of ``cfg.cameras``
    cropped to the workspace above the table, resampled and normalized like the object cloud) and
    ``rgb`` (the object's pixels in the ``top`` camera, background black, cropped to a square
    around the object and resized to RGB_SIZE px, uint8)."""
    from flatlab_lerobot.sim.cameras import crop

    out = {}
    rig = rigs[cfg.image_size]
    if "scene" in cfg.extras:
        tx, ty = sim.cell.table_size
        h = sim.cell.table_height
        pts = crop(rig.scene_points(sim.data), [-tx / 2, -ty / 2, h - 0.005], [tx / 2 + 0.15, ty / 2, h + 0.6])
        out["scene"] = normalize(resample(pts, cfg.n_points, rng))[0]
    if "rgb" in cfg.extras:
        fr = rig.capture(sim.data, RGB_CAMERA, segmentation=True, rgb=True)
        mask = rig.object_mask(fr.seg, sim.obj_geoms, sim.flex_id)
        img = np.where(mask[..., None], fr.rgb, 0).astype(np.uint8)
        ys, xs = np.nonzero(mask)
        if len(ys):
            cy, cx = (ys.min() + ys.max()) / 2, (xs.min() + xs.max()) / 2
            half = max(ys.max() - ys.min(), xs.max() - xs.min()) / 2 + 1
        else:
            cy = cx = half = mask.shape[0] / 2
        grid = (np.arange(RGB_SIZE) + 0.5) / RGB_SIZE * 2 - 1
        yy = np.clip(np.round(cy + grid * half).astype(int), 0, mask.shape[0] - 1)
        xx = np.clip(np.round(cx + grid * half).astype(int), 0, mask.shape[1] - 1)
        out["rgb"] = img[yy][:, xx]
    return out


def capture_variant(variant, cfg: SetConfig) -> tuple[np.ndarray, list[dict]]:
    """Clouds ((views, n_points, 3) float32) and index rows of one variant: one fresh simulation,
    ``cfg.views`` placements."""
    from flatlab_lerobot.sim.core import FlatLabSim
    from flatlab_lerobot.tasks import ResetDistribution
    from flatlab_lerobot.transforms import LABEL_INDEX

    spec = variant.spec
    sim = FlatLabSim(spec)
    rigs: dict = {}
    clouds, rows = [], []
    extras: dict = {k: [] for k in cfg.extras}
    try:
        for view in range(cfg.views):
            seed = view_seed(cfg.seed, spec.id, view)
            x, y, yaw = ResetDistribution().sample(seed)
            sim.reset(x, y, yaw, settle=cfg.settle)
            if not spec.deformable:
                low = float(sim.object_points()[:, 2].min() - sim.cell.table_height)
                if low < -0.01:
                    raise RuntimeError(
                        f"object '{spec.id}' view {view}: fell off the table while settling ({low:+.3f} m)"
                    )
            raw, image_size = _object_cloud(sim, rigs, cfg)
            if len(raw) == 0:
                raise RuntimeError(f"object '{spec.id}' view {view}: not seen by cameras {list(cfg.cameras)}")
            rng = np.random.default_rng(seed)
            cloud, centre, radius = normalize(resample(raw, cfg.n_points, rng))
            for k, v in _extras(sim, rigs, cfg, rng).items():
                extras[k].append(v)
            strategy = variant.strategy
            clouds.append(cloud)
            rows.append({
                "label": LABEL_INDEX[strategy], "strategy": strategy, "label_source": variant.label_source,
                "catalog_strategy": variant.base.strategy, "object_id": spec.id, "base_object_id": variant.base.id,
                "category": spec.category, "split": spec.split, "material": spec.material, "shape": spec.shape,
                "transform": variant.transform, "scale": 1.0 if variant.scale is None else float(variant.scale),
                "rigid_counterpart": bool(variant.rigid_counterpart), "view": view, "seed": seed,
                "placement_x": x, "placement_y": y, "placement_yaw": yaw,
                "centre_x": float(centre[0]), "centre_y": float(centre[1]), "centre_z": float(centre[2]),
                "radius": radius, "n_points_raw": len(raw), "image_size": image_size,
                "size_x": float(spec.size[0]), "size_y": float(spec.size[1]), "size_z": float(spec.size[2]),
                "mass": float(spec.mass),
            })  # fmt: skip
    finally:
        for rig in rigs.values():
            rig.close()
    if cfg.extras:
        rows[0]["_extras"] = {k: np.stack(v) for k, v in extras.items()}
    return np.stack(clouds), rows


def _work(job):
    i, variant, cfg = job
    try:
        return i, *capture_variant(variant, cfg)
    except Exception as exc:  # name the variant: a bare traceback from a worker says little
        raise RuntimeError(f"strategy set: variant '{variant.spec.id}' failed: {type(exc).__name__}: {exc}") from exc


# ------------------------------------------------------------------------------ build
def _meta(cfg: SetConfig, bases, index, seconds: float, workers: int) -> dict:
    from importlib import metadata

    import mujoco

    from flatlab_lerobot.catalog import STRATEGY_LABELS
    from flatlab_lerobot.sim.scene import CellConfig
    from flatlab_lerobot.tasks import ResetDistribution
    from flatlab_lerobot.transforms import LABEL_RULE, label_disagreements, scale_range, seven_scales

    def counts(col):
        return dict(sorted(Counter(index[col]).items()))

    cell, reset = CellConfig(), ResetDistribution()
    ranges = {}
    for b in bases:
        lo, hi = scale_range(b)
        ranges[b.id] = {"min": lo, "max": hi, "scales": list(seven_scales(b, n=cfg.n_scales)) if cfg.n_scales else []}
    settings = asdict(cfg)
    return {
        "description": "FlatLab strategy set: object clouds normalized to the unit sphere, with strategy labels",
        "n_clouds": len(index["label"]),
        "n_points": cfg.n_points,
        "n_base_objects": len(bases),
        "label_names": list(STRATEGY_LABELS),
        "counts": {c: counts(c) for c in ("strategy", "split", "category", "transform", "material", "label_source")},
        "seed": cfg.seed,
        "settings": settings,
        "pipeline": {
            "sim": "FlatLabSim(object) with the default CellConfig, arms at home, reset(x, y, yaw, settle)",
            "placement": {"planar_m": reset.planar, "yaw_deg": reset.yaw_deg, "sampler": "tasks.ResetDistribution"},
            "cell": {"table_size": list(cell.table_size), "table_height": cell.table_height},
            "cloud": "CameraRig.object_points (segmentation mask + metric depth back-projected, world frame); "
            f"re-rendered at 2x, then up to {MAX_UPSCALE}x the image size while fewer pixels than points",
            "sampling": "fpsample.bucket_fps_kdline_sampling (farthest point) from a seeded start; "
            "fewer raw points: all once + seeded random repeats",
            "normalization": "minus the mean of the sampled points, divided by their largest norm",
        },
        "label_rule": LABEL_RULE,
        "label_rule_disagreements": [
            {"object_id": i, "catalog": c, "rule": r} for i, c, r in label_disagreements(bases)
        ],
        "scale_ranges": ranges,
        "paper_n_clouds": PAPER_CLOUDS,
        "build_seconds": round(seconds, 1),
        "workers": workers,
        "versions": {"mujoco": mujoco.__version__, "numpy": np.__version__, "fpsample": metadata.version("fpsample")},
    }


def build(cfg: SetConfig, out: Path, workers: int = 2, progress: bool = True) -> dict:
    """Build the set into ``out`` (replaced atomically when complete); returns ``meta.json``'s dict."""
    import pandas as pd
    from tqdm import tqdm

    t0 = time.perf_counter()
    bases, todo = plan(cfg)
    if not todo:
        raise ValueError("strategy set: nothing to build (no objects selected)")
    results: list = [None] * len(todo)
    jobs = [(i, v, cfg) for i, v in enumerate(todo)]
    bar = tqdm(total=len(todo), desc="strategy set", unit="variant", disable=not progress)
    try:
        if workers <= 1:
            for job in jobs:
                i, c, r = _work(job)
                results[i] = (c, r)
                bar.update(1)
        else:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor, as_completed

            with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
                futures = [pool.submit(_work, job) for job in jobs]
                try:
                    for fut in as_completed(futures):
                        i, c, r = fut.result()
                        results[i] = (c, r)
                        bar.update(1)
                except BaseException:
                    for f in futures:
                        f.cancel()
                    raise
    finally:
        bar.close()
    clouds = np.concatenate([c for c, _ in results]).astype(np.float32)
    rows = [row for _, r in results for row in r]
    extras = {}
    for k in cfg.extras:
        extras[k] = np.concatenate([r[0]["_extras"][k] for _, r in results])
    for row in rows:
        row.pop("_extras", None)
    index = pd.DataFrame(rows)
    meta = _meta(cfg, bases, index, time.perf_counter() - t0, workers)
    _write_atomic(Path(out), clouds, index, meta, extras)
    return meta


EXTRA_FILES = {"scene": "scene_clouds.npy", "rgb": "rgb.npy"}


def _write_atomic(out: Path, clouds: np.ndarray, index, meta: dict, extras: dict | None = None) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp-{os.getpid()}"
    old = out.parent / f".{out.name}.old-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        np.save(tmp / "clouds.npy", clouds)
        for k, arr in (extras or {}).items():
            np.save(tmp / EXTRA_FILES[k], arr)
        index.to_parquet(tmp / "index.parquet", index=False)
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
        if out.exists():
            os.rename(out, old)
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if old.exists() and not out.exists():
            os.rename(old, out)
        raise
    shutil.rmtree(old, ignore_errors=True)


def load(folder: Path) -> tuple[np.ndarray, object, dict]:
    """(clouds, index DataFrame, meta) of a built set; checks that they agree."""
    import pandas as pd

    folder = Path(folder)
    for f in FILES:
        if not (folder / f).is_file():
            raise FileNotFoundError(f"{folder / f}: missing (not a complete strategy set)")
    clouds = np.load(folder / "clouds.npy")
    index = pd.read_parquet(folder / "index.parquet")
    meta = json.loads((folder / "meta.json").read_text())
    if len(clouds) != len(index) or len(index) != meta["n_clouds"]:
        raise ValueError(f"{folder}: clouds.npy has {len(clouds)} clouds, index.parquet {len(index)} rows, "
                         f"meta.json says {meta['n_clouds']}")  # fmt: skip
    return clouds, index, meta


# ------------------------------------------------------------------------------ CLI
def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="flatlab strategy-set", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument(
        "--out", type=Path, default=DEFAULT_OUT, help="output folder (default: outputs/learning/strategy_set)"
    )
    ap.add_argument("--splits", default="train", help="comma-separated catalog splits, or 'all' (default: train)")
    ap.add_argument("--objects", default="", help="comma-separated object ids (overrides --splits)")
    ap.add_argument(
        "--scales", type=int_at_least(0), default=7, help="rescaled instances per object (default 7; 0: none)"
    )
    ap.add_argument("--no-counterparts", action="store_true", help="no rigid counterparts of the cloths")
    ap.add_argument(
        "--views", type=int_at_least(1), default=1, help="randomized placements per variant (default 1)"
    )
    ap.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    ap.add_argument("--cameras", default=",".join(CAMERA_NAMES), help="comma-separated cameras (default: all four)")
    ap.add_argument(
        "--image-size", type=int_at_least(16), default=512, help="render size in pixels (default 512)"
    )
    ap.add_argument("--settle", type=float, default=0.5, help="seconds of physics before the capture (default 0.5)")
    ap.add_argument("--points", type=int_at_least(1), default=2048, help="points per cloud (default 2048)")
    ap.add_argument("--workers", type=int_at_least(1), default=2, help="worker processes (default 2)")
    ap.add_argument("--limit", type=int_at_least(1), default=None, help="build only the first N variants")
    ap.add_argument("--extras", default="", help="comma-separated extra views per cloud: scene (scene_clouds.npy), "
                    "rgb (rgb.npy, the object's 64-px top-camera crop); for ablations A-8 / A-7")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def config_from_args(args) -> SetConfig:
    from flatlab_lerobot.catalog import BENCHMARK_SPLITS

    splits = tuple(s.strip() for s in args.splits.split(",") if s.strip())
    if splits == ("all",):
        splits = BENCHMARK_SPLITS
    cams = tuple(c.strip() for c in args.cameras.split(",") if c.strip())
    bad = [c for c in cams if c not in CAMERA_NAMES]
    if bad or not cams:
        raise ValueError(f"--cameras: unknown camera(s) {bad or cams}; known: {list(CAMERA_NAMES)}")
    extras = tuple(e.strip() for e in args.extras.split(",") if e.strip())
    if any(e not in EXTRAS for e in extras):
        raise ValueError(f"--extras: unknown extra(s) {[e for e in extras if e not in EXTRAS]}; known: {list(EXTRAS)}")
    if not (0.0 <= args.settle <= 10.0):
        raise ValueError(f"--settle: must be in [0, 10] s, got {args.settle}")
    return SetConfig(
        splits=splits, objects=tuple(o.strip() for o in args.objects.split(",") if o.strip()),
        n_scales=args.scales, counterparts=not args.no_counterparts, views=args.views, seed=args.seed,
        cameras=cams, image_size=args.image_size, settle=args.settle, n_points=args.points, limit=args.limit,
        extras=extras,
    )  # fmt: skip


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        cfg = config_from_args(args)
        plan(cfg)  # bad ids / splits fail here, before any work
    except ValueError as exc:
        ap.error(str(exc))
    meta = build(cfg, args.out, workers=args.workers, progress=not args.quiet)
    c = meta["counts"]
    print(f"strategy set: {meta['n_clouds']} clouds of {meta['n_points']} points from {meta['n_base_objects']} objects "
          f"in {meta['build_seconds']} s -> {args.out}")  # fmt: skip
    print(f"  labels {c['strategy']}  transforms {c['transform']}  (paper: {PAPER_CLOUDS} clouds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

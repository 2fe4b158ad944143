"""``flatlab collect``: run a recipe's expert episodes into a LeRobotDataset, resumably."""

from __future__ import annotations

import argparse
import logging
import shutil
import sys
import time
from pathlib import Path

from flatlab_lerobot.collect.recipe import Recipe, RecipeError, load_recipe
from flatlab_lerobot.collect.runner import run_episode
from flatlab_lerobot.collect.writer import DatasetMismatch, DatasetStore


def collect(
    recipe: Recipe,
    out: Path,
    *,
    overwrite: bool = False,
    progress: bool = True,
    log=print,
) -> dict:
    """Collect ``recipe.episodes`` episodes into ``out/<recipe.name>``; episodes already committed
    there are skipped (their count comes from the dataset's meta).  Returns a summary."""
    _quiet_ffmpeg()
    store = DatasetStore(recipe, out)
    if overwrite:
        for p in (store.root, store.staging, store.old):
            shutil.rmtree(p, ignore_errors=True)
    did = store.recover()
    if did != "clean":
        log(f"[collect] recovered {store.root}: {did}")
    store.check_compatible()
    done = len(store.records())
    n = recipe.episodes
    t0 = time.perf_counter()
    new = []
    if done >= n:
        log(f"[collect] {store.root}: {done}/{n} episodes already collected; nothing to do")
    else:
        if done:
            log(f"[collect] {store.root}: resuming at episode {done}/{n}")
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=n, initial=done, desc=f"collect {recipe.name}", unit="ep", dynamic_ncols=True)
        i = done
        try:
            while i < n:
                store.begin()
                try:
                    for _ in range(recipe.commit_every):
                        if i >= n:
                            break
                        res = run_episode(recipe, i)
                        store.add(res)
                        new.append(res.record())
                        msg = (
                            f"episode {i} seed {res.seed} {res.object_id}/{res.strategy}: "
                            f"{'success' if res.success else 'FAILED (' + res.failure_reason + ')'} "
                            f"{len(res.frames)} frames, {res.wall_time_s:.1f} s"
                        )
                        (bar.write if bar else log)(msg)
                        i += 1
                    store.commit()
                except BaseException:
                    store.abort()
                    raise
                if bar:
                    bar.update(i - bar.n)
        finally:
            if bar:
                bar.close()
    wall = time.perf_counter() - t0
    records = store.records()
    summary = {
        "root": str(store.root),
        "repo_id": recipe.repo_id,
        "episodes_total": len(records),
        "episodes_new": len(new),
        "successes_total": sum(r["success"] for r in records),
        "wall_s": round(wall, 2),
        "episodes_per_hour": round(3600 * len(new) / wall, 1) if new and wall > 0 else None,
    }
    log(
        f"[collect] {summary['episodes_total']} episodes in {store.root} "
        f"({summary['successes_total']} successful); {len(new)} new in {wall:.1f} s"
        + (f" = {summary['episodes_per_hour']} episodes/hour" if summary["episodes_per_hour"] else "")
    )
    return summary


def _quiet_ffmpeg() -> None:
    """lerobot restores ffmpeg's native log callback after each encode, which then prints the
    encoders' INFO banners/statistics for every video; raise ffmpeg's own level to ERROR."""
    try:
        import av

        av.logging.set_libav_level(av.logging.ERROR)
    except Exception:  # noqa: BLE001, S110 -- cosmetic only
        pass
    try:
        import datasets

        datasets.disable_progress_bars()  # one "Map" bar per saved episode otherwise
    except Exception:  # noqa: BLE001, S110 -- cosmetic only
        pass


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="flatlab collect", description="collect scripted-expert demos from a recipe into a LeRobotDataset (v3)"
    )
    ap.add_argument("--recipe", required=True, type=Path, help="YAML recipe, e.g. datasets/tiny_rigid.yaml")
    ap.add_argument("--out", type=Path, default=None, help="parent folder (default: outputs/datasets); "
                    "the dataset goes to OUT/<recipe name>")  # fmt: skip
    ap.add_argument("--episodes", type=int, default=None, help="override the recipe's episode count")
    ap.add_argument("--overwrite", action="store_true", help="delete an existing dataset of that name first")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--quiet", action="store_true", help="silence lerobot's info logging")
    args = ap.parse_args(argv)
    if args.quiet:
        logging.getLogger().setLevel(logging.WARNING)
    try:
        recipe = load_recipe(args.recipe)
        if args.episodes is not None:
            if args.episodes < 1:
                raise RecipeError(f"--episodes: must be >= 1, got {args.episodes}")
            import dataclasses

            recipe = dataclasses.replace(recipe, episodes=args.episodes)
        if args.out is None:
            from flatlab_lerobot.paths import OUTPUTS_DIR

            args.out = OUTPUTS_DIR / "datasets"
        collect(recipe, args.out, overwrite=args.overwrite, progress=not args.no_progress)
    except (RecipeError, DatasetMismatch) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: committed episodes are kept; re-run the same command to resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())

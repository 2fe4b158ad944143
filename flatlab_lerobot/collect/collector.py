"""``flatlab collect``: run a recipe's expert episodes into a LeRobotDataset, resumably.

Episodes are simulated -- and their camera streams encoded -- in ``recipe.workers`` processes
(``--workers`` overrides; 1 runs everything in this process).  Each worker builds its own env per
episode, so an episode depends only on (recipe, episode index).  Results come back to this
process, which adds them to the dataset strictly in episode-index order and commits every
``commit_every`` contiguous episodes: the dataset is the same for any number of workers, and a
crash loses at most the uncommitted episodes, which the next run re-simulates from their seeds.
At most ``2 x workers`` episodes are in flight or waiting to be added (bounded memory).
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import os
import resource
import shutil
import sys
import threading
import time
from pathlib import Path

from flatlab_lerobot.collect.recipe import Recipe, RecipeError, load_recipe
from flatlab_lerobot.collect.runner import EnvCache, EpisodeResult, run_episode
from flatlab_lerobot.collect.store import DatasetMismatch, DatasetStore
from flatlab_lerobot.collect.video import encode_videos, stream_specs


def peak_rss_mb() -> float:
    """This process's peak resident memory (MB).  /proc's VmHWM belongs to the current address
    space; getrusage's ru_maxrss (the fallback) survives exec, so a spawned worker would report its
    parent's peak."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0  # kB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kB


_ENVS = EnvCache()  # this process's envs, reused across its episodes


def episode_task(recipe: Recipe, episode_index: int, workdir: str, specs: dict) -> tuple[EpisodeResult, dict]:
    """One episode as a worker runs it: simulate, then encode the camera streams into ``workdir``
    (``specs``: :func:`~flatlab_lerobot.collect.video.stream_specs`).  Returns the result (frames
    without the video arrays) and the worker's pid and peak RSS."""
    cpu0 = time.process_time()
    res = run_episode(recipe, episode_index, cache=_ENVS)
    t0 = time.perf_counter()
    encode_videos(res, recipe, Path(workdir), specs)
    res.timing["encode"] = time.perf_counter() - t0
    res.timing["cpu"] = time.process_time() - cpu0
    return res, {"pid": os.getpid(), "peak_rss_mb": peak_rss_mb()}


def _init_worker(parent_pid: int) -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle

    def watchdog():  # the parent was killed (-9): do not linger as an orphan
        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watchdog, daemon=True).start()
    import av  # not _quiet_ffmpeg(): `datasets` would pull torch into every worker

    av.logging.set_libav_level(av.logging.ERROR)


def _warm_worker() -> None:
    import flatlab_lerobot.env
    import flatlab_lerobot.strategies  # noqa: F401


class EpisodesInOrder:
    """Iterator of ``(index, EpisodeResult, worker info)`` for ``start <= index < stop``, in index
    order.  With ``workers > 1`` a process pool computes them, at most ``2 x workers`` ahead of the
    consumer; the pool starts at construction, so it boots while the writer opens the dataset.
    :meth:`close` stops the workers (in-flight episodes are dropped)."""

    def __init__(self, recipe: Recipe, start: int, stop: int, workers: int, workdir: Path):
        self.recipe, self.next_index, self.stop, self.workdir = recipe, start, stop, str(workdir)
        self.pending: collections.deque = collections.deque()
        self.ex = None
        self._submitted = start
        if workers > 1 and start < stop:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            # spawn: the parent holds GL contexts and torch/ffmpeg threads that must not be forked
            self.ex = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_init_worker,
                                          initargs=(os.getpid(),))  # fmt: skip
            self.window = 2 * workers
            for _ in range(workers):  # start the workers now: they boot while this process imports lerobot
                self.ex.submit(_warm_worker)
        self.specs = stream_specs(recipe)  # imports lerobot (torch)
        if self.ex is not None:
            self._fill()

    def _fill(self) -> None:
        while self._submitted < self.stop and len(self.pending) < self.window:
            i = self._submitted
            self.pending.append((i, self.ex.submit(episode_task, self.recipe, i, self.workdir, self.specs)))
            self._submitted += 1

    def __iter__(self):
        return self

    def __next__(self):
        if self.next_index >= self.stop:
            raise StopIteration
        if self.ex is None:
            out = (self.next_index, *episode_task(self.recipe, self.next_index, self.workdir, self.specs))
        else:
            self._fill()
            i, fut = self.pending.popleft()
            assert i == self.next_index, (i, self.next_index)
            out = (i, *fut.result())
            self._fill()
        self.next_index += 1
        return out

    def close(self) -> None:
        ex, self.ex = self.ex, None
        if ex is None:
            _ENVS.close()  # in-process episodes: this process's envs are not needed any more
            return
        if not self.pending:
            ex.shutdown(wait=True)
            return
        # stopped early (error, Ctrl-C): the in-flight episodes are not needed
        procs = list((getattr(ex, "_processes", None) or {}).values())
        ex.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=10)
        self.pending.clear()


def collect(
    recipe: Recipe,
    out: Path,
    *,
    overwrite: bool = False,
    progress: bool = True,
    log=print,
) -> dict:
    """Collect ``recipe.episodes`` episodes into ``out/<recipe.name>``; episodes already committed
    there are skipped (their count comes from the dataset's meta).  Returns a summary, with
    timings and peak memory per process."""
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
    sim = collections.Counter()  # worker seconds by phase
    worker_rss: dict[int, float] = {}
    first_result_s = None
    if done >= n:
        log(f"[collect] {store.root}: {done}/{n} episodes already collected; nothing to do")
    else:
        if done:
            log(f"[collect] {store.root}: resuming at episode {done}/{n}")
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=n, initial=done, desc=f"collect {recipe.name}", unit="ep", dynamic_ncols=True)
        episodes = EpisodesInOrder(recipe, done, n, recipe.workers, store.work)
        i = done
        try:
            while i < n:
                store.begin()
                try:
                    for _ in range(recipe.commit_every):
                        if i >= n:
                            break
                        j, res, winfo = next(episodes)
                        assert j == i, (j, i)  # in index order, whichever worker finished first
                        if first_result_s is None:
                            first_result_s = time.perf_counter() - t0
                        sim.update(res.timing)
                        worker_rss[winfo["pid"]] = max(worker_rss.get(winfo["pid"], 0.0), winfo["peak_rss_mb"])
                        store.add(res)
                        new.append(res.record())
                        msg = (
                            f"episode {i} seed {res.seed} {res.object_id}/{res.strategy}: "
                            f"{'success' if res.success else 'FAILED (' + res.failure_reason + ')'} "
                            f"{res.record()['num_frames']} frames, {res.wall_time_s:.1f} s"
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
            episodes.close()  # stops the workers
            shutil.rmtree(store.work, ignore_errors=True)
            if bar:
                bar.close()
    wall = time.perf_counter() - t0
    records = store.records()
    writer_rss = peak_rss_mb()
    if recipe.workers <= 1:
        worker_rss = {}  # the episodes ran in this process: its peak is writer_peak_rss_mb
    summary = {
        "root": str(store.root),
        "repo_id": recipe.repo_id,
        "workers": recipe.workers,
        "episodes_total": len(records),
        "episodes_new": len(new),
        "frames_new": sum(r["num_frames"] for r in new),
        "successes_total": sum(r["success"] for r in records),
        "wall_s": round(wall, 2),
        "first_episode_s": None if first_result_s is None else round(first_result_s, 2),
        "episodes_per_hour": round(3600 * len(new) / wall, 1) if new and wall > 0 else None,
        # seconds summed over the new episodes: worker wall time by phase, and worker CPU ("cpu")
        "worker_s": {k: round(v, 2) for k, v in sim.items()},
        "writer_s": {k: round(v, 2) for k, v in store.timing.items()},  # writer wall and CPU seconds
        "worker_peak_rss_mb": {str(pid): round(v, 1) for pid, v in sorted(worker_rss.items())},
        "writer_peak_rss_mb": round(writer_rss, 1),
    }
    log(
        f"[collect] {summary['episodes_total']} episodes in {store.root} "
        f"({summary['successes_total']} successful); {len(new)} new in {wall:.1f} s"
        + (f" = {summary['episodes_per_hour']} episodes/hour" if summary["episodes_per_hour"] else "")
        + f" with {recipe.workers} worker{'s' if recipe.workers > 1 else ''}"
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


def with_overrides(recipe: Recipe, episodes: int | None = None, workers: int | None = None) -> Recipe:
    """The recipe with command-line overrides (neither changes the recipe's fingerprint)."""
    import dataclasses

    if episodes is not None:
        if episodes < 1:
            raise RecipeError(f"--episodes: must be >= 1, got {episodes}")
        recipe = dataclasses.replace(recipe, episodes=episodes)
    if workers is not None:
        if not 1 <= workers <= 64:
            raise RecipeError(f"--workers: must be in [1, 64], got {workers}")
        recipe = dataclasses.replace(recipe, workers=workers)
    return recipe


def successful_episodes(root: Path) -> list[int]:
    """The dataset episode indices of the successful demonstrations in a collected dataset (for
    ``lerobot-train --dataset.episodes=[...]``), from ``meta/flatlab_episodes.jsonl``."""
    from flatlab_lerobot.collect.store import EPISODES_JSONL

    p = Path(root) / EPISODES_JSONL
    if not p.is_file():
        raise RecipeError(f"{root}: not a collected dataset (no {EPISODES_JSONL}); run `flatlab collect` first")
    recs = [json.loads(line) for line in p.read_text().splitlines() if line.strip()]
    return [int(r["dataset_episode_index"]) for r in recs if r["success"] and r.get("dataset_episode_index") is not None]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="flatlab collect", description="collect scripted-expert demos from a recipe into a LeRobotDataset (v3)"
    )
    ap.add_argument("--recipe", required=True, type=Path, help="YAML recipe, e.g. datasets/tiny_rigid.yaml")
    ap.add_argument("--out", type=Path, default=None, help="parent folder (default: outputs/datasets); "
                    "the dataset goes to OUT/<recipe name>")  # fmt: skip
    ap.add_argument("--episodes", type=int, default=None, help="override the recipe's episode count")
    ap.add_argument("--workers", type=int, default=None, help="override the recipe's number of simulation "
                    "processes (the data does not depend on it)")  # fmt: skip
    ap.add_argument("--overwrite", action="store_true", help="delete an existing dataset of that name first")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--quiet", action="store_true", help="silence lerobot's info logging")
    ap.add_argument("--successful-episodes", action="store_true", help="collect nothing: print the recipe's "
                    "dataset's successful episode indices as a JSON list, for lerobot-train --dataset.episodes=...")  # fmt: skip
    args = ap.parse_args(argv)
    if args.quiet:
        logging.getLogger().setLevel(logging.WARNING)
    try:
        recipe = with_overrides(load_recipe(args.recipe), args.episodes, args.workers)
        if args.out is None:
            from flatlab_lerobot.paths import OUTPUTS_DIR

            args.out = OUTPUTS_DIR / "datasets"
        if args.successful_episodes:
            print(json.dumps(successful_episodes(args.out / recipe.name), separators=(",", ":")))
            return 0
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

"""The ``flatlab`` command: ``demo``, ``bench``, ``eval``, ``collect``, ``assets``, ``push``, ``view``,
``eval-compare``, ``strategy-set``, ``primitive-set``, ``bench-collect``, ``strategy-export``, ``strategy-eval``,
``primitive-export``, ``executor-metrics``, ``average-checkpoints``, ``unified-build``, ``desk``, ``paper``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from flatlab_lerobot.paths import OUTPUTS_DIR


PASSTHROUGH = {
    "bench": "flatlab_lerobot.bench.speed",
    "eval": "flatlab_lerobot.evaluation.protocol",
    "eval-compare": "flatlab_lerobot.evaluation.compare",
    "assets": "flatlab_lerobot.assets_cli",
    "collect": "flatlab_lerobot.collect",
    "push": "flatlab_lerobot.collect.hub",
    "view": "flatlab_lerobot.viz",
    "strategy-set": "flatlab_lerobot.learning.strategy_set",
    "primitive-set": "flatlab_lerobot.learning.primitive_set",
    "primitive-export": "flatlab_lerobot.learning.primitive_export",
    "executor-metrics": "flatlab_lerobot.learning.executor_metrics",
    "bench-collect": "flatlab_lerobot.bench.collect_speed",
    "strategy-export": "flatlab_lerobot.learning.strategy_export",
    "strategy-eval": "flatlab_lerobot.learning.strategy_eval",
    "average-checkpoints": "flatlab_lerobot.learning.checkpoint_average",
    "unified-build": "flatlab_lerobot.learning.unified_build",
    "desk": "flatlab_lerobot.paper.desk",
    "paper": "flatlab_lerobot.paper.main",
}
"""Subcommands whose own parser takes the rest of the command line (``flatlab eval --help``)."""


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in PASSTHROUGH:
        import importlib

        return importlib.import_module(PASSTHROUGH[argv[0]]).main(argv[1:]) or 0
    ap = argparse.ArgumentParser(prog="flatlab", description="FlatLab-LeRobot: flat-object grasping benchmark in MuJoCo")
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("demo", help="scripted expert on one reference object per strategy: key frames, videos, summary")
    d.add_argument("--out", type=Path, default=OUTPUTS_DIR / "demo", help="output folder (default: outputs/demo)")
    d.add_argument("--strategies", default="A,B,C", help="comma-separated subset of A,B,C")
    d.add_argument("--seed", type=int, default=0, help="placement seed (planar ±5 cm, yaw ±30°)")
    b = sub.add_parser("bench", help="speed benchmark: env vs raw mj_step+render, real-time factors")
    b.add_argument("rest", nargs=argparse.REMAINDER)
    e = sub.add_parser("eval", help="benchmark protocol: a policy over splits x objects x trials, paper-format tables")
    e.add_argument("rest", nargs=argparse.REMAINDER)
    c = sub.add_parser("collect", help="expert demonstrations from a recipe (datasets/*.yaml) into a LeRobotDataset v3")
    c.add_argument("rest", nargs=argparse.REMAINDER)
    a = sub.add_parser("assets", help="list / validate the catalog, render contact sheets")
    a.add_argument("rest", nargs=argparse.REMAINDER)
    for name, text in (
        ("eval-compare", "two flatlab eval runs trial by trial: discordant pairs, exact sign test, strategies"),
        ("push", "upload a collected dataset (with a generated dataset card) to the Hugging Face hub"),
        ("view", "open / save a rerun recording of a dataset episode with clouds, EE poses, stages, success"),
        ("strategy-set", "the strategy generator's learning set: normalized object clouds + strategy labels"),
        ("primitive-set", "the action module's learning set: scene cloud at each primitive start + start/end poses"),
        ("primitive-export", "a primitive set as a LeRobotDataset for lerobot-train --policy.type=flatlab_executor"),
        ("executor-metrics", "P-MSE / R-Err of a trained flatlab_executor per split, grasp and primitive"),
        ("bench-collect", "collection throughput benchmark: episodes/hour, overhead vs raw sim+render, memory"),
        ("strategy-export", "a strategy set as a LeRobotDataset v3 for lerobot-train --policy.type=flatlab_strategy"),
        ("strategy-eval", "learned strategy generator: accuracy per split / category, confusion, cloud ambiguity"),
        ("average-checkpoints", "one pretrained_model from the mean of a lerobot-train run's last K checkpoints"),
        ("unified-build", "one flatlab_unified policy folder from a trained flatlab_strategy and flatlab_executor"),
        ("desk", "the five-object desk (clear_desk) with the scripted expert over layout seeds"),
        ("paper", "the paper's results: run the missing stages of a preset (cached), render docs/results.md"),
    ):
        sub.add_parser(name, help=text).add_argument("rest", nargs=argparse.REMAINDER)
    args = ap.parse_args(argv)
    if args.cmd == "demo":
        from flatlab_lerobot.demo import run_demo

        records = run_demo(args.out, strategies=tuple(s.strip() for s in args.strategies.split(",")), seed=args.seed)
        return 0 if records else 1
    return 2


if __name__ == "__main__":
    sys.exit(main())

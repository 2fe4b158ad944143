"""``flatlab paper``: run the missing stages of a preset, then render the results page.

    flatlab paper --preset cpu --dry-run          # the plan: each stage done / earlier / run / blocked
    flatlab paper --preset cpu                    # run what is missing, render docs/results.md
    flatlab paper --preset cpu --only 'strategy_lambda_*'
    flatlab paper --render-only                   # docs/results.md + plots from docs/results/*.json
    flatlab paper --preset paper --render-only    # docs/results_paper.md (its trainings ran on a lent GPU)
    flatlab paper --headline                      # the README's headline table
"""

from __future__ import annotations

import sys
from pathlib import Path

from flatlab_lerobot.paper import render
from flatlab_lerobot.paper.pipeline import (
    Context, PaperError, context, display, fingerprints, plan, presets, run_stage, select, statuses,
)  # fmt: skip


def print_plan(ctx: Context, targets: list[str], force: set[str]) -> list[str]:
    st = statuses(ctx)
    todo = plan(ctx, targets, force, st)
    print(f"preset {ctx.preset['name']}: {len(ctx.stages)} stages, {len(targets)} selected; $OUT = {ctx.out_root}, "
          f"$RESULTS = {ctx.results_dir}")  # fmt: skip
    w = max(map(len, ctx.stages))
    for name in [n for n in ctx.stages if n in todo or n in targets]:
        s = st[name]
        state = "run" if name in todo and s.state != "blocked" else s.state
        extra = f"  ({s.reason})" if s.reason and s.state != "done" else ""
        print(f"  {name:<{w}}  {ctx.stages[name].kind:<12} {state:<8}{extra}")
        if name in todo and s.state != "blocked":
            print(f"  {'':<{w}}  $ {display(ctx, ctx.stages[name])}")
    return todo


def main(argv_=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(
        prog="flatlab paper",
        description="The paper's results: run the missing stages of a preset (learning sets, trainings, evaluations; "
        "each cached and resumable), then render docs/results.md and its plots from the results JSONs.",
    )
    ap.add_argument("--preset", default="cpu", help=f"one of {', '.join(presets())} (default cpu)")
    ap.add_argument("--only", nargs="+", metavar="STAGE", help="run these stages (glob patterns) and what they need")
    ap.add_argument(
        "--force", nargs="+", default=[], metavar="STAGE",
        help="rerun these stages from scratch even if done (each one's output folder is discarded first)",
    )  # fmt: skip
    ap.add_argument("--dry-run", action="store_true", help="print the plan: each stage done / earlier / run / blocked")
    ap.add_argument("--render-only", action="store_true", help="only rebuild the results page and plots")
    ap.add_argument("--headline", action="store_true", help="print the README's headline table and exit")
    ap.add_argument("--no-render", action="store_true", help="run the stages, do not render")
    ap.add_argument("--keep-going", action="store_true", help="after a failed stage, go on with the others")
    ap.add_argument("--results-dir", type=Path, default=None, help="results JSONs (default docs/results)")
    ap.add_argument("--out", type=Path, default=None, help="stage outputs (default outputs/paper/<preset>)")
    ap.add_argument("--page", type=Path, default=None,
                    help="page to write (default docs/results.md for --results-dir docs/results, docs/results_<preset>.md for "
                         "another preset than cpu, else <results-dir>/results.md)")  # fmt: skip
    a = ap.parse_args(argv_)
    ctx = context(a.preset, a.out, a.results_dir)
    if a.headline:
        print(render.headline(ctx), end="")
        return 0
    if not a.render_only:
        targets = select(ctx, a.only)
        force = set(select(ctx, a.force)) if a.force else set()
        todo = print_plan(ctx, targets, force)
        if a.dry_run:
            return 0
        fps = fingerprints(ctx)
        failed: list[str] = []
        for name in todo:
            st = statuses(ctx, fps)
            if st[name].state == "blocked":
                print(f"[skip] {name}: {st[name].reason}")
                continue
            if bad := [i for i in ctx.stages[name].inputs if i in failed]:
                print(f"[skip] {name}: input {bad[0]} failed")
                failed.append(name)
                continue
            print(f"[run ] {name}: {display(ctx, ctx.stages[name])}", flush=True)
            try:
                # resume only an interrupted run (no record yet); a forced or stale stage starts over
                rec = run_stage(ctx, ctx.stages[name], fps[name], fps, restart=name in force or st[name].state != "missing")
            except PaperError as e:
                if not a.keep_going:
                    raise
                print(e, file=sys.stderr)
                failed.append(name)
                continue
            print(f"[done] {name}: {rec['paper_stage']['wall_s']} s -> {ctx.record_path(name)}", flush=True)
        if failed:
            print(f"failed: {', '.join(failed)}", file=sys.stderr)
    if not a.no_render:
        page = render.write_page(ctx, a.page)
        print(f"wrote {page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Average the weights of a ``lerobot-train`` run's last K saved checkpoints into one ``pretrained_model``.

Why: the strategy generator's held-out Train views cannot tell its late checkpoints apart (validation
accuracy within 2-3 points), yet on unseen categories consecutive checkpoints disagree: of 33 unseen
cloth views, 2 to 26 are called C by checkpoints 270 steps apart of one run
(``docs/results/paper/strategy_checkpoint_spread.json``).  The mean of the last K checkpoints' weights
(stochastic weight averaging over saved checkpoints, decided before looking at any split) damps that
checkpoint-to-checkpoint noise and is still one model of the same type: it loads with ``from_pretrained``,
goes into ``flatlab unified-build --generator``, and ``lerobot-eval`` cannot tell it from a checkpoint.

Floating-point tensors (weights and BatchNorm running statistics) are averaged; integer buffers
(BatchNorm's ``num_batches_tracked``) are taken from the last checkpoint, and every other file of the
folder (config, train config, processors) is the last checkpoint's.  The checkpoints are read, never
written; the result is written to a temporary folder and moved into place, so a crash leaves no half
folder.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

WEIGHTS = "model.safetensors"


def saved_checkpoints(run_dir: Path) -> list[Path]:
    """The run's saved ``pretrained_model`` folders, by step (``checkpoints/<step>/pretrained_model``)."""
    ck = sorted(
        (p for p in (Path(run_dir) / "checkpoints").glob("[0-9]*") if (p / "pretrained_model" / WEIGHTS).is_file()),
        key=lambda p: int(p.name),
    )
    return [p / "pretrained_model" for p in ck]


def average_checkpoints(run_dir: Path, last: int, out: Path | None = None, flag: str = "--average-last") -> tuple[Path, list[str]]:
    """Average the last ``last`` saved checkpoints of ``run_dir`` into ``out`` (default
    ``<run_dir>/checkpoints/average_last<K>/pretrained_model``).  Returns (the folder, the steps averaged).
    ``flag`` names the option in error messages."""
    from safetensors.torch import load_file, save_file

    run_dir = Path(run_dir)
    if not (run_dir / "checkpoints").is_dir():
        raise FileNotFoundError(f"{run_dir}: no checkpoints/ folder (not a lerobot-train output folder)")
    if int(last) < 1:
        raise ValueError(f"{flag}: must be >= 1, got {last}")
    cks = saved_checkpoints(run_dir)
    if len(cks) < last:
        raise ValueError(f"{flag} {last}: {run_dir}/checkpoints holds {len(cks)} saved step(s)")
    cks = cks[-last:]
    steps = [p.parent.name for p in cks]
    types = {json.loads((p / "config.json").read_text()).get("type") for p in cks}
    if len(types) != 1:
        raise ValueError(f"{flag}: the checkpoints {steps} are of different policy types {sorted(types)}")
    states = [load_file(str(p / WEIGHTS)) for p in cks]
    keys = set(states[-1])
    for p, s in zip(cks, states, strict=True):
        if set(s) != keys or any(s[k].shape != states[-1][k].shape for k in keys):
            raise ValueError(f"{flag}: {p} has other tensors than {cks[-1]} (not the same model)")
    avg = {}
    for k, last_t in states[-1].items():
        if last_t.is_floating_point():
            avg[k] = (sum(s[k].double() for s in states) / len(states)).to(last_t.dtype).contiguous()
        else:
            avg[k] = last_t.clone()
    out = Path(out) if out else run_dir / "checkpoints" / f"average_last{last}" / "pretrained_model"
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(cks[-1], tmp)
    save_file(avg, str(tmp / WEIGHTS), metadata={"format": "pt"})
    (tmp / "average.json").write_text(json.dumps({"run": str(run_dir), "steps": steps, "method": "mean of the "
                                                  "floating-point tensors; integer buffers and files of the last"}, indent=1) + "\n")  # fmt: skip
    shutil.rmtree(out, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp.rename(out)
    return out, steps


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="flatlab average-checkpoints", description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a lerobot-train output folder (holding checkpoints/<step>/pretrained_model)")
    ap.add_argument("--last", type=int, required=True, help="how many of the last saved checkpoints to average")
    ap.add_argument("--out", type=Path, default=None,
                    help="pretrained_model folder to write (default: RUN/checkpoints/average_lastK/pretrained_model)")
    args = ap.parse_args(argv)
    try:
        out, steps = average_checkpoints(args.run, args.last, args.out, flag="--last")
    except (FileNotFoundError, ValueError) as exc:
        ap.error(str(exc))
    print(f"averaged steps {', '.join(steps)} -> {out}")
    return 0

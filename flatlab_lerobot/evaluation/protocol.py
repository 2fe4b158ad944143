"""The evaluation protocol (``flatlab eval``): strategy choice S and grasp success G.

``--policy`` is either a built-in scripted policy or any LeRobot checkpoint:

* ``oracle``: the object's label strategy (the upper bound of strategy choice),
* ``slide_only``: always A (slide to the edge, grasp the overhang),
* ``lift_only``: always B (two-arm squeeze and lift),
* ``fold_only``: always C (squeeze into a fold, pinch the fold; the asset validation's third column),
* ``flatlab_scripted``: the ``flatlab_scripted`` policy's own rule (C if deformable, else B if
  >= 4 cm thick, else A), exactly ``lerobot-eval --policy.type=flatlab_scripted``,
* a folder holding a LeRobot ``pretrained_model`` (``config.json`` + ``model.safetensors`` +
  processors; a training output folder or its ``checkpoints/<step>`` also work) or a hub repo id.

Every trial runs through LeRobot's own machinery, as ``lerobot-eval`` does: the policy and its
pre/post processors come from ``make_policy`` / ``make_pre_post_processors`` (``set_seed(--seed)``
first), the env from ``make_env`` on the ``flatlab`` :class:`~flatlab_lerobot.lerobot_env.FlatLabEnvConfig`
(``--env.<field>=<value>`` as in lerobot-eval, ``env.object_id`` set per object) and each episode
from ``lerobot.scripts.lerobot_eval.eval_policy`` with ``start_seed = --seed + trial``.  So trial
``t`` of object ``o`` is episode ``t`` of ``lerobot-eval --env.type=flatlab --env.object_id=o
--eval.batch_size=1 --eval.n_episodes=N --seed=SEED`` (same placement, same length, same success);
the trials of one object run in order in one process after restoring the RNG state that
``set_seed`` + policy construction left, so a stochastic policy should draw the same noise too (not
tested; not for an object interrupted half-way and resumed).  The built-in policies run with
``obs_pixels=false, obs_pointcloud=false`` (the scripted expert reads only the state; rendering
never changes the physics), which makes them as fast as the bare expert.

S = the strategy the policy chose (policies exposing ``.strategies``, e.g. ``flatlab_scripted``)
equals the object's label; a policy that exposes no strategy gets S = n/a (``-``).  G = the env's
success rule (``info["is_success"]``, the benchmark's 2-s hold for ``--env.task=grasp``).

Runs in ``--workers`` processes (each loads the policy once and takes whole objects).  Every
finished trial is appended to ``results.jsonl`` (one JSON line, written by the parent only,
flushed and fsynced) and a restart skips the ``(object, trial)`` keys already there, so an
interrupted run resumes without repeating or losing trials (a half-written last line is dropped).
When every trial is done it writes ``results.json``, ``results.md`` (per object S and G as
successes/trials, per-split averages) and ``results.png``.

    flatlab eval --policy oracle --splits train --trials 5
    flatlab eval --policy outputs/train/act/checkpoints/last/pretrained_model --objects ref_box \\
        --env.image_size=64 --policy.device=cpu
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import multiprocessing as mp
import os
import queue as queue_mod
import re
import time
import traceback
from contextlib import contextmanager, nullcontext
from pathlib import Path

from flatlab_lerobot.atomic import replacing, write_text
from flatlab_lerobot.catalog import BENCHMARK_SPLITS, benchmark_objects, get_object

BUILTIN = {
    "oracle": lambda spec: spec.strategy,
    "slide_only": lambda spec: "A",
    "lift_only": lambda spec: "B",
    "fold_only": lambda spec: "C",
    "flatlab_scripted": lambda spec: "auto",
}
"""Built-in policy -> the ``flatlab_scripted`` strategy setting it uses for an object."""
POLICIES = BUILTIN  # backwards-compatible name
RESULTS_JSONL = "results.jsonl"
RUN_JSON = "run.json"
DEFAULT_SEED = 1000  # lerobot-eval's default --seed
BUILTIN_ENV_ARGS = ["--obs_pixels=false", "--obs_pointcloud=false"]
ENV_FIXED = {"object_id": "set per object by --objects/--splits", "features": "derived", "features_map": "derived"}


class EvalError(SystemExit):
    """A bad argument or input: a clear message on stderr, exit status 1."""

    def __init__(self, msg: str):
        super().__init__(f"flatlab eval: {msg}")


# ----------------------------------------------------------------------------- policy and env
def resolve_policy(arg: str) -> tuple[str, bool]:
    """``(name, builtin)``: a built-in name, an absolute ``pretrained_model`` folder, or a hub id."""
    if arg in BUILTIN:
        return arg, True
    p = Path(arg).expanduser()
    if p.exists():
        if not p.is_dir():
            raise EvalError(f"--policy {arg}: not a folder (want a LeRobot pretrained_model folder with config.json)")
        for cand in (p, p / "pretrained_model", p / "checkpoints" / "last" / "pretrained_model"):
            if (cand / "config.json").is_file():
                if not (cand / "model.safetensors").is_file():
                    raise EvalError(
                        f"{cand / 'model.safetensors'}: missing (a LeRobot checkpoint holds config.json + model.safetensors)"
                    )
                return str(cand.resolve()), False
        raise EvalError(f"{p / 'config.json'}: missing (--policy must be a LeRobot pretrained_model folder, a hub repo id "
                        f"or one of {sorted(BUILTIN)})")  # fmt: skip
    if re.fullmatch(r"[\w.-]+/[\w.-]+", arg) and not arg.startswith((".", "/")):
        return arg, False  # a hub repo id: downloaded by lerobot's from_pretrained
    raise EvalError(f"--policy {arg!r}: no such folder, not a hub repo id (owner/name), not one of {sorted(BUILTIN)}")


def make_env_config(env_args: list[str], builtin: bool):
    """The ``flatlab`` EnvConfig from ``--env.<field>=<value>`` overrides, parsed by draccus as
    lerobot-eval parses them (the built-ins default to no pixels / no clouds)."""
    import draccus

    from flatlab_lerobot.lerobot_env import EnvConfigError, FlatLabEnvConfig

    fields = {f.name for f in dataclasses.fields(FlatLabEnvConfig)}
    for a in env_args:
        key = a[2:].split("=", 1)[0]
        if key in ENV_FIXED:
            raise EvalError(f"--env.{key}: not settable here ({ENV_FIXED[key]})")
        if key not in fields:
            raise EvalError(
                f"--env.{key}: not a field of the flatlab EnvConfig (fields: {', '.join(sorted(fields - set(ENV_FIXED)))})"
            )
    args = (BUILTIN_ENV_ARGS if builtin else []) + env_args
    try:
        return draccus.parse(config_class=FlatLabEnvConfig, args=args)
    except EnvConfigError as e:
        raise EvalError(str(e)) from None
    except SystemExit as e:
        raise EvalError(f"bad --env.* value in {env_args}") from e


def load_policy_config(name: str, builtin: bool, overrides: list[str]):
    """The policy config as lerobot-eval builds it (``--policy.path`` + ``--policy.*`` overrides)."""
    import lerobot.policies  # noqa: F401  registers lerobot's policy types, as lerobot-eval's import does
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()  # lerobot_policy_* / lerobot_env_* packages, as lerobot-eval's main()

    if builtin:
        import draccus

        from flatlab_lerobot.policies.scripted import FlatLabScriptedConfig

        try:
            return draccus.parse(config_class=FlatLabScriptedConfig, args=["--device=cpu", *overrides])
        except SystemExit as e:
            raise EvalError(f"bad --policy.* override for the built-in policy in {overrides}") from e
    try:
        cfg = PreTrainedConfig.from_pretrained(name, cli_overrides=overrides)
    except SystemExit as e:
        raise EvalError(f"bad --policy.* override {overrides} for {name}") from e
    except Exception as e:  # missing file, unknown type, no hub access ...
        where = Path(name) / "config.json" if Path(name).is_dir() else name
        raise EvalError(f"{where}: cannot load the policy config: {type(e).__name__}: {e}") from e
    cfg.pretrained_path = Path(name)
    return cfg


class Evaluator:
    """One process's policy, processors and per-object envs; :meth:`run_object` yields trial records."""

    def __init__(self, spec: dict):
        import torch
        from lerobot.envs import make_env_pre_post_processors
        from lerobot.policies import make_policy, make_pre_post_processors
        from lerobot.utils.device_utils import get_safe_torch_device
        from lerobot.utils.random_utils import get_rng_state, set_seed

        self.spec = spec
        self.builtin = spec["builtin"]
        self.env_cfg = make_env_config(spec["env_args"], self.builtin)
        cfg = load_policy_config(spec["policy"], self.builtin, spec["policy_args"])
        # as lerobot_eval.eval_main, in its order
        self.device = get_safe_torch_device(cfg.device, log=False)
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = True
        set_seed(spec["seed"])
        # (the built-ins have nothing to normalize: lerobot's "policy from scratch" warning does not apply)
        with _no_warnings() if self.builtin else nullcontext():
            self.policy = make_policy(cfg=cfg, env_cfg=self.env_cfg, rename_map=spec["rename_map"])
        self.policy.eval()
        overrides = {
            "device_processor": {"device": str(self.policy.config.device)},
            "rename_observations_processor": {"rename_map": spec["rename_map"]},
        }
        self.pre, self.post = make_pre_post_processors(
            policy_cfg=cfg, pretrained_path=cfg.pretrained_path, preprocessor_overrides=overrides
        )
        self.env_pre, self.env_post = make_env_pre_post_processors(env_cfg=self.env_cfg, policy_cfg=cfg)
        self.cfg = cfg
        self.rng0 = get_rng_state()  # what the first episode of a lerobot-eval run starts from

    def run_object(self, object_id: str, trials: list[int]):
        import torch
        from lerobot.envs import close_envs, make_env
        from lerobot.scripts import lerobot_eval
        from lerobot.utils.random_utils import set_rng_state

        spec = get_object(object_id)
        if self.builtin:
            self.policy.config.strategy = BUILTIN[self.spec["policy"]](spec)
        set_rng_state(self.rng0)
        env_cfg = dataclasses.replace(self.env_cfg, object_id=spec.id)
        envs = make_env(env_cfg, n_envs=1, use_async_envs=False)
        vec = envs[env_cfg.type][0]
        amp = torch.autocast(device_type=self.device.type) if self.cfg.use_amp else nullcontext()
        env_post = self.env_post
        if hasattr(self.policy, "reads_next_clouds") and not self.spec.get("render_every_step"):
            env_post = _SkipUnreadClouds(self.env_post, vec.envs[0].unwrapped, self.policy)
        try:
            for t in trials:
                if self.spec.get("parent_pid") and not _alive(self.spec["parent_pid"]):
                    os._exit(0)  # a worker whose parent was killed: stop now, not run on as an orphan
                seed = self.spec["seed"] + t
                t0 = time.perf_counter()
                with torch.no_grad(), amp:
                    info = lerobot_eval.eval_policy(
                        env=vec, policy=self.policy, env_preprocessor=self.env_pre, env_postprocessor=env_post,
                        preprocessor=self.pre, postprocessor=self.post, n_episodes=1, start_seed=seed,
                    )  # fmt: skip
                ep = info["per_episode"][0]
                env = vec.envs[0].unwrapped
                chosen = getattr(self.policy, "strategies", None)
                strategy = chosen[0] if chosen else None
                x, y, yaw = env.placement
                st = env.sim.grasp_status()
                success = bool(ep["success"])
                # the env's own outcome of the episode lerobot's eval_policy just ran (its loop, not
                # flatlab_lerobot.rollout: a trial must be exactly a lerobot-eval episode)
                reason = "" if success else env.failure_reason or st.shortfall.text()
                record = {
                    "policy": self.spec["policy"],
                    "object_id": spec.id,
                    "trial": t,
                    "seed": ep["seed"],
                    "split": spec.split,
                    "category": spec.category,
                    "label": spec.strategy,
                    "strategy": strategy,
                    "S": None if strategy is None else strategy == spec.strategy,
                    "G": success,
                    "steps": int(env.steps),
                    "sim_time_s": round(float(env.sim.data.time), 3),
                    "placement": {"x": x, "y": y, "yaw_deg": math.degrees(yaw)},
                    "final_clearance_m": round(float(st.clearance), 4),
                    "failure_reason": reason,
                    "sum_reward": ep["sum_reward"],
                    "wall_s": round(time.perf_counter() - t0, 3),
                    "pid": os.getpid(),
                }
                if getattr(env, "layout", None) is not None:  # a scenario (clear_desk): what became of each object
                    record["desk"] = desk_outcome(env, self.policy)
                elif len(attempts := (getattr(self.policy, "attempts", None) or [[]])[0]) > 1:
                    record["attempts"] = attempts  # a policy that retried: the strategy of every attempt
                yield record
        finally:
            close_envs(envs)


class _SkipUnreadClouds:
    """lerobot's env postprocessor (it runs between the policy's ``select_action`` and ``env.step``), then: when
    the policy says its next step will not read the clouds (``policy.reads_next_clouds``, e.g.
    ``flatlab_unified`` between two stage decisions), the env skips rendering them for that step
    (``FlatLabEnv.skip_clouds``).  Each step's clouds are sampled with their own generator, so the episode is
    the one lerobot-eval runs, rendering at every step (tests/test_unified_policy.py checks it); these renders
    were about half of a learned rigid-object trial's wall time on 2 cores (docs/performance.md)."""

    def __init__(self, env_post, env, policy):
        self.env_post, self.env, self.policy = env_post, env, policy

    def __call__(self, transition):
        out = self.env_post(transition)
        if not self.policy.reads_next_clouds:
            self.env.skip_clouds()
        return out


def desk_outcome(env, policy) -> dict:
    """A scenario trial's objects (clearing order), which were lifted (the hold rule met) and cleared
    (lifted and off the table), and the policy's attempts (strategy per attempt) when it reports them."""
    from flatlab_lerobot.tasks.clear_desk import cleared

    out = {"split": env.layout.items[0].obj.split, "objects": env.layout.object_ids,
           "lifted": [bool(v) for v in env.sim.lifted], "cleared": [bool(v) for v in cleared(env.sim)]}  # fmt: skip
    attempts = getattr(policy, "attempts", None)
    if attempts:
        out["attempts"] = attempts[0]
    return out


@contextmanager
def _no_warnings():
    logging.disable(logging.WARNING)
    try:
        yield
    finally:
        logging.disable(logging.NOTSET)


def _quiet_lerobot_bars() -> None:
    """lerobot's per-episode tqdm bars would interleave with ours (one bar, counting trials)."""
    from lerobot.scripts import lerobot_eval
    from tqdm import trange

    def quiet_trange(*args, **kwargs):
        return trange(*args, **{**kwargs, "disable": True})

    lerobot_eval.trange = quiet_trange


def _alive(pid: int) -> bool:
    """Whether process ``pid`` still exists (the caller; a forkserver worker's own parent is the server)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _die_with_parent() -> None:
    """Linux: have the kernel SIGKILL this worker when the parent dies (e.g. ``kill -9``); elsewhere
    the per-trial parent check in :meth:`Evaluator.run_object` stops it."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _worker(spec: dict, jobs, results, threads: int | None) -> None:
    """Worker process: load the policy once, then take whole objects from ``jobs`` until a None."""
    try:
        _die_with_parent()
        if threads:
            import torch

            torch.set_num_threads(threads)
        _quiet_lerobot_bars()
        ev = Evaluator(spec)
        while (job := jobs.get()) is not None:
            for rec in ev.run_object(job["object_id"], job["trials"]):
                results.put(("trial", rec))
            results.put(("object", job["object_id"]))
    except BaseException:  # noqa: BLE001  reported to the parent, which stops the run
        results.put(("error", f"worker {os.getpid()}:\n{traceback.format_exc()}"))


# ----------------------------------------------------------------------------- bookkeeping
def saved_trials(path: Path) -> dict[tuple[str, int], dict]:
    """Finished trials in ``results.jsonl`` by (object_id, trial), read only: the lines ended by a newline
    (a half-written last line is not one)."""
    done: dict[tuple[str, int], dict] = {}
    if not path.exists():
        return done
    raw = path.read_bytes()
    for line in raw[: raw.rfind(b"\n") + 1].decode().splitlines():
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        done[(rec["object_id"], int(rec["trial"]))] = rec
    return done


def load_done(path: Path, policy: str) -> dict[tuple[str, int], dict]:
    """``saved_trials`` of a run about to resume: a half-written last line (an interrupted write) is cut off
    the file so later appends start on a clean line, and every trial must be ``policy``'s."""
    if path.exists():
        raw = path.read_bytes()
        good_end = raw.rfind(b"\n") + 1
        if good_end < len(raw):
            with open(path, "r+b") as f:
                f.truncate(good_end)
    done = saved_trials(path)
    for rec in done.values():
        if rec.get("policy") != policy:
            raise EvalError(f"{path} holds results of policy {rec.get('policy')!r}, not {policy!r}: use another --out")
    return done


def _env_field_defaults() -> dict:
    """The ``flatlab`` EnvConfig's fields with their defaults, as ``gym_kwargs`` names them."""
    from flatlab_lerobot.lerobot_env import FlatLabEnvConfig

    return {f.name: f.default for f in dataclasses.fields(FlatLabEnvConfig) if f.default is not dataclasses.MISSING}


def check_run(out: Path, run: dict) -> None:
    """``run.json`` pins what the trials in ``results.jsonl`` mean (policy, seed, env, overrides);
    resuming with other settings would mix incomparable trials."""
    path = out / RUN_JSON
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise EvalError(f"{path}: not valid JSON ({e}); delete it only if results.jsonl is empty") from e
        run = json.loads(json.dumps(run))  # tuples -> lists, as stored
        # an env field added to the EnvConfig since does not count as a change while it keeps its default (the run's
        # trials ran as if it were there); set to anything else it does (--env.joint_speed_limit=true on a run of before)
        new_default = _env_field_defaults()
        run["env"] = {k: v for k, v in run["env"].items() if k in old.get("env", {}) or new_default.get(k, v) != v}
        diff = sorted(k for k in run if old.get(k) != run[k])
        if diff:
            raise EvalError(f"{path}: this folder was run with other settings ({', '.join(diff)}: "
                            f"{ {k: old.get(k) for k in diff} }): use another --out")  # fmt: skip
    else:
        jsonl = out / RESULTS_JSONL
        if jsonl.exists() and jsonl.stat().st_size > 0:
            raise EvalError(f"{jsonl}: trials of an older flatlab eval (no {RUN_JSON} beside it): use another --out")
        write_text(path, json.dumps(run, indent=2))


def select_objects(splits, objects) -> list[str]:
    if objects:
        try:
            return [get_object(o).id for o in objects]
        except KeyError as e:
            raise EvalError(f"--objects: {e.args[0] if e.args else e}") from None
    return [o.id for s in splits for o in sorted(benchmark_objects(s), key=lambda o: o.id)]


def _rate(recs, key) -> float | None:
    vals = [r[key] for r in recs if r.get(key) is not None]
    return sum(vals) / len(vals) if vals else None


def summarize(records: list[dict], config: dict) -> dict:
    per_object: dict[str, dict] = {}
    for r in sorted(records, key=lambda r: (r["split"], r["object_id"], r["trial"])):
        o = per_object.setdefault(
            r["object_id"],
            {"object_id": r["object_id"], "split": r["split"], "category": r["category"], "label": r["label"],
             "trials": 0, "S": 0, "G": 0, "strategies": {}},
        )  # fmt: skip
        o["trials"] += 1
        if r.get("S") is None:
            o["S"] = None
        elif o["S"] is not None:
            o["S"] += int(r["S"])
        o["G"] += int(r["G"])
        key = r.get("strategy") or "-"
        o["strategies"][key] = o["strategies"].get(key, 0) + 1
    per_split = {}
    for split in dict.fromkeys(o["split"] for o in per_object.values()):
        recs = [r for r in records if r["split"] == split]
        per_split[split] = {
            "objects": sum(1 for o in per_object.values() if o["split"] == split),
            "trials": len(recs),
            "S": _rate(recs, "S"),
            "G": _rate(recs, "G"),
        }
    out = {
        "config": config,
        "per_object": list(per_object.values()),
        "per_split": per_split,
        "overall": {"trials": len(records), "S": _rate(records, "S"), "G": _rate(records, "G")},
    }
    desks = [r["desk"] for r in records if "desk" in r]
    if desks:  # a scenario: objects lifted / cleared per trial (the trial's G is the whole desk)
        out["desk"] = {
            "trials": len(desks),
            "n_objects": len(desks[0]["objects"]),
            "cleared_mean": sum(sum(d["cleared"]) for d in desks) / len(desks),
            "lifted_mean": sum(sum(d["lifted"]) for d in desks) / len(desks),
            "attempts_mean": (sum(len(d["attempts"]) for d in desks) / len(desks)) if all("attempts" in d for d in desks) else None,
        }
    return out


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f}"


def markdown(summary: dict) -> str:
    c = summary["config"]
    env = c.get("env", {})
    lines = [
        f"# FlatLab evaluation: policy `{c['policy']}`",
        "",
        (
            f"{c['trials']} trials per object, seeds {c['seed']}..{c['seed'] + c['trials'] - 1} "
            f"(= `lerobot-eval --env.type=flatlab --seed={c['seed']} --eval.n_episodes={c['trials']} --eval.batch_size=1` "
            f"per object), task `{env.get('task', 'grasp')}`, {env.get('episode_length', '?')} steps at {env.get('fps', '?')} Hz; "
            "S = strategy choice correct (`-`: the policy exposes no strategy), G = grasp success (successes/trials)."
        ),
        "",
        "| split | category | object | label | S | G |",
        "|---|---|---|---|---|---|",
    ]
    for o in summary["per_object"]:
        n = o["trials"]
        s = "-" if o["S"] is None else f"{o['S']}/{n}"
        lines.append(f"| {o['split']} | {o['category']} | {o['object_id']} | {o['label']} | {s} | {o['G']}/{n} |")
    lines += ["", "| split | objects | trials | S (%) | G (%) |", "|---|---|---|---|---|"]
    for split, s in summary["per_split"].items():
        lines.append(f"| {split} | {s['objects']} | {s['trials']} | {_pct(s['S'])} | {_pct(s['G'])} |")
    ov = summary["overall"]
    lines.append(f"| **all** | {len(summary['per_object'])} | {ov['trials']} | {_pct(ov['S'])} | {_pct(ov['G'])} |")
    return "\n".join(lines) + "\n"


def plot(summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    splits = list(summary["per_split"])
    s = [np.nan if summary["per_split"][k]["S"] is None else 100 * summary["per_split"][k]["S"] for k in splits]
    g = [100 * summary["per_split"][k]["G"] for k in splits]
    x = np.arange(len(splits))
    fig, ax = plt.subplots(figsize=(1.8 * len(splits) + 2, 3.2))
    ax.bar(x - 0.2, s, 0.4, label="S: strategy choice" + (" (n/a)" if all(np.isnan(s)) else ""))
    ax.bar(x + 0.2, g, 0.4, label="G: grasp success")
    ax.set_xticks(x, splits)
    ax.set_ylim(0, 105)
    ax.set_ylabel("%")
    ax.set_title(f"policy {summary['config']['policy']}"[-60:])
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    with replacing(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    plt.close(fig)


def _slug(policy: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", policy).strip("_")[-80:] or "policy"


# ----------------------------------------------------------------------------- CLI
def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="flatlab eval",
        description="S/G evaluation of a policy (built-in scripted or any LeRobot checkpoint) over objects x trials, "
        "episode for episode the same as lerobot-eval --env.type=flatlab. Extra --env.<field>=<value> and "
        "--policy.<field>=<value> arguments are passed on as in lerobot-eval.",
    )
    ap.add_argument("--policy", default="oracle",
                    help=f"one of {', '.join(BUILTIN)}; or a LeRobot pretrained_model folder / training output folder; "
                    "or a hub repo id (default oracle)")  # fmt: skip
    ap.add_argument("--splits", default=",".join(BENCHMARK_SPLITS), help="comma-separated splits (default: all three)")
    ap.add_argument("--objects", default="", help="comma-separated object ids (overrides --splits; ref_* allowed)")
    ap.add_argument("--trials", type=int, default=5, help="trials per object (default 5)")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED,
                    help=f"trial t uses episode seed SEED + t, as lerobot-eval's episode t (default {DEFAULT_SEED}, lerobot-eval's)")  # fmt: skip
    ap.add_argument("--workers", type=int, default=2, help="worker processes (default 2; 1 = in-process)")
    ap.add_argument(
        "--torch-threads",
        type=int,
        default=None,
        help="torch CPU threads per worker (default: torch's own, as in lerobot-eval; 1 avoids oversubscribing "
        "2 cores with 2 workers but may change a learned policy's float rounding)",
    )
    ap.add_argument("--render-every-step", action="store_true",
                    help="render the clouds at every step, also where the policy says it will not read them "
                    "(policy.reads_next_clouds; the episodes are the same, only slower: for checking that)")  # fmt: skip
    ap.add_argument("--device", default=None, help="policy device (shortcut for --policy.device=...)")
    ap.add_argument("--rename-map", default="{}", help="JSON observation rename map, as lerobot-eval's --rename_map")
    ap.add_argument(
        "--max-trials", type=int, default=None, help="stop after this many newly finished trials (resume later)"
    )
    ap.add_argument("--out", type=Path, default=None, help="output folder (default outputs/eval/<policy>)")
    ap.add_argument("--no-plot", action="store_true")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def _split_extra(extra: list[str]) -> tuple[list[str], list[str]]:
    env_args, policy_args = [], []
    it = iter(extra)
    for a in it:
        for prefix, dest in (("--env.", env_args), ("--policy.", policy_args)):
            if a.startswith(prefix):
                body = a[len(prefix) :]
                if "=" not in body:  # "--env.image_size 32"
                    body = f"{body}={next(it, '')}"
                dest.append("--" + body)
                break
        else:
            raise EvalError(
                f"unrecognized argument {a!r} (extra arguments must be --env.<field>=<value> or --policy.<field>=<value>)"
            )
    return env_args, policy_args


def evaluator_for(policy: str, seed: int, extra: list[str]) -> Evaluator:
    """An in-process :class:`Evaluator` for the scripts that run ``flatlab eval``'s trials one by one
    (``scripts/trace_episode.py``, ``scripts/response_probe.py``): ``policy`` as ``--policy``, ``extra`` the
    ``--env.*`` / ``--policy.*`` flags (anything else is refused, as ``flatlab eval`` refuses it)."""
    env_args, policy_args = _split_extra(extra)
    path, builtin = resolve_policy(policy)
    return Evaluator({"policy": path, "builtin": builtin, "rename_map": {}, "seed": seed,
                      "env_args": env_args, "policy_args": policy_args})  # fmt: skip


def main(argv=None) -> int:
    args, extra = build_parser().parse_known_args(argv)
    env_args, policy_args = _split_extra(extra)
    if args.device:
        policy_args.append(f"--device={args.device}")
    if args.trials < 1:
        raise EvalError("--trials must be >= 1")
    try:
        rename_map = json.loads(args.rename_map)
    except json.JSONDecodeError as e:
        raise EvalError(f"--rename-map: not JSON ({e})") from e
    import flatlab_lerobot  # noqa: F401  registers the flatlab env and policy types
    from flatlab_lerobot.paths import OUTPUTS_DIR

    policy, builtin = resolve_policy(args.policy)
    env_cfg = make_env_config(env_args, builtin)
    policy_cfg = load_policy_config(policy, builtin, policy_args)
    if not builtin:
        from flatlab_lerobot.lerobot_env import PolicyEnvMismatch, check_policy_features

        try:
            check_policy_features(policy_cfg, env_cfg, where=f"--policy {policy}", rename_map=rename_map)
        except PolicyEnvMismatch as e:
            raise EvalError(str(e)) from None
    out = args.out or OUTPUTS_DIR / "eval" / _slug(args.policy)
    out.mkdir(parents=True, exist_ok=True)
    splits = [s.strip() for s in args.splits.split(",") if s.strip()]
    objects = select_objects(splits, [o.strip() for o in args.objects.split(",") if o.strip()])
    env_desc = {k: v for k, v in env_cfg.gym_kwargs.items() if k != "object_id"} | {"fps": env_cfg.fps}
    run = {"policy": policy, "seed": args.seed, "env": env_desc, "policy_args": policy_args, "rename_map": rename_map}
    check_run(out, run)
    config = {**run, "objects": objects, "trials": args.trials, "policy_type": policy_cfg.type}
    jsonl = out / RESULTS_JSONL
    done = load_done(jsonl, policy)
    jobs = []
    for o in objects:
        todo = [t for t in range(args.trials) if (o, t) not in done]
        if todo:
            jobs.append({"object_id": o, "trials": todo, "slow": get_object(o).material == "deformable"})
    jobs.sort(key=lambda j: not j["slow"])  # slow (cloth) objects first: the two workers end together
    total = len(objects) * args.trials
    n_todo = sum(len(j["trials"]) for j in jobs)
    budget = n_todo if args.max_trials is None else min(n_todo, args.max_trials)
    spec = {"policy": policy, "builtin": builtin, "env_args": env_args, "policy_args": policy_args,
            "rename_map": rename_map, "seed": args.seed, "render_every_step": args.render_every_step}  # fmt: skip
    if budget > 0 and args.workers <= 1:
        trials = _run_in_process(spec, jobs)
    elif budget > 0:  # start the workers before any thread (tqdm's monitor) exists in this process
        trials = _run_workers(spec, jobs, min(args.workers, len(jobs)), args.torch_threads)
    from tqdm import tqdm

    bar = tqdm(
        total=total, initial=total - n_todo, desc=f"eval {_slug(args.policy)[-30:]}", unit="trial", disable=args.quiet
    )
    finished = 0
    with open(jsonl, "a") as f:

        def record(rec):
            f.write(json.dumps(rec) + "\n")
            f.flush()
            os.fsync(f.fileno())
            done[(rec["object_id"], rec["trial"])] = rec
            bar.update(1)
            bar.set_postfix(G=f"{_rate(list(done.values()), 'G'):.2f}")

        if budget > 0:
            try:
                for rec in trials:
                    record(rec)
                    finished += 1
                    if finished >= budget:
                        break
            finally:
                trials.close()
    bar.close()
    remaining = sum(1 for o in objects for t in range(args.trials) if (o, t) not in done)
    if remaining:
        print(f"{finished} trials finished this run, {remaining} left: run the same command again to resume ({jsonl})")
        return 0
    records = [done[(o, t)] for o in objects for t in range(args.trials)]
    summary = summarize(records, config)
    write_text(out / "results.json", json.dumps(summary, indent=2))
    write_text(out / "results.md", markdown(summary))
    if not args.no_plot:
        plot(summary, out / "results.png")
    ov = summary["overall"]
    print(f"policy {args.policy}: S {_pct(ov['S'])}%  G {_pct(ov['G'])}% over {ov['trials']} trials; {out}")
    return 0


def _run_in_process(spec: dict, jobs: list[dict]):
    """The trials of ``jobs`` in this process, as they finish."""
    _quiet_lerobot_bars()
    ev = Evaluator(spec)
    for job in jobs:
        gen = ev.run_object(job["object_id"], job["trials"])
        try:
            yield from gen
        finally:
            gen.close()  # closes the env when the caller stops early


def _run_workers(spec: dict, jobs: list[dict], n: int, threads: int | None = None):
    """Start ``n`` worker processes on ``jobs`` (whole objects) and return a generator of
    their trial records as they arrive.  Closing it (budget reached, error, interrupt) kills them.

    Workers are *spawned* (fresh interpreters, each imports lerobot once, a few seconds):
    forking the caller itself deadlocked when it had already run torch / GL threads (seen in
    the test suite: a forked child stuck on a futex forever)."""
    ctx = mp.get_context("spawn")
    job_q, res_q = ctx.Queue(), ctx.Queue()
    for job in jobs:
        job_q.put(job)
    for _ in range(n):
        job_q.put(None)
    spec = {**spec, "parent_pid": os.getpid()}
    procs = [ctx.Process(target=_worker, args=(spec, job_q, res_q, threads), daemon=True) for _ in range(n)]
    for p in procs:
        p.start()

    def results(_keep=(job_q, res_q)):  # the queues live as long as the generator: a spawned child
        # rebuilds their semaphores by name, and a collected Queue unlinks them (FileNotFoundError)
        objects_left = len(jobs)
        try:
            while objects_left > 0:
                try:
                    kind, payload = res_q.get(timeout=1.0)
                except queue_mod.Empty:
                    dead = [p for p in procs if p.exitcode not in (None, 0)]
                    if dead:
                        raise EvalError(
                            f"worker {dead[0].pid} died (exit code {dead[0].exitcode}); finished trials are saved, rerun to resume"
                        ) from None
                    if all(p.exitcode == 0 for p in procs):
                        raise EvalError("the workers exited with objects left; rerun to resume") from None
                    continue
                if kind == "trial":
                    yield payload
                elif kind == "object":
                    objects_left -= 1
                else:
                    raise EvalError(f"a worker failed; finished trials are saved.\n{payload}")
        finally:
            for p in procs:
                if p.is_alive():
                    p.terminate()
            for p in procs:
                p.join(timeout=10)
                if p.is_alive():
                    p.kill()
                    p.join()
            for q in _keep:  # release their semaphores now (else: "leaked semaphore" warnings at exit)
                q.close()
                q.cancel_join_thread()

    return results()


if __name__ == "__main__":
    raise SystemExit(main())

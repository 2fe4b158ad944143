"""The paper's results as one pipeline of cached stages (``flatlab paper``).

A **stage** is one real command (``flatlab strategy-set``, ``lerobot-train --config_path=...``,
``flatlab strategy-eval``, ``flatlab eval --policy ...``, ...) with an output folder and a small
results JSON (its **record**).  Stages are data: ``stages.yaml`` holds the registry (command
templates), ``presets/<name>.yaml`` the sizes, lists and sweeps of a preset.  Nothing here knows
what a stage does; a new policy or baseline is a new entry in those files.

Templates.  ``${var}`` is a preset variable (or a field of the ``for:`` item a stage is expanded
from); an argv item that is exactly ``${var}`` and names a list is spliced in, its own ``${var}``
items resolved too (a ``for:`` item's ``args`` may name a list the preset shares).  At run time
``{out}`` is the stage's own folder (``--out``/<stage>), ``{<stage>}`` another stage's folder
(which makes that stage an input), ``{record:<stage>}`` another stage's record path, and an item
``{jsonlist:<stage>/<file>#<key>}`` is replaced by the list under ``key`` in that stage's JSON file
(the env flags ``flatlab unified-build`` wrote for its artifact).

Cache.  A stage is **done** when its record exists with the same fingerprint: a hash of its
expanded command, the preset's environment variables, the recipe files it names (their bytes)
and its inputs' fingerprints.  The code version is *not* in the fingerprint (the commit is in the
record); ``--force STAGE`` reruns a stage from scratch (its output folder is discarded first, as a
stale stage's is).  A record without a fingerprint (written before this pipeline, or a stage's
``legacy`` file) is an **earlier run**: it is rendered and not rerun unless forced.  A missing
stage's command resumes what an interrupted run left (``flatlab eval``/``primitive-set`` keep
finished trials / shards, ``lerobot-train`` resumes from its last checkpoint).

Needs.  ``gpu`` (no CUDA here: *needs GPU*), ``weights:<hub id>`` (not in the HF cache: *needs
weights*), ``module:<python module>``, ``cli:<flatlab subcommand>`` and ``recipe:<path>`` (not in
this tree: *not available*), ``todo:<what is missing>`` (always *not available*).  A stage with an unmet need, or an input with one, is **blocked** and
reported as such by ``--dry-run`` and in the rendered tables.
"""

from __future__ import annotations

import copy
import datetime as _dt
import fnmatch
import hashlib
import importlib.util
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from flatlab_lerobot.atomic import write_json
from flatlab_lerobot.paths import OUTPUTS_DIR

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
PRESETS_DIR = HERE / "presets"
REGISTRY = HERE / "stages.yaml"
KINDS = ("learning-set", "train", "build", "eval", "metrics")
VAR = re.compile(r"\$\{(\w+)\}")
REF = re.compile(r"\{(record:)?([\w.-]+)\}")
JSONLIST = re.compile(r"\{jsonlist:([\w.-]+)/([^#}]+)#(\w+)\}")  # a list in an input stage's JSON, spliced
REPO_FILE = re.compile(r"(?:policies|datasets)/[\w./-]+\.(?:json|ya?ml)")


class PaperError(SystemExit):
    def __init__(self, msg: str):
        super().__init__(f"flatlab paper: {msg}")


@dataclass
class Stage:
    name: str
    kind: str
    cmd: list[str]
    what: str = ""
    needs: list[str] = field(default_factory=list)
    inputs: list[str] = field(default_factory=list)
    result: str | None = None  # metrics/eval stages: record path under the results dir (+ preset prefix)
    metrics: str | None = None  # the tool's JSON folded into the record
    legacy: list[str] = field(default_factory=list)  # earlier measured files that stand for this stage
    fresh: bool = False  # the tool refuses an existing output: remove a partial one first
    report: dict = field(default_factory=dict)  # how the renderer uses the result

    @property
    def is_result(self) -> bool:
        return self.result is not None


# ----------------------------------------------------------------------------- registry
def presets() -> list[str]:
    return sorted(p.stem for p in PRESETS_DIR.glob("*.yaml"))


def load_preset(name: str) -> dict:
    path = PRESETS_DIR / f"{name}.yaml"
    if not path.is_file():
        raise PaperError(f"--preset {name}: no {path.relative_to(REPO)} (presets: {', '.join(presets())})")
    p = yaml.safe_load(path.read_text()) or {}
    p.setdefault("name", name)
    p.setdefault("vars", {})
    p.setdefault("env", {})
    p.setdefault("results_prefix", "")
    p.setdefault("sweeps", [])
    _expand_sweeps(p)
    return p


def _expand_sweeps(p: dict) -> None:
    """Each sweep value becomes a run of the sweep's list (a copy of its base run plus one CLI
    override), except the base value itself and values ``same_as`` an existing run."""
    for sw in p["sweeps"]:
        runs = p["vars"].setdefault(sw["list"], [])
        base = next((r for r in runs if r["id"] == sw["base"]), None)
        if base is None:
            raise PaperError(f"preset {p['name']}: sweep {sw['id']}: base run {sw['base']!r} not in {sw['list']}")
        same = {float(k): v for k, v in (sw.get("same_as") or {}).items()}
        sw["runs"] = {}
        for v in sw["values"]:
            if float(v) == float(sw["default"]):
                rid = base["id"]
            elif float(v) in same:
                rid = same[float(v)]
            else:
                rid = f"{sw['id']}_{v}"
                run = copy.deepcopy(base)
                run.update(id=rid, row="", legacy=[], overrides=[*base.get("overrides", []), f"{sw['flag']}={v}"])
                runs.append(run)
            sw["runs"][v] = rid


def _subst(value, env: dict, where: str, inside: tuple[str, ...] = ()):
    """``${var}`` in strings / lists / dicts; an item that is exactly ``${var}`` takes the value, its own
    ``${var}`` items resolved too (a stage's ``args`` may name a preset's shared flag list; a list item
    that is a list is spliced)."""
    if isinstance(value, str):
        m = VAR.fullmatch(value)
        if m:
            if m[1] not in env:
                raise PaperError(f"{where}: ${{{m[1]}}} is not a preset variable")
            if m[1] in inside:
                raise PaperError(f"{where}: ${{{m[1]}}} refers to itself (through {' -> '.join(inside)})")
            return _subst(copy.deepcopy(env[m[1]]), env, where, (*inside, m[1]))

        def one(m):
            if m[1] not in env:
                raise PaperError(f"{where}: ${{{m[1]}}} is not a preset variable")
            return str(env[m[1]])

        return VAR.sub(one, value)
    if isinstance(value, list):
        out = []
        for item in value:
            v = _subst(item, env, where, inside)
            if isinstance(item, str) and VAR.fullmatch(item) and isinstance(v, list):
                out.extend(v)
            elif v is not None or not (isinstance(item, str) and VAR.fullmatch(item)):
                out.append(v)
        return out
    if isinstance(value, dict):
        return {k: _subst(v, env, where, inside) for k, v in value.items()}
    return value


def build_stages(preset: dict) -> dict[str, Stage]:
    """The preset's stages, in registry order (an input always precedes its users)."""
    entries = yaml.safe_load(REGISTRY.read_text())
    stages: dict[str, Stage] = {}
    for entry in entries:
        entry = dict(entry)
        loop, defaults = entry.pop("for", None), entry.pop("defaults", {})
        only = entry.pop("presets", None)
        if only and preset["name"] not in only:
            continue
        items = [{}] if loop is None else preset["vars"].get(loop) or []
        for item in items:
            env = {**defaults, **preset["vars"], **item}
            where = f"stages.yaml {entry.get('name')} ({preset['name']})"
            st = _subst(entry, env, where)
            st["cmd"] = [str(a) for a in st["cmd"]]
            if st["kind"] not in KINDS:
                raise PaperError(f"{where}: kind {st['kind']!r} not one of {KINDS}")
            if st["name"] in stages:
                raise PaperError(f"{where}: stage {st['name']} defined twice")
            stage = Stage(**st)
            stage.needs = [n for n in stage.needs if n]
            stage.legacy = [x for x in stage.legacy if x]
            refs = [m[2] for a in stage.cmd for m in REF.finditer(a) if m[2] != "out"]
            refs += [m[1] for a in stage.cmd if (m := JSONLIST.fullmatch(a))]
            for r in refs:
                if r not in stages:
                    raise PaperError(f"{where}: {{{r}}} names no earlier stage")
            stage.inputs = list(dict.fromkeys([*stage.inputs, *refs]))
            stages[stage.name] = stage
    return stages


# ----------------------------------------------------------------------------- state
@dataclass
class Context:
    preset: dict
    stages: dict[str, Stage]
    out_root: Path
    results_dir: Path

    def out(self, name: str) -> Path:
        return self.out_root / name

    def record_path(self, name: str) -> Path:
        st = self.stages[name]
        rel = st.result if st.is_result else f"stages/{name}.json"
        return self.results_dir / f"{self.preset['results_prefix']}{rel}"

    def log_path(self, name: str) -> Path:
        return self.out_root / "logs" / f"{name}.log"


def _read(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _file_hash(rel: str) -> str | None:
    p = REPO / rel
    return hashlib.sha256(p.read_bytes()).hexdigest()[:16] if p.is_file() else None


def fingerprints(ctx: Context) -> dict[str, str]:
    fps: dict[str, str] = {}
    for name, st in ctx.stages.items():
        files = {f: _file_hash(f) for a in st.cmd for f in REPO_FILE.findall(a)}
        blob = {"cmd": st.cmd, "env": ctx.preset["env"], "files": files, "inputs": {i: fps[i] for i in st.inputs}}
        fps[name] = hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()[:16]
    return fps


_CUDA: list[bool] = []


def cuda_available() -> bool:
    if not _CUDA:
        try:
            import torch

            _CUDA.append(bool(torch.cuda.is_available()))
        except ImportError:
            _CUDA.append(False)
    return _CUDA[0]


def unmet(need: str) -> str | None:
    """Why ``need`` is not met here (a short status), or None."""
    kind, _, arg = need.partition(":")
    if kind == "gpu":
        return None if cuda_available() else "needs GPU"
    if kind == "weights":
        hub = Path(os.environ.get("HF_HUB_CACHE") or Path(os.environ.get("HF_HOME", Path.home() / ".cache/huggingface")) / "hub")
        return None if (hub / f"models--{arg.replace('/', '--')}").is_dir() else f"needs weights ({arg})"
    if kind == "module":
        try:
            found = importlib.util.find_spec(arg) is not None
        except ModuleNotFoundError:
            found = False
        return None if found else f"not available ({arg} not in this tree)"
    if kind == "cli":
        from flatlab_lerobot.cli import PASSTHROUGH

        return None if arg in PASSTHROUGH else f"not available (no `flatlab {arg}`)"
    if kind == "todo":  # a stage registered before what it needs exists (say what is missing)
        return f"not available ({arg})"
    if kind == "recipe":
        return None if (REPO / arg).is_file() else f"not available ({arg} not in this tree)"
    raise PaperError(f"unknown need {need!r} (gpu, weights:, module:, cli:, recipe:, todo:)")


@dataclass
class Status:
    state: str  # done | earlier | missing | stale | blocked
    reason: str = ""
    record: dict | None = None
    record_path: Path | None = None


def statuses(ctx: Context, fps: dict[str, str] | None = None) -> dict[str, Status]:
    fps = fps or fingerprints(ctx)
    out: dict[str, Status] = {}
    for name, st in ctx.stages.items():
        path = ctx.record_path(name)
        rec = _read(path)
        why = next((u for u in map(unmet, st.needs) if u), None)
        if why is None:
            why = next((f"{i}: {out[i].reason}" for i in st.inputs if out[i].state == "blocked"), None)
        meta = (rec or {}).get("paper_stage")
        if meta and meta.get("fingerprint") == fps[name]:
            # the config is the same (the inputs too: they are in the fingerprint); an input rebuilt since (another
            # digest of its data) makes the record stale
            moved = next((i for i, d in meta.get("input_digests", {}).items()
                          if record_digest(out[i].record) not in (None, d)), None)  # fmt: skip
            out[name] = (Status("stale", f"input {moved} rebuilt since its record", rec, path) if moved
                         else Status("done", record=rec, record_path=path))  # fmt: skip
        elif rec is not None and not meta:
            out[name] = Status("earlier", "measured before `flatlab paper` (no fingerprint)", rec, path)
        elif legacy := next((ctx.results_dir / x for x in st.legacy if (ctx.results_dir / x).is_file()), None):
            out[name] = Status("earlier", f"earlier run: {legacy.name}", _read(legacy), legacy)
        elif why:
            out[name] = Status("blocked", why)
        elif meta:
            out[name] = Status("stale", "config changed since its record", rec, path)
        else:
            out[name] = Status("missing", "not run")
    return out


def plan(ctx: Context, targets: list[str], force: set[str], st: dict[str, Status]) -> list[str]:
    """Stages to run for ``targets``, inputs first: a target not done, and every input of a stage to
    run whose record is not done or whose output folder is gone.  A stage downstream of a forced one
    is not done either: its record describes the output the forced stage is about to replace."""
    todo: list[str] = []
    above: dict[str, bool] = {}

    def forced_above(name: str) -> bool:
        if name not in above:
            above[name] = any(i in force or forced_above(i) for i in ctx.stages[name].inputs)
        return above[name]

    def need(name: str, as_input: bool) -> None:
        if name in todo:
            return
        s = st[name]
        done = s.state in ("done", "earlier") and name not in force and not forced_above(name)
        if done and (not as_input or ctx.stages[name].is_result or ctx.out(name).exists()):
            return
        for i in ctx.stages[name].inputs:
            need(i, True)
        todo.append(name)

    for t in targets:
        need(t, False)
    order = list(ctx.stages)
    return sorted(todo, key=order.index)


def select(ctx: Context, patterns: list[str] | None) -> list[str]:
    if not patterns:
        return [n for n, s in ctx.stages.items() if s.is_result]
    names = []
    for p in patterns:
        hit = [n for n in ctx.stages if fnmatch.fnmatchcase(n, p)]
        if not hit:
            raise PaperError(f"--only {p}: no such stage in preset {ctx.preset['name']} (see --dry-run)")
        names += hit
    return list(dict.fromkeys(names))


# ----------------------------------------------------------------------------- commands
def argv(ctx: Context, st: Stage, display: bool = False) -> list[str]:
    """The stage's command: real paths, or for display ``$OUT/<stage>`` and ``$RESULTS/<record>``."""

    def ref(m):
        name = st.name if m[2] == "out" else m[2]
        if m[1]:
            p = ctx.record_path(name)
            return f"$RESULTS/{p.relative_to(ctx.results_dir)}" if display else str(p)
        return f"$OUT/{name}" if display else str(ctx.out(name))

    out = []
    for a in st.cmd:
        m = JSONLIST.fullmatch(a)
        if m is None:
            out.append(REF.sub(ref, a))
        elif display:
            out.append(f"<{m[3]} of $OUT/{m[1]}/{m[2]}>")
        else:  # an input's JSON names flags for this command (e.g. the env flags a built policy needs)
            out += [str(x) for x in json.loads((ctx.out(m[1]) / m[2]).read_text())[m[3]]]
    if display:
        return out
    prog = out[0]
    if prog == "flatlab":
        return [sys.executable, "-m", "flatlab_lerobot.cli", *out[1:]]
    exe = Path(sys.executable).with_name(prog)
    return [str(exe) if exe.exists() else prog, *out[1:]]


_PLAIN = re.compile(r"[\w@%+=:,./$\[\]-]+")


def display(ctx: Context, st: Stage) -> str:
    """The command as a user would type it ($OUT / $RESULTS left for the shell to expand)."""
    return " ".join(a if _PLAIN.fullmatch(a) else shlex.quote(a) for a in argv(ctx, st, display=True))


def machine() -> dict:
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu_count": os.cpu_count(), "cpu_model": model, "platform": platform.platform(),
            "python": platform.python_version()}  # fmt: skip


def device() -> str:
    if cuda_available():
        import torch

        return f"cuda ({torch.cuda.get_device_name(0)})"
    return "cpu"


def machine_line() -> str:
    """``machine()`` and ``device()`` as the one line the hand-run result records carry."""
    m = machine()
    return f"{m['cpu_count']} CPU cores ({m['cpu_model']}), device {device()}"


def git_commit() -> dict:
    def git(*a):
        r = subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True)
        return r.stdout.strip() if r.returncode == 0 else None

    if os.environ.get("FLATLAB_GIT_COMMIT"):  # a copy of the tree whose .git is absent or stale (a lent GPU machine)
        return {"commit": os.environ["FLATLAB_GIT_COMMIT"], "dirty": False, "from": "FLATLAB_GIT_COMMIT"}
    return {"commit": git("rev-parse", "HEAD"), "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}


def _seeds(cmd: list[str]) -> dict:
    seeds = {}
    for i, a in enumerate(cmd):
        m = re.match(r"--(?:[\w.]+\.)?(seed|seeds)(?:=(.*))?$", a)
        if m:
            seeds[a.split("=")[0].lstrip("-")] = m[2] if m[2] is not None else (cmd[i + 1] if i + 1 < len(cmd) else None)
    for f in {f for a in cmd for f in REPO_FILE.findall(a) if f.endswith(".json")}:
        try:
            if (s := json.loads((REPO / f).read_text()).get("seed")) is not None:
                seeds[f"{f}:seed"] = s
        except (OSError, json.JSONDecodeError, AttributeError):
            pass
    return seeds


def _resume_train(ctx: Context, st: Stage, cmd: list[str]) -> list[str]:
    """lerobot-train refuses an existing output dir: resume from its last checkpoint, or start over."""
    out = ctx.out(st.name)
    last = out / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    if last.is_file():
        return [cmd[0], f"--config_path={last}", "--resume=true"]
    if out.exists():
        shutil.rmtree(out)
    return cmd


SEGMENT_START = "# segment started "
SEGMENT_STARTED = re.compile(rf"^{re.escape(SEGMENT_START)}(\S+)$", re.M)
SEGMENT_END = re.compile(r"^# segment ended \S+ after ([\d.]+) s", re.M)


def _utc(t: float | None = None) -> str:
    t = time.time() if t is None else t
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).isoformat(timespec="seconds")


def _segment_end(wall: float, why: str, t: float | None = None) -> str:
    """The log line that closes a run of a stage (read back by ``SEGMENT_END``)."""
    return f"\n# segment ended {_utc(t)} after {wall:.1f} s ({why})\n"


def _earlier_segments(log: Path) -> list[float]:
    """Wall times (s) of the earlier runs of a stage this run resumes, from its log: each run writes
    '# segment started <UTC>' and, when it returns, '# segment ended <UTC> after <s> s'. A run that was
    killed wrote no end: it ended at the log's last write (lerobot-train and flatlab eval write progress
    all along), and that end is appended now. A log from before the markers gives none."""
    if not log.is_file():
        return []
    text = log.read_text(errors="replace")
    walls = [float(w) for w in SEGMENT_END.findall(text)]
    starts = list(SEGMENT_STARTED.finditer(text))
    if starts and not SEGMENT_END.search(text, starts[-1].end()):
        try:
            t0 = _dt.datetime.fromisoformat(starts[-1][1]).timestamp()
        except ValueError:
            return walls
        end = log.stat().st_mtime
        wall = round(max(0.0, end - t0), 1)
        with open(log, "a") as f:
            f.write(_segment_end(wall, "interrupted: no exit written", end))
        walls.append(wall)
    return walls


def _trials_saved(out: Path) -> int:
    """Finished trials an evaluation's ``results.jsonl`` holds, as ``flatlab eval`` counts them when it resumes."""
    from flatlab_lerobot.evaluation.protocol import saved_trials  # the eval's own bookkeeping (lazy: heavy imports)

    return len(saved_trials(out / "results.jsonl"))


DATA_SUFFIXES = (".npy", ".parquet", ".safetensors")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def content_hashes(out: Path, files: list[Path]) -> dict:
    """Digests that let two machines' outputs be compared from their records alone: ``content_sha256`` over the
    data files (arrays, parquet tables, weights; by relative path, in order), which leaves out what records a
    run rather than its result (wall times and paths in json, logs, videos); ``model_sha256``, the weights a
    later stage loads (the output's own ``model.safetensors``, else the last numbered checkpoint's)."""
    data = sorted((p for p in files if p.suffix in DATA_SUFFIXES and "last" not in p.relative_to(out).parts),
                  key=lambda p: p.relative_to(out).as_posix())  # fmt: skip
    if not data:
        return {}
    h, sums = hashlib.sha256(), {}
    for p in data:
        sums[p] = _sha256(p)
        h.update(f"{p.relative_to(out).as_posix()}\0{sums[p]}\n".encode())
    res = {"content_sha256": h.hexdigest()}
    models = [p for p in data if p.name == "model.safetensors"]  # in path order, as ``data``
    if models:
        res["model_sha256"] = sums[next((p for p in models if p.parent == out), models[-1])]
    return res


def record_digest(rec: dict | None) -> str | None:
    """The digest of what a stage made, from its record (``content_sha256``; None for a record without one:
    a result, or a record written before the digests existed)."""
    return ((rec or {}).get("metrics") or {}).get("content_sha256")


def _output_summary(out: Path, log: Path) -> dict:
    """What a non-metrics stage made: its output's size and content digests (:func:`content_hashes`) and, for a
    training, the last logged loss and step."""
    files = [p for p in out.rglob("*") if p.is_file()] if out.is_dir() else []
    res: dict = {"output_files": len(files), "output_bytes": sum(p.stat().st_size for p in files)}
    res.update(content_hashes(out, files))
    steps = re.findall(r"step:(\S+) .*?loss:([\d.]+)", log.read_text()) if log.is_file() else []
    if steps:
        res["last_logged_step"], res["last_logged_loss"] = steps[-1][0], float(steps[-1][1])
    return res


SUBST = re.compile(r"\$\((.+)\)")


def _expand_subcommands(ctx: Context, st: Stage, cmd: list[str], env: dict) -> list[str]:
    """``$(flatlab ...)`` inside an argv item: run it (paths substituted like the stage's) and put its
    stripped stdout there, as a shell would (e.g. ``--dataset.episodes=$(flatlab collect ... --successful-episodes)``)."""
    out = []
    for a in cmd:
        m = SUBST.search(a)
        if m:
            sub = argv(ctx, Stage(st.name, st.kind, shlex.split(m[1])))
            r = subprocess.run(sub, cwd=REPO, env=env, capture_output=True, text=True)
            if r.returncode != 0:
                raise PaperError(f"stage {st.name}: $({m[1]}) failed: {r.stderr[-2000:]}")
            a = a[: m.start()] + r.stdout.strip() + a[m.end() :]
        out.append(a)
    return out


def run_stage(ctx: Context, st: Stage, fp: str, fps: dict[str, str], restart: bool = False) -> dict:
    """Run one stage and write its record; ``restart``: discard its output first (no resume)."""
    cmd = argv(ctx, st)
    out = ctx.out(st.name)
    if restart and out.exists():
        shutil.rmtree(out)
    if st.kind == "train":
        cmd = _resume_train(ctx, st, cmd)
    elif st.fresh and out.exists():
        shutil.rmtree(out)
    if st.is_result:
        out.mkdir(parents=True, exist_ok=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, **{k: str(v) for k, v in ctx.preset["env"].items()})
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    env.setdefault("MUJOCO_GL", "egl")
    cmd = _expand_subcommands(ctx, st, cmd, env)
    log = ctx.log_path(st.name)
    log.parent.mkdir(parents=True, exist_ok=True)
    created = _utc()
    before = _trials_saved(out) if st.kind == "eval" else 0  # an interrupted run's trials: this run resumes after them
    resuming = before > 0 or (st.kind == "train" and "--resume=true" in cmd)
    earlier = _earlier_segments(log) if resuming else []  # the log keeps every run of a resumed stage
    t0 = time.perf_counter()
    with open(log, "a" if resuming else "w") as f:
        f.write(f"{SEGMENT_START}{created}\n$ {shlex.join(cmd)}\n")
        f.flush()
        r = subprocess.run(cmd, cwd=REPO, env=env, stdout=f, stderr=subprocess.STDOUT)
        wall = round(time.perf_counter() - t0, 1)
        f.write(_segment_end(wall, f"exit {r.returncode}"))
    if r.returncode != 0:
        tail = "\n".join(log.read_text().splitlines()[-25:])
        raise PaperError(f"stage {st.name} failed (exit {r.returncode}, {wall} s); log {log}:\n{tail}")
    rec: dict = {"metrics": _output_summary(out, log)}
    if st.metrics:
        mpath = Path(REF.sub(lambda m: str(ctx.out(st.name if m[2] == "out" else m[2])), st.metrics))
        rec = _read(mpath)
        if rec is None:
            raise PaperError(f"stage {st.name}: its command wrote no JSON at {mpath}")
    rec["paper_stage"] = {
        "stage": st.name, "kind": st.kind, "preset": ctx.preset["name"], "what": st.what,
        "command": display(ctx, st), "command_run": shlex.join(cmd), "fingerprint": fp,
        "inputs": {i: fps[i] for i in st.inputs},
        "input_digests": {i: d for i in st.inputs if (d := record_digest(_read(ctx.record_path(i))))},
        "seeds": _seeds(st.cmd), "env": ctx.preset["env"],
        "git": git_commit(), "wall_s": round(wall + sum(earlier), 1), "machine": machine(), "device": device(),
        "created": created, "output": f"$OUT/{st.name}",
    }  # fmt: skip
    if earlier:  # a resumed stage: wall_s sums its runs (the earlier ones from its log)
        rec["paper_stage"]["wall_s_segments"] = [*earlier, wall]
    if before:  # without earlier segments in the log, wall_s covers this run's trials only
        rec["paper_stage"]["resumed"] = {"trials_before": before, "trials_this_run": _trials_saved(out) - before}
    write_json(ctx.record_path(st.name), rec)
    return rec


# ----------------------------------------------------------------------------- CLI
def context(preset: str, out: Path | None, results_dir: Path | None) -> Context:
    p = load_preset(preset)
    return Context(p, build_stages(p), (out or OUTPUTS_DIR / "paper" / preset).resolve(),
                   (results_dir or REPO / "docs" / "results").resolve())  # fmt: skip

"""The package's import graph: no cycles, and layers that never import upward.

Built from the source with ``ast`` (every ``import``, also the lazy ones inside functions), so a
cycle hidden behind a function-level import fails here too, without importing anything heavy."""

from __future__ import annotations

import ast
import importlib
import pkgutil
from pathlib import Path

import pytest

import flatlab_lerobot

PKG = "flatlab_lerobot"
ROOT = Path(flatlab_lerobot.__file__).parent

# Layers, lowest first: a module may import its own layer's modules and the layers below only.
LAYERS: list[tuple[str, ...]] = [
    ("paths", "constants", "atomic"),  # leaves
    ("catalog",),  # typed specs from envs/ YAML
    ("assets",),  # geometry builders
    ("sim",),  # scene, physics, robot, cameras
    ("primitives", "strategies"),  # the scripted expert
    ("tasks", "transforms"),  # what an episode must achieve; object transforms and rule labels
    ("env",),  # the gymnasium env
    ("rollout", "demo"),  # the one episode loop and its simplest user
    ("lerobot_env", "policies", "collect", "learning", "evaluation", "bench", "viz", "assets_cli"),  # LeRobot-facing
    ("lerobot_plugin", "cli", "paper"),  # entry points; paper runs the other layers' commands
]


def _modules() -> dict[str, Path]:
    out = {PKG: ROOT / "__init__.py"}
    for info in pkgutil.walk_packages([str(ROOT)], prefix=PKG + "."):
        spec = importlib.util.find_spec(info.name)
        out[info.name] = Path(spec.origin)
    return out


MODULES = _modules()


def _resolve(name: str) -> str | None:
    """The package module ``name`` refers to (``a.b.C`` -> ``a.b`` when C is not a module)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(mod: str, path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    base = mod if is_pkg else mod.rpartition(".")[0]
    out = set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = base.split(".")
                root = ".".join(parts[: len(parts) - node.level + 1])
                mod_name = f"{root}.{node.module}" if node.module else root
            else:
                mod_name = node.module or ""
            names = [f"{mod_name}.{a.name}" for a in node.names] + [mod_name]
        for n in names:
            if n.startswith(PKG):
                target = _resolve(n)
                if target and target != mod and not mod.startswith(target + "."):
                    out.add(target)
    return out


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m) :] + [m]
            if m not in state and (c := visit(m)):
                return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (c := visit(n)):
            return c
    return None


def _layer(mod: str) -> int | None:
    top = mod.split(".")[1] if "." in mod else ""
    for i, names in enumerate(LAYERS):
        if top in names:
            return i
    return None


def test_every_module_has_a_layer():
    assert not [m for m in MODULES if m != PKG and _layer(m) is None], "add new top-level modules to LAYERS"


def test_module_graph_has_no_cycle():
    # package __init__ files that only re-export their submodules are not edges back up
    graph = {m: {t for t in ts if not m.startswith(t + ".")} for m, ts in GRAPH.items()}
    assert _find_cycle(graph) is None, f"import cycle: {' -> '.join(_find_cycle(graph))}"


def test_top_level_packages_have_no_cycle():
    top = {}
    for m, ts in GRAPH.items():
        a = m.split(".")[1] if "." in m else PKG
        for t in ts:
            b = t.split(".")[1] if "." in t else PKG
            if a != b and b != PKG:
                top.setdefault(a, set()).add(b)
    assert _find_cycle(top) is None, f"package-level import cycle: {' -> '.join(_find_cycle(top))}"


@pytest.mark.parametrize("mod", sorted(m for m in MODULES if _layer(m) is not None))
def test_layers_never_import_upward(mod):
    mine = _layer(mod)
    upward = sorted(t for t in GRAPH[mod] if (_layer(t) or -1) > mine)
    assert not upward, f"{mod} (layer {LAYERS[mine]}) imports from a higher layer: {upward}"


def test_catalog_imports_nothing_from_sim():
    assert not {t for t in GRAPH[f"{PKG}.catalog"] if t.startswith(f"{PKG}.sim")}


@pytest.mark.parametrize("mod", sorted(m for m in MODULES if not m.endswith(".__main__")))
def test_every_module_imports(mod):
    importlib.import_module(mod)


# Private attributes of a third-party class the package has to reach (no public API for them).
THIRD_PARTY_PRIVATE = {
    "_rect", "_mjr_context", "_gl_context",  # mujoco.Renderer: custom render passes (segmentation + depth)
    "_exit",  # os._exit: the documented way to leave a forked/spawned worker at once
    "_streaming_encoder",  # lerobot's dataset writer: whether it encodes video while recording
}


@pytest.mark.parametrize("mod", sorted(MODULES))
def test_no_access_to_another_objects_private_attributes(mod):
    """``x._name`` only on ``self`` / ``cls`` (tests may peek; the package may not)."""
    bad = []
    for node in ast.walk(ast.parse(MODULES[mod].read_text())):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            owner = node.value
            if isinstance(owner, ast.Name) and owner.id in ("self", "cls"):
                continue
            if node.attr in THIRD_PARTY_PRIVATE:
                continue
            bad.append(f"line {node.lineno}: {ast.unparse(node)}")
    assert not bad, f"{mod} reads private attributes of other objects: {bad}"

"""The layer contract of docs/architecture.md, checked on the source: every module imports only from its own
layer or below, never from inside a function, and core/ is torch alone."""

from __future__ import annotations

import ast
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "rmpfusion"

#: Bottom to top. Folders of one rank that must not import each other are listed in SIDE_BY_SIDE.
RANK = {
    "core": 0,
    "files": 0,
    "resolvers": 0,  # OmegaConf resolvers the shipped configs use
    "confdir": 0,  # where conf/ is (the configs, the robot files)
    "registry": 1,
    "examples": 1,
    "maps": 1,
    "rmps": 1,
    "weights": 1,
    "assembly": 2,
    "robots": 2,
    "scenes": 2,
    "recordings": 4,
    "sims": 3,  # simulator backends (pybullet, MuJoCo) behind one protocol
    "envs": 4,
    "learn": 5,
    "evaluate": 5,
    "plots": 6,
    "pipeline": 7,
    "studies": 8,  # the runs behind a results page: run, stored, tabled and checked over the pipeline's commands
    "cli": 9,
    "gym": 10,  # Gymnasium environments over experiments composed as the command line composes them
}
SIDE_BY_SIDE = {frozenset({"learn", "evaluate"})}
#: what core/ may import besides itself: the math needs torch and the standard library only
CORE_ALLOWED = {
    "torch",
    "__future__",
    "collections",
    "copy",
    "dataclasses",
    "logging",
    "math",
    "types",
    "typing",
    "warnings",
}


def _layer(module: str) -> str | None:
    """``rmpfusion.envs.manipulator.env`` -> ``envs``; the package root (its façade) has none."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def _module_of(path: pathlib.Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _target(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def violations(module: str, source: str, is_package: bool = False) -> list[str]:
    """Every import of ``module`` (given its source) that breaks the layer contract, said in one line each."""
    tree, here = ast.parse(source), _layer(module)
    inside_functions = {
        id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)) for n in ast.walk(f)
    }
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            targets = [_target(module, is_package, node)]
            if node.level and not node.module:  # ``from . import x``: x are modules of the package
                targets = [f"{targets[0]}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            continue
        for t in targets:
            own = t == "rmpfusion" or t.startswith("rmpfusion.")
            if here == "core" and not own and t.split(".")[0] not in CORE_ALLOWED:
                out.append(f"{module}:{node.lineno} core imports {t} (core/ is torch and the standard library only)")
            if not own or here is None:
                continue
            if id(node) in inside_functions:
                out.append(f"{module}:{node.lineno} imports {t} inside a function (import at the top)")
            there = _layer(t)
            if there is None or there not in RANK or here not in RANK:
                if there is not None and here is not None and there != here:
                    out.append(f"{module}:{node.lineno} imports {t}, a folder without a layer (add it to RANK)")
                continue
            if RANK[there] > RANK[here]:
                out.append(f"{module}:{node.lineno} imports {t}: {there}/ is above {here}/")
            elif there != here and frozenset({here, there}) in SIDE_BY_SIDE:
                out.append(f"{module}:{node.lineno} imports {t}: {there}/ and {here}/ sit side by side")
    return out


def _sources():
    for path in sorted(PACKAGE.rglob("*.py")):
        yield _module_of(path), path.read_text(), path.name == "__init__.py"


def test_every_folder_has_a_layer():
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    modules = {p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__"}
    assert folders | modules <= set(RANK), f"no layer for {sorted((folders | modules) - set(RANK))}"


def test_the_package_keeps_its_layers():
    found = [v for module, source, pkg in _sources() for v in violations(module, source, pkg)]
    assert not found, "\n".join(found)


@pytest.mark.parametrize(
    "module,source,expected",
    [
        ("rmpfusion.core.tree", "from ..assembly.tree import build_tree\n", "assembly/ is above core/"),
        ("rmpfusion.envs.particle2d", "from ..plots import plot_trajectories\n", "plots/ is above envs/"),
        ("rmpfusion.evaluate.metrics", "from ..learn.objectives import dataset_loss\n", "side by side"),
        ("rmpfusion.assembly.tree", "def f():\n    from ..maps import basic\n", "inside a function"),
        ("rmpfusion.core.gds", "import pydantic\n", "core imports pydantic"),
        ("rmpfusion.maps.basic", "import rmpfusion.pipeline.run\n", "pipeline/ is above maps/"),
    ],
)
def test_a_deliberate_breach_is_caught(module, source, expected):
    """The checker is not vacuous: each kind of breach, written into a module, is reported."""
    found = violations(module, source)
    assert any(expected in v for v in found), found


def test_importing_the_package_chooses_no_plotting_backend():
    """Nothing happens at import: importing every layer leaves matplotlib's backend choice to the user."""
    import subprocess
    import sys

    code = "import rmpfusion, rmpfusion.pipeline.run, rmpfusion.cli.run, sys; print('matplotlib.pyplot' in sys.modules)"
    r = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        env={"RMPFUSION_CONF": "/nonexistent", "PATH": "/usr/bin:/bin"},
    )
    assert r.returncode == 0, r.stderr  # and no conf/ lookup at import either: RMPFUSION_CONF points nowhere
    assert r.stdout.strip() == "False"


#: simulator engines: only their backends in rmpfusion/sims/ import them, so the task (sampling, rollouts, collisions,
#: metrics, figures) runs in any simulator the protocol serves, a plugin's included
SIMULATOR_MODULES = {"pybullet", "pybullet_data", "mujoco"}


def simulator_imports(module: str, source: str) -> list[str]:
    """Every import of a simulator engine in ``module`` (anywhere in it, functions included), one line each; none for
    the backends in rmpfusion/sims/."""
    if module.startswith("rmpfusion.sims."):
        return []
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names = [node.module or ""]
        else:
            continue
        found += [f"{module}:{node.lineno} imports {n}" for n in names if n.split(".")[0] in SIMULATOR_MODULES]
    return found


def test_only_the_simulator_backends_import_a_simulator():
    found = [v for module, source, _ in _sources() for v in simulator_imports(module, source)]
    assert not found, "\n".join(found)


def test_the_simulator_check_sees_an_import_inside_a_function():
    source = "import math\n\ndef f():\n    from mujoco import MjModel\n    import pybullet as p\n    return p\n"
    assert simulator_imports("rmpfusion.envs.manipulator.torque", source) == [
        "rmpfusion.envs.manipulator.torque:4 imports mujoco",
        "rmpfusion.envs.manipulator.torque:5 imports pybullet",
    ]
    assert simulator_imports("rmpfusion.sims.pybullet_backend", source) == []


def _import_targets(module: str, is_package: bool, node: ast.Import | ast.ImportFrom, known: set[str]) -> set[str]:
    """The modules of the package an import statement names: a name imported from a package that is itself a module
    of it (``from . import sets``, ``from .maps import kinematics``) is that module, anything else its package."""
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        base = _target(module, is_package, node)
        names = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
    out = set()
    for name in names:
        while name and name not in known:  # ``import rmpfusion.maps.kinematics.Chain`` style: the longest module
            name = name.rpartition(".")[0]
        if name:
            out.add(name)
    return out


def import_graph(sources) -> dict[str, set[str]]:
    """Module -> the package's modules it imports, from the source: every import statement, those under ``if
    TYPE_CHECKING:`` and inside functions included (an import only a type checker runs still ties the modules)."""
    sources = list(sources)
    known = {module for module, _, _ in sources}
    graph: dict[str, set[str]] = {module: set() for module in known}
    for module, source, is_package in sources:
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.Import | ast.ImportFrom):
                graph[module] |= _import_targets(module, is_package, node, known) - {module}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected group of modules (Tarjan's algorithm), each as the path ``a -> b -> ... ->
    a`` found by walking the group from its first module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return [_cycle_in(group, graph) for group in sorted(groups)]


def _cycle_in(group: list[str], graph: dict[str, set[str]]) -> list[str]:
    """A path from the group's first module back to it, inside the group (breadth first: the shortest)."""
    members, start = set(group), group[0]
    came_from: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & members):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(came_from[path[-1]])
                    return [*reversed(path), start]
                if w not in came_from:
                    came_from[w] = v
                    nxt.append(w)
        frontier = nxt
    raise AssertionError(f"no cycle through {start} in {group}")


def test_no_module_imports_itself_through_others():
    """No import circle, not even one a type checker alone walks (``if TYPE_CHECKING:``): a type two modules share
    lives in the lower one, or in a small module both import."""
    cycles = import_cycles(import_graph(_sources()))
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_the_cycle_check_names_a_circle_made_only_for_type_checking():
    sources = [
        ("rmpfusion.envs.arm", "from .rollout import record\n", False),
        (
            "rmpfusion.envs.rollout",
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .arm import Arm\n",
            False,
        ),
        ("rmpfusion.envs.plain", "from . import rollout\n", False),
        ("rmpfusion.envs", "from .plain import x\n", True),
    ]
    assert import_cycles(import_graph(sources)) == [
        ["rmpfusion.envs.arm", "rmpfusion.envs.rollout", "rmpfusion.envs.arm"]
    ]

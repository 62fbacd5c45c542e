"""The package's layering: the library never imports the study, no floor imports a floor above it, and
there is no import cycle (read from the source with ``ast``, so lazy imports inside functions count)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "softpend"

#: Floors from the bottom; a module may import its own unit and units of lower floors only.
FLOORS = [
    ["softpend", "softpend.checks"],
    ["softpend.stats"],
    ["softpend.io"],
    ["softpend.plant"],
    ["softpend.task"],
    ["softpend.sysid", "softpend.fidelity", "softpend.plotting"],
    ["softpend.envs", "softpend.vision"],
    ["softpend.evaluation", "softpend.hardware"],
    ["softpend.control", "softpend.rl", "softpend.pilco"],
    ["softpend.study"],
    ["softpend.commands", "softpend.cli"],
]


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in PACKAGE.rglob("*.py")}


def import_graph() -> dict[str, set[str]]:
    """Module -> the package modules it imports (``from a import b`` counts ``a`` and, if a module, ``a.b``)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")
                    parts = parts[: len(parts) - (node.level - 1)]
                    base = ".".join(parts + ([base] if base else []))
                targets = [base] + [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            deps.update(t for t in targets if t in modules and t != name)
        graph[name] = deps
    return graph


def unit_of(module: str) -> tuple[int, str]:
    """``(floor, unit)`` of a module: the longest unit of :data:`FLOORS` that contains it."""
    best: tuple[int, str] | None = None
    for floor, units in enumerate(FLOORS):
        for unit in units:
            if (module == unit or module.startswith(unit + ".")) and (best is None or len(unit) > len(best[1])):
                best = (floor, unit)
    if best is None:
        raise AssertionError(f"{module} belongs to no floor of tests/test_layers.py: place it")
    return best


def test_every_module_has_a_floor() -> None:
    for module in _modules():
        unit_of(module)


def floor_violations(graph: dict[str, set[str]]) -> list[str]:
    """Every import of a unit on the same floor or above, as a readable line."""
    wrong = []
    for module, deps in graph.items():
        floor, unit = unit_of(module)
        for dep in deps:
            dep_floor, dep_unit = unit_of(dep)
            if dep_unit != unit and dep_floor >= floor:
                wrong.append(f"{module} (floor {floor}) imports {dep} (floor {dep_floor})")
    return sorted(wrong)


def test_no_module_imports_a_floor_at_or_above_its_own() -> None:
    wrong = floor_violations(import_graph())
    assert not wrong, "\n".join(wrong)


def test_the_library_never_imports_the_study() -> None:
    graph = import_graph()
    library = [m for m in _modules() if unit_of(m)[0] < unit_of("softpend.study")[0]]
    assert library, "no library module found"
    wrong = [
        (m, d) for m in library for d in graph[m] if d.startswith("softpend.study") or d.startswith("softpend.commands")
    ]
    assert not wrong


def test_no_import_cycle() -> None:
    graph = import_graph()
    # a package's __init__ importing its own submodules is how packages re-export; a cycle through it counts
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for dep in sorted(graph[node]):
            if _is_parent_package(dep, node):
                continue  # importing a submodule runs its parent package first: not an edge of the design
            if state.get(dep) == 1:
                cycle = stack[stack.index(dep) :] + [dep]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if dep not in state:
                visit(dep)
        stack.pop()
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module)


def _is_parent_package(candidate: str, module: str) -> bool:
    return module.startswith(candidate + ".")


def test_the_checker_sees_violations() -> None:
    """The floor check flags a library module importing the study and a sibling import on one floor, and
    passes a downward import (guards against a vacuous test)."""
    graph = {
        "softpend.plant.prb": {"softpend.study.book"},
        "softpend.hardware.twin": {"softpend.evaluation", "softpend.plant.prb"},
        "softpend.rl.dqn": {"softpend.envs.soft_pendulum"},
    }
    wrong = floor_violations(graph)
    assert len(wrong) == 2
    assert any("softpend.plant.prb" in w and "softpend.study.book" in w for w in wrong)
    assert any("softpend.hardware.twin" in w and "softpend.evaluation" in w for w in wrong)

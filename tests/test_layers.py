"""The package's layers, read from the source: every ``trainclimate.X`` import of every module under
``backend/trainclimate`` (at the top of a module or inside a function, ``if TYPE_CHECKING`` too)
runs down the layer order of docs/architecture.md, the coach's vocabulary imports only itself,
the simulator only itself and that vocabulary, and no module imports itself back through others.

The layers, bottom to top: ``coach`` ← ``sim`` ← ``data`` ← ``twin`` ← ``predict`` ← ``control``
← ``analysis`` ← ``service`` / ``study`` ← ``bench`` ← ``cli``. ``coach`` is the coach as the
layers above see it (the rule-based controller and the HVAC modes, the setpoint band, the HVAC
states, the meters), the simulator the first layer that speaks it. The twin (a simulator
calibrated to a coach's trajectories) imports ``coach``, ``sim`` and ``data``; the service,
``bench`` and ``cli`` import it.
``paths``, ``resources`` and the package's own ``__init__`` (its version) are below every layer
but ``coach`` and ``sim``, and import none of them.
"""

from __future__ import annotations

import ast
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "backend" / "trainclimate"
#: The layers, bottom to top; the packages of one layer do not import each other.
LAYERS = (
    ("coach",),
    ("sim",),
    ("data",),
    ("twin",),
    ("predict",),
    ("control",),
    ("analysis",),
    ("service", "study"),
    ("bench",),
    ("cli",),
)
#: Modules any layer but ``coach`` and ``sim`` may import; they import no layer. ``trainclimate``
#: is the package's ``__init__``.
BASE = ("trainclimate", "paths", "resources")
#: Imports known to run up the layers, (importing package, imported package) → the modules: each
#: entry is a debt to pay, and the test fails once it is paid until the entry is removed.
KNOWN_UPWARD: dict[tuple[str, str], set[str]] = {}

RANK = {package: rank for rank, layer in enumerate(LAYERS) for package in layer}


def _modules() -> dict[str, Path]:
    """Every module of the package by dotted name (``os.walk``: the symbolic links under
    ``resources`` to the migrations and the dashboard are not followed)."""
    modules = {}
    for directory, _, files in os.walk(ROOT):
        for name in files:
            if name.endswith(".py"):
                parts = (Path(directory) / name).relative_to(ROOT.parent).with_suffix("").parts
                modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = Path(
                    directory, name
                )
    return modules


MODULES = _modules()


def _imports(path: Path) -> set[str]:
    """The ``trainclimate`` modules ``path`` imports, wherever in it (a name imported from a
    package counts as its module when it is one, else as the package)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}: a relative import"
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                found.add(full if full in MODULES else str(node.module))
    return {name for name in found if name == "trainclimate" or name.startswith("trainclimate.")}


IMPORTS = {module: _imports(path) for module, path in MODULES.items()}


def package_of(module: str) -> str:
    """The layer (or base module) ``module`` belongs to: ``trainclimate.sim.params`` → ``sim``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def _package_imports() -> dict[tuple[str, str], set[str]]:
    """(importing package, imported package) → the importing modules, between packages only."""
    edges: dict[tuple[str, str], set[str]] = {}
    for module, imported in IMPORTS.items():
        for name in imported:
            pair = (package_of(module), package_of(name))
            if pair[0] != pair[1]:
                edges.setdefault(pair, set()).add(module)
    return edges


EDGES = _package_imports()


def test_every_package_has_a_layer():
    packages = {package_of(m) for m in MODULES}
    assert packages - set(BASE) == set(RANK)


#: What each self-contained package may import besides itself: the coach's vocabulary nothing of
#: the package, the simulator only that vocabulary (not even ``paths``).
SELF_CONTAINED = {"coach": set(), "sim": {"coach"}}


@pytest.mark.parametrize("package", sorted(SELF_CONTAINED))
def test_the_vocabulary_and_the_simulator_are_self_contained(package):
    allowed = {package} | SELF_CONTAINED[package]
    outside = {
        module: sorted(name for name in imported if package_of(name) not in allowed)
        for module, imported in IMPORTS.items()
        if package_of(module) == package
    }
    assert {m: names for m, names in outside.items() if names} == {}


def test_the_base_modules_import_no_layer():
    assert {pair: modules for pair, modules in EDGES.items() if pair[0] in BASE} == {}


def test_every_import_runs_down_the_layers():
    upward = {
        pair: modules
        for pair, modules in EDGES.items()
        if pair[0] in RANK and pair[1] in RANK and RANK[pair[1]] >= RANK[pair[0]]
    }
    assert upward == KNOWN_UPWARD


@pytest.mark.parametrize("package", ["predict", "control"])
def test_the_predictor_and_the_controller_need_no_twin(package):
    """They work on any coach's parameters, calibrated or not."""
    assert (package, "twin") not in EDGES


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of ``graph`` (node → the nodes it imports), as its nodes in order, or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt) :], nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_no_cycle_between_packages_but_the_known_upward_imports():
    graph: dict[str, set[str]] = {}
    for importer, imported in set(EDGES) - set(KNOWN_UPWARD):
        graph.setdefault(importer, set()).add(imported)
    assert _cycle(graph) is None


def test_no_module_imports_itself_back():
    """Not even inside a function: sim.params reads its plausible ranges from sim.plausible,
    which imports nothing of the package."""
    graph = {m: {n for n in imported if n in MODULES and n != m} for m, imported in IMPORTS.items()}
    assert _cycle(graph) is None


def test_the_cycle_finder_finds_one():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None

"""The service's dependency direction, read off its imports: the store imports nothing from the
API, the scheduler, the policy or the adapters; the API nothing from the scheduler or the
adapters; the scheduler nothing from the API or the adapters; and the policy, at run time, nothing
that reaches a database."""

from __future__ import annotations

import ast
from pathlib import Path

import trainclimate.service

SERVICE = Path(trainclimate.service.__file__).parent


def imports(path: Path, *, runtime_only: bool = False) -> set[str]:
    """The modules ``path`` imports (with ``runtime_only``, not those under ``TYPE_CHECKING``)."""
    tree = ast.parse(path.read_text())
    skipped: set[int] = set()
    if runtime_only:
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING":
                skipped |= {id(n) for n in ast.walk(node)}
    out = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.ImportFrom) and node.module:
            out |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return out


def reaching(modules: set[str], *parts: str) -> set[str]:
    """Those of ``modules`` inside ``trainclimate.service.<part>`` for any of ``parts``."""
    prefixes = tuple(f"trainclimate.service.{p}" for p in parts)
    return {m for m in modules if m.startswith(prefixes)}


def package(name: str) -> list[Path]:
    """The modules of ``trainclimate.service.<name>``, its subpackages' included."""
    return sorted((SERVICE / name).rglob("*.py"))


def test_the_store_imports_nothing_that_builds_on_it():
    for path in package("store"):
        assert not reaching(imports(path), "api", "scheduler", "policy", "adapters", "app"), path


def test_the_api_does_not_reach_the_scheduler_or_the_adapters():
    for path in package("api"):
        assert not reaching(imports(path), "scheduler", "policy", "adapters"), path


def test_the_scheduler_does_not_reach_the_api_or_the_adapters():
    assert not reaching(imports(SERVICE / "scheduler.py"), "api", "adapters", "app")


def test_the_policy_touches_no_database():
    modules = imports(SERVICE / "policy.py", runtime_only=True)
    assert not reaching(modules, "store", "scheduler", "api", "adapters", "app")
    assert not {m for m in modules if m.startswith("sqlalchemy")}

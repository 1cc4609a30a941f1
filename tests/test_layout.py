"""The layout is the pipeline (issue 54): eskin's packages and root modules import one
another in one direction only, so that each can be read, tested and changed from the
bottom up. Imports inside functions count: they are deferred, not absent."""

from __future__ import annotations

import ast
from collections import defaultdict
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

ESKIN = Path(__file__).resolve().parent.parent / "eskin"


def unit_of(module: str) -> str | None:
    """The package or root module of eskin that ``module`` (dotted) lies in."""
    parts = module.split(".")
    return parts[1] if parts[0] == "eskin" and len(parts) > 1 else None


def import_graph() -> dict[str, dict[str, set[str]]]:
    """unit → the units it imports → the files that import them."""
    graph: dict[str, dict[str, set[str]]] = defaultdict(lambda: defaultdict(set))
    units = {path.stem for path in ESKIN.glob("*.py")} | {
        path.parent.name for path in ESKIN.glob("*/__init__.py")}
    for path in ESKIN.rglob("*.py"):
        relative = path.relative_to(ESKIN.parent).with_suffix("")
        unit = relative.parts[1]
        graph[unit]  # every unit is a node, importing or not
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
                if node.module == "eskin":  # from eskin import cli: the unit is the name
                    names = [f"eskin.{alias.name}" for alias in node.names]
            elif isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            else:
                continue
            for name in names:
                other = unit_of(name)
                if other in units and other != unit:  # not eskin.__version__
                    graph[unit][other].add(str(relative))
    return graph


def test_the_graph_is_read_from_the_code():
    graph = import_graph()
    assert {"data", "learning", "evaluation", "catalog", "kinds"} <= set(graph)
    assert "eskin/learning/train" in graph["learning"]["evaluation"]  # it cross-validates


def test_no_two_parts_of_eskin_import_each_other_nor_go_round_in_a_cycle():
    graph = import_graph()
    mutual = sorted(f"{a} ↔ {b} ({', '.join(sorted(graph[a][b]))}; "
                    f"{', '.join(sorted(graph[b][a]))})"
                    for a in graph for b in graph[a] if a < b and a in graph[b])
    assert not mutual, "packages that import each other: " + "; ".join(mutual)
    try:
        order = list(TopologicalSorter({unit: set(imports) for unit, imports in graph.items()})
                     .static_order())
    except CycleError as error:
        raise AssertionError(f"an import cycle: {' → '.join(error.args[1])}") from None
    assert set(order) == set(graph)


def test_the_cycle_check_finds_a_cycle():
    """The check itself, on a graph with a three-part cycle."""
    cyclic = {"a": {"b"}, "b": {"c"}, "c": {"a"}}
    try:
        list(TopologicalSorter(cyclic).static_order())
    except CycleError:
        return
    raise AssertionError("graphlib found no cycle in a → b → c → a")

"""The package's layout follows the data's path and has no import cycles (issue 21, item 2).

The import graph is read from the sources (every ``import capsmech...`` and ``from capsmech...
import``, at module level or inside a function: a cycle through a deferred import is still a
cycle of concepts). Checked: no strongly connected component of more than one module, and
the layers of the data's path only import downwards: ``cli`` -> ``api`` -> ``diagnosis`` ->
``inversion`` -> ``io``; ``imaging`` and ``workflow`` beside them; nothing below ``cli``
imports it.
"""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "analysis" / "src" / "capsmech"


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module, *(f"{node.module}.{alias.name}" for alias in node.names)]
            else:
                continue
            graph[name].update(t for t in targets if t in modules and t != name)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_graph_is_read():
    graph = import_graph()
    assert "capsmech.diagnosis.sequential" in graph
    assert "capsmech.diagnosis.diagnose" in graph["capsmech.diagnosis.sequential"]


def test_no_import_cycles():
    assert cycles(import_graph()) == []


#: Layers of the data's path, lowest first; a module may import its own layer and those below.
LAYERS = [("capsmech.errors", "capsmech.version", "capsmech.formatting"), ("capsmech.io",),
          ("capsmech.imaging", "capsmech.workflow"), ("capsmech.inversion",), ("capsmech.diagnosis",),
          ("capsmech.api", "capsmech.plotting"), ("capsmech.cli",)]


def layer(module: str) -> int | None:
    for k, prefixes in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return k
    return None


def test_imports_follow_the_data_path_downwards():
    upward = [(source, target) for source, targets in import_graph().items() for target in targets
              if layer(source) is not None and layer(target) is not None and layer(target) > layer(source)]
    assert upward == []

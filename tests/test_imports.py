"""The package's import graph has no cycle, and every module imports.

The graph is read statically (``ast``) from every ``import`` statement in
``src/photax`` -- module level *and* inside functions: a deferred import
that only exists to break a cycle is still a cycle in the design.  Edges go
from a module to the photax modules it names; a package's ``__init__`` is
its own node (``photax.io``), and importing ``photax.io.gcp`` from outside
``photax.io`` also imports ``photax.io`` (Python runs the package's
``__init__`` first), so that edge counts too.
"""

from __future__ import annotations

import ast
import importlib
import pathlib

import pytest

import photax

SRC = pathlib.Path(photax.__file__).resolve().parent


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _graph() -> dict[str, set[str]]:
    """``{module: {photax modules it imports}}`` for every ``.py`` under ``src/photax``."""
    files = {_module_name(p): p for p in SRC.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        is_pkg = path.name == "__init__.py"
        package = name if is_pkg else name.rpartition(".")[0]
        edges: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[: len(base) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                # "from pkg import sub" names the submodule when there is one.
                subs = [f"{mod}.{a.name}" for a in node.names if f"{mod}.{a.name}" in files]
                targets = subs if subs and len(subs) == len(node.names) else [mod, *subs]
            else:
                continue
            for t in targets:
                # Python imports every enclosing package first, unless we are inside it.
                parts = t.split(".")
                for k in range(2, len(parts) + 1):
                    anc = ".".join(parts[:k])
                    if anc in files and anc != name and not (name + ".").startswith(anc + "."):
                        edges.add(anc)
        graph[name] = edges
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as ``[a, b, ..., a]``, or None (depth-first search)."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n) :] + [n]
            if n not in state and (found := visit(n)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_cycle_finder_finds_a_planted_cycle():
    # The checker itself must be able to fail.
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_graph_sees_known_edges():
    g = _graph()
    assert "photax.collinearity" in g["photax.bundle._problem"]
    assert "photax.camera" in g["photax.intersection"]
    assert {"photax.io", "photax.io.results"} <= g["photax.demo"]  # the package's __init__ runs first
    assert "photax.io" not in g["photax.io.gcp"]  # ... but not for its own modules
    assert len(g) > 30


def test_no_import_cycle():
    cycle = _cycle(_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


@pytest.mark.parametrize("name", sorted(_module_name(p) for p in SRC.rglob("*.py")))
def test_every_module_imports(name):
    assert importlib.import_module(name).__name__ == name

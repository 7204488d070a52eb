"""No import cycle among the ``frng`` modules (issue 26): the graph is built from the sources with ``ast``.

What counts as an edge A -> B: EVERY ``import`` / ``from ... import`` statement in module A that names a frng module
B, wherever it stands -- at module level, under ``if TYPE_CHECKING:``, or inside a function. A ``TYPE_CHECKING``
import is a dependency of the design (the 22-module cycle through ``frng/plan/config.py`` hid behind one), and a
function-local import that merely defers a cycle to run time is still a cycle, so neither is a way out: a cycle is
broken by moving the shared piece to a module both can import (a leaf such as ``frng.plan.sections``, which imports no
component). ``from pkg import name`` is an edge to ``pkg.name`` when that is a module, else to ``pkg``; importing
``a.b.c`` also runs ``a/__init__`` and ``a/b/__init__``, so those count as edges too (but a module's own parent
packages, which are initialised before it runs). ``importlib.import_module``
with a literal ``frng...`` name counts as an import; the CLI's table of stage modules (``frng/cli.py``), strings in
a dict, does not (nothing imports the CLI).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _modules() -> dict[str, Path]:
    out = {}
    for p in sorted((ROOT / "frng").rglob("*.py")):
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _imported(module: str, path: Path, node: ast.AST, modules: dict[str, Path]) -> list[str]:
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if isinstance(node, ast.ImportFrom):
        base = node.module or ""
        if node.level:
            parts = package.split(".")
            parts = parts[: len(parts) - (node.level - 1)]
            base = ".".join(parts + ([node.module] if node.module else []))
        return [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "import_module"
        and node.args
        and isinstance(node.args[0], ast.Constant)
        and isinstance(node.args[0].value, str)
    ):
        return [node.args[0].value]
    return []


def import_graph() -> dict[str, set[str]]:
    """frng module -> the frng modules it imports (every import statement anywhere in it; see the docstring)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            for name in _imported(module, path, node, modules):
                if name != "frng" and not name.startswith("frng."):
                    continue
                parts = name.split(".")
                for i in range(1, len(parts) + 1):  # a.b.c runs a, a.b, a.b.c
                    prefix = ".".join(parts[:i])
                    if prefix in modules and prefix != module and not module.startswith(prefix + "."):
                        deps.add(prefix)
        graph[module] = deps
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as [m0, m1, ..., m0], or None (depth-first search, sorted for a stable answer)."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(v: str) -> list[str] | None:
        state[v] = 1
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if state.get(w) == 1:
                return stack[stack.index(w) :] + [w]
            if w not in state:
                found = visit(w)
                if found:
                    return found
        stack.pop()
        state[v] = 2
        return None

    for v in sorted(graph):
        if v not in state:
            found = visit(v)
            if found:
                return found
    return None


def test_no_import_cycle_among_frng_modules():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_sections_is_a_leaf_and_only_stages_assemble_the_config():
    """frng.plan.sections imports no frng module; frng.typedconfig (which imports every component declaring a section) is
    imported by the stage layer only -- libraries get the typed config, or their section, handed to them."""
    graph = import_graph()
    assert graph["frng.plan.sections"] == set()
    importers = sorted(m for m, deps in graph.items() if "frng.typedconfig" in deps)
    outside = [m for m in importers if not m.startswith("frng.stages")]
    assert not outside, f"libraries importing frng.typedconfig: {outside}"

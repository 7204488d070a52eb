"""The package's floor plan, checked on its import graph (built from the sources with ``ast``): no import cycle among
the ``frng`` modules (issue 26), none between its packages either (no arrow back up), stages import no stage, only the
command layer (stages, commands, diagnostics) and the typed config import a trainer, the models do not plan (issue 58).

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


# The command layer: what a subcommand runs -- the pipeline's stages (one per rule), the commands a user runs by hand,
# the benchmarks and diagnostics (``frng bench``). Each is arguments and orchestration around the libraries.
COMMAND_LAYER = ("frng.stages", "frng.commands", "frng.diagnostics")


def test_sections_is_a_leaf_and_only_stages_assemble_the_config():
    """frng.plan.sections imports no frng module; frng.typedconfig (which imports every component declaring a section) is
    imported by the command layer only -- libraries get the typed config, or their section, handed to them."""
    graph = import_graph()
    assert graph["frng.plan.sections"] == set()
    importers = sorted(m for m, deps in graph.items() if "frng.typedconfig" in deps)
    outside = [m for m in importers if not m.startswith(COMMAND_LAYER)]
    assert not outside, f"libraries importing frng.typedconfig: {outside}"


def _unit(module: str) -> str:
    """The floor-plan unit of a module: its top-level subpackage (``frng.render``), or the root module itself."""
    return ".".join(module.split(".")[:2])


def test_no_arrow_runs_back_up_between_packages():
    """Collapsed to the package's units (subpackages and root modules), the graph still has no cycle: a package
    that imports another is never imported back by it (the arrows run one way, top to bottom)."""
    units: dict[str, set[str]] = {}
    for a, deps in import_graph().items():
        units.setdefault(_unit(a), set()).update(_unit(b) for b in deps if _unit(b) != _unit(a))
    cycle = find_cycle(units)
    assert cycle is None, "packages import each other: " + " -> ".join(cycle)


def test_stages_import_no_stage():
    """A stage (or a command, or a benchmark) is arguments and orchestration around the libraries; what two of them
    share lives in a library or in a private helper of their package (``frng.stages._name``, not a stage: no rule
    runs it). None imports another stage, command or benchmark."""
    layer = tuple(f"{p}." for p in COMMAND_LAYER)
    bad = [
        f"{a} -> {b}"
        for a, deps in import_graph().items()
        if a.startswith(layer)
        for b in deps
        if b.startswith(layer) and not b.rpartition(".")[2].startswith("_")
    ]
    assert not bad, bad


def test_models_and_applications_import_no_trainer():
    """Only the command layer, the typed config (which assembles every section) and the trainers themselves import a
    trainer (``frng.training``): a model file loads and relights without the training code."""
    allowed = (*COMMAND_LAYER, "frng.training", "frng.typedconfig")
    bad = [
        f"{a} -> {b}"
        for a, deps in import_graph().items()
        if not a.startswith(allowed)
        for b in deps
        if b == "frng.training" or b.startswith("frng.training.")
    ]
    assert not bad, bad


def test_models_do_not_plan():
    """The models (``frng.model``) know their architecture records, not the pipeline's variants or results layout."""
    graph = import_graph()
    bad = [
        f"{a} -> {b}"
        for a, deps in graph.items()
        if a == "frng.model" or a.startswith("frng.model.")
        for b in deps & {"frng.plan.variants", "frng.plan.layout"}
    ]
    assert not bad, bad


def test_the_floor_plan_rules_catch_a_violation():
    assert find_cycle({"frng.a": {"frng.b"}, "frng.b": {"frng.a"}}) == ["frng.a", "frng.b", "frng.a"]
    assert _unit("frng.render.envmap") == "frng.render" and _unit("frng.metrics") == "frng.metrics"

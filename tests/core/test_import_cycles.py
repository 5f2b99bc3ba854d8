"""No import cycles among the project's modules (issue 21): none at module level, and none through
the imports made inside functions either."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("api", "workers", "shared")

#: Cycles through imports inside functions that are known and not fixed yet (none left: the
#: registry hands a sampler its record when it builds it). A change may shrink this list, never
#: add to it.
KNOWN_LAZY_CYCLES: list[set[str]] = []


def _modules() -> dict[str, Path]:
    modules = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def _imported(name: str, path: Path, node: ast.AST, modules: dict[str, Path]) -> list[str]:
    """The project modules an import statement loads (``from pkg import sub``: the submodule)."""
    if isinstance(node, ast.Import):
        targets = [alias.name for alias in node.names]
    elif isinstance(node, ast.ImportFrom):
        module = node.module or ""
        if node.level:
            here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
            module = ".".join(here[: len(here) - node.level + 1] + ([module] if module else []))
        targets = [
            f"{module}.{alias.name}" if f"{module}.{alias.name}" in modules else module
            for alias in node.names
        ]
    else:
        return []
    found = []
    for target in targets:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        if target and target != name:
            found.append(target)
    return found


def _run_at_import(tree: ast.Module) -> list[ast.AST]:
    """The statements run when the module is imported: not function bodies, not the
    ``if TYPE_CHECKING:`` blocks."""
    found: list[ast.AST] = []
    pending: list[ast.AST] = list(tree.body)
    while pending:
        node = pending.pop()
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            continue
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            pending.extend(node.orelse)
            continue
        found.append(node)
        pending.extend(ast.iter_child_nodes(node))
    return found


def import_graph(module_level_only: bool) -> dict[str, set[str]]:
    """Module -> the project modules it imports (at module level only, or anywhere)."""
    modules = _modules()
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        nodes = _run_at_import(tree) if module_level_only else ast.walk(tree)
        for node in nodes:
            graph[name].update(_imported(name, path, node, modules))
    return graph


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[set[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in graph[node]:
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = set()
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.add(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(component)

    for node in graph:
        if node not in index:
            visit(node)
    return found


def test_no_import_cycle_at_module_level():
    assert cycles(import_graph(module_level_only=True)) == []


def test_no_new_import_cycle_through_function_level_imports():
    for cycle in cycles(import_graph(module_level_only=False)):
        assert any(cycle <= known for known in KNOWN_LAZY_CYCLES), sorted(cycle)


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]


def test_no_route_module_imports_another():
    """Routes share through ``api.responses`` (issue 30): a route imports no other route."""
    graph = import_graph(module_level_only=False)
    routes = {name for name in graph if name.startswith("api.routes.")}
    assert routes, "no route modules found"
    assert {name: graph[name] & routes for name in routes if graph[name] & routes} == {}


#: The modules that may import the solver registry (issue 30): one door per floor (the API's
#: dependencies, the workers' queues, the command line, the bench runner), the level's inference
#: table and the meter table. Everything else is handed the ``ResolvedSolver`` (the package
#: ``shared.solvers`` re-exports none of the registry's names). A change may shrink this set;
#: growing it needs a reason.
REGISTRY_IMPORTERS = {
    "api.deps",
    "shared.bench.runner",
    "shared.cli",
    "shared.inference.table",
    "shared.solvers.meters",
    "workers.queues",
}
#: The registry's own names, which ``shared.solvers`` re-exports.
REGISTRY_NAMES = {"get_solver", "spec", "solver_names", "register", "resolve", "check_params",
                  "params_schema", "registry"}  # fmt: skip


def test_only_the_doors_import_the_solver_registry():
    found = set()
    for name, path in _modules().items():
        if name == "shared.solvers.registry":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                names = {alias.name for alias in node.names}
                if node.module == "shared.solvers.registry" or (
                    node.module == "shared.solvers" and names & REGISTRY_NAMES
                ):
                    found.add(name)
            elif isinstance(node, ast.Import) and "shared.solvers.registry" in {
                alias.name for alias in node.names
            }:
                found.add(name)
    assert found <= REGISTRY_IMPORTERS, sorted(found - REGISTRY_IMPORTERS)

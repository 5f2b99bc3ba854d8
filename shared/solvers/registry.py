"""The one registry of solver adapters. The CLI, the API's validation and the worker queues all
read it. Adapters are built lazily, so importing the registry does not import Ocean or Gurobi."""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module

from shared.solvers.base import Solver

#: name -> "module:attribute" of a zero-argument factory (usually the adapter class).
_FACTORIES: dict[str, str] = {
    "exact": "shared.solvers.exact:ExactSolver",
    "sa": "shared.solvers.anneal:SimulatedAnnealingSolver",
    "tabu": "shared.solvers.anneal:TabuSolver",
    "steepest-descent": "shared.solvers.anneal:SteepestDescentSolver",
    "gurobi": "shared.solvers.gurobi:GurobiSolver",
    "qpu": "shared.solvers.dwave:QPUSolver",
    "qpu-sim": "shared.solvers.dwave:SimulatedQPUSolver",
    "hybrid": "shared.solvers.hybrid:LeapHybridSolver",
    "hybrid-sim": "shared.solvers.hybrid:KerberosSolver",
}
_INSTANCES: dict[str, Solver] = {}


class UnknownSolver(KeyError):
    def __str__(self) -> str:
        return f"unknown solver {self.args[0]!r}; known solvers: {', '.join(solver_names())}"


def register(name: str, factory: str | Callable[[], Solver]) -> None:
    """Add an adapter (tests register failing or slow fakes this way)."""
    if callable(factory):
        _INSTANCES[name] = factory()
    _FACTORIES[name] = factory if isinstance(factory, str) else f"<instance>:{name}"


def solver_names() -> list[str]:
    return list(_FACTORIES)


def get_solver(name: str) -> Solver:
    """The adapter registered under ``name``; ``UnknownSolver`` lists the valid names."""
    if name in _INSTANCES:
        return _INSTANCES[name]
    if name not in _FACTORIES:
        raise UnknownSolver(name)
    module_name, attribute = _FACTORIES[name].split(":")
    solver = getattr(import_module(module_name), attribute)()
    _INSTANCES[name] = solver
    return solver

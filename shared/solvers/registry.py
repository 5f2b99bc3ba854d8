"""The one registry of solver adapters. The CLI, the API's validation and the worker queues all
read it. Adapters are built lazily, so importing the registry does not import Ocean or Gurobi."""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module
from typing import Any

from shared.solvers import params as schemas
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
#: name -> the schema of its ``solver_params`` (bounds checked at submit).
_PARAMS: dict[str, type[schemas.SolverParams]] = {
    "exact": schemas.NoParams,
    "sa": schemas.AnnealParams,
    "tabu": schemas.TabuParams,
    "steepest-descent": schemas.DescentParams,
    "gurobi": schemas.GurobiParams,
    "qpu": schemas.QPUParams,
    "qpu-sim": schemas.QPUParams,
    "hybrid": schemas.LeapHybridParams,
    "hybrid-sim": schemas.KerberosParams,
}
#: Solvers that sample the QUBO heuristically: domain-wall rows are far easier for them
#: (README, "Solvers"; docs/benchmarks.md). The exact ones have no preference.
_DOMAIN_WALL_SOLVERS = frozenset(
    {"sa", "tabu", "steepest-descent", "qpu", "qpu-sim", "hybrid", "hybrid-sim"}
)
_INSTANCES: dict[str, Solver] = {}


class UnknownSolver(KeyError):
    def __str__(self) -> str:
        return f"unknown solver {self.args[0]!r}; known solvers: {', '.join(solver_names())}"


def register(
    name: str,
    factory: str | Callable[[], Solver],
    params: type[schemas.SolverParams] = schemas.NoParams,
) -> None:
    """Add an adapter with the schema of its parameters (tests register fakes this way)."""
    if callable(factory):
        _INSTANCES[name] = factory()
    _FACTORIES[name] = factory if isinstance(factory, str) else f"<instance>:{name}"
    _PARAMS[name] = params


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


def params_schema(name: str) -> type[schemas.SolverParams]:
    """The pydantic model bounding ``name``'s ``solver_params``."""
    if name not in _FACTORIES:
        raise UnknownSolver(name)
    return _PARAMS.get(name, schemas.NoParams)


def check_params(name: str, params: dict[str, Any]) -> dict[str, Any]:
    """``params`` checked against the solver's schema (``InvalidSolverParams`` says why not)."""
    return schemas.check(params_schema(name), name, params)


def recommended_encoding(name: str) -> str | None:
    """The label encoding to use with ``name`` when none is asked for (``qhsm bench``); None:
    no preference (the preset decides)."""
    return "domain-wall" if name in _DOMAIN_WALL_SOLVERS else None

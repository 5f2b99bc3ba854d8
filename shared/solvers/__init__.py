"""QUBO solvers as dimod samplers behind one registry (see :mod:`shared.solvers.registry`)."""

from shared.solvers.base import (
    Availability,
    Sampler,
    SolverError,
    SolveResult,
    SolverUnavailableError,
    TransientSolverError,
    solve,
)
from shared.solvers.params import InvalidSolverParamsError
from shared.solvers.registry import (
    SolverSpec,
    UnknownSolverError,
    check_params,
    get_solver,
    params_schema,
    register,
    solver_names,
    spec,
)

#: The type of a registered solver (a ``dimod.Sampler`` with availability and a name).
Solver = Sampler

__all__ = [
    "Availability",
    "InvalidSolverParamsError",
    "Sampler",
    "SolveResult",
    "Solver",
    "SolverError",
    "SolverSpec",
    "SolverUnavailableError",
    "TransientSolverError",
    "UnknownSolverError",
    "check_params",
    "get_solver",
    "params_schema",
    "register",
    "solve",
    "solver_names",
    "spec",
]

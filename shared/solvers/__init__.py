"""Solver adapters behind one registry (see :mod:`shared.solvers.registry`)."""

from shared.solvers.base import (
    Availability,
    Solver,
    SolverError,
    SolveResult,
    SolverUnavailable,
    TransientSolverError,
)
from shared.solvers.params import InvalidSolverParams
from shared.solvers.registry import (
    UnknownSolver,
    check_params,
    get_solver,
    params_schema,
    register,
    solver_names,
)

__all__ = [
    "Availability",
    "InvalidSolverParams",
    "SolveResult",
    "Solver",
    "SolverError",
    "SolverUnavailable",
    "TransientSolverError",
    "UnknownSolver",
    "check_params",
    "get_solver",
    "params_schema",
    "register",
    "solver_names",
]

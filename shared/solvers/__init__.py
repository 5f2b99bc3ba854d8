"""Solver adapters behind one registry (see :mod:`shared.solvers.registry`)."""

from shared.solvers.base import (
    Availability,
    Solver,
    SolverError,
    SolveResult,
    SolverUnavailable,
    TransientSolverError,
)
from shared.solvers.registry import UnknownSolver, get_solver, register, solver_names

__all__ = [
    "Availability",
    "SolveResult",
    "Solver",
    "SolverError",
    "SolverUnavailable",
    "TransientSolverError",
    "UnknownSolver",
    "get_solver",
    "register",
    "solver_names",
]

"""QUBO solvers as dimod samplers behind one registry (see :mod:`shared.solvers.registry`)."""

from shared.solvers.base import (
    Availability,
    Sampler,
    SolverError,
    SolveResult,
    SolverUnavailable,
    TransientSolverError,
    solve,
)
from shared.solvers.params import InvalidSolverParamsError
from shared.solvers.registry import (
    SolverSpec,
    UnknownSolver,
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
    "SolverUnavailable",
    "TransientSolverError",
    "UnknownSolver",
    "check_params",
    "get_solver",
    "params_schema",
    "register",
    "solve",
    "solver_names",
    "spec",
]

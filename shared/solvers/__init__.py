"""QUBO solvers as dimod samplers behind one registry (see :mod:`shared.solvers.registry`)."""

from typing import TYPE_CHECKING, Any

from shared.solvers.base import (
    Availability,
    SolverError,
    SolveResult,
    SolverUnavailableError,
    TransientSolverError,
    solve,
)
from shared.solvers.errors import UnknownSolverError
from shared.solvers.params import InvalidSolverParamsError
from shared.solvers.registry import (
    ResolvedSolver,
    SolverSpec,
    check_params,
    get_solver,
    params_schema,
    register,
    resolve,
    solver_names,
    spec,
)

if TYPE_CHECKING:
    from shared.solvers.sampler import Sampler

    #: The type of a registered solver (a ``dimod.Sampler`` with availability and a name).
    Solver = Sampler


def __getattr__(name: str) -> Any:
    """``Sampler`` (and its alias ``Solver``) on first use: importing them imports dimod, which
    ``exact``'s grid inference never needs (:mod:`shared.solvers.sampler`)."""
    if name in ("Sampler", "Solver"):
        from shared.solvers.sampler import Sampler

        return Sampler
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Availability",
    "InvalidSolverParamsError",
    "ResolvedSolver",
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
    "resolve",
    "solve",
    "solver_names",
    "spec",
]

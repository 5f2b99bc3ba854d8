"""QUBO solvers as dimod samplers behind one registry (:mod:`shared.solvers.registry`).

The package's names are the solvers' contract (errors, results, the resolved solver); the
registry's functions are not re-exported: the few modules that look a solver up import
:mod:`shared.solvers.registry` itself (``tests/core/test_import_cycles.py`` lists them), the rest
are handed a :class:`ResolvedSolver`.
"""

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
from shared.solvers.records import SolverSpec
from shared.solvers.resolved import ResolvedSolver

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
    "solve",
]

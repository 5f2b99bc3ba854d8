"""The solvers' errors: what failed, and whether it is worth retrying. A module of its own that
imports nothing of the project, so that any solver module (the registry, the embedding search)
can raise them without importing the sampler base class."""

from __future__ import annotations


class SolverError(RuntimeError):
    """A solver failed; the message says what is wrong and what to do. Not worth retrying."""


class SolverUnavailableError(SolverError):
    """The solver cannot run here (missing token, licence or package)."""


class TransientSolverError(SolverError):
    """A failure worth retrying later (rate limit, timeout, solver offline)."""


class UnknownSolverError(KeyError):
    """A solver name nobody registered (nor an allowed ``dimod:`` class): ``args`` are the name
    and the message the registry words (the valid names, or why the ``dimod:`` name fails)."""

    def __str__(self) -> str:
        return str(self.args[1]) if len(self.args) > 1 else f"unknown solver {self.args[0]!r}"


def bad_parameters(name: str, error: Exception) -> SolverError | None:
    """``TypeError`` / ``ValueError`` from a sampler (bad parameters) as a ``SolverError`` naming
    solver ``name``; None for any other error (it goes through unchanged).

    Parameters
    ----------
    name : str
        The solver's name, for the message.
    error : Exception
        What the sampler raised.

    Returns
    -------
    SolverError or None
    """
    if isinstance(error, TypeError | ValueError):
        return SolverError(f"{name}: invalid parameters: {error}")
    return None
